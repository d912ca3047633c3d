"""The accuracy report's per-stage cost of a frame (issue 17, Qian Fig. 7.7 spirit): every shipped scene is
rendered through the pipeline at 48 pixels wide for two frames (or its one; "tiny" level, no warm-up), and its
row lists exactly the stages its plan runs, each timed or named as timed inside another, with the figure embedded."""
from __future__ import annotations

import pytest

from tissuerender import load_scene
from tissuerender.plan import make_plan
from tissuerender.report import stage_costs
from tissuerender.report.html import stage_section


@pytest.fixture(scope="module")
def costs():
    return stage_costs.run_stage_costs(stage_costs.STAGE_SWEEPS["tiny"])


def test_every_shipped_scene_appears_with_the_stages_its_plan_runs(costs):
    shipped = stage_costs.shipped_scenes()
    assert len(shipped) >= 5 and [r["scene"] for r in costs["scenes"]] == [p.stem for p in shipped]
    for row, path in zip(costs["scenes"], shipped):
        scene = stage_costs.small(load_scene(path), costs["sweep"])
        planned = make_plan(scene).names
        assert row["planned"] == planned
        # nothing runs that the plan does not list, and every planned stage is timed or named inside one that is
        assert set(row["stages"]) <= set(planned), row["scene"]
        assert set(row["stages"]) | set(row["timed_inside"]) == set(planned), row["scene"]
        assert all(v in row["stages"] for v in row["timed_inside"].values()), (row["scene"], row["timed_inside"])
        for name in ("raster", "shade", "write_png"):  # every shipped scene rasterises, shades and writes PNG
            assert row["stages"][name]["calls"] >= row["frames"] and row["per_frame_s"][name] > 0.0
        assert row["frames"] == min(2, load_scene(path).output.frames)  # kidney_static has one frame
        if "simulate" in planned:  # frame 1 is the rest state: one interval simulated per later frame
            assert row["stages"]["simulate"]["calls"] == row["frames"] - 1
        assert row["frame_s"] == pytest.approx(sum(row["per_frame_s"].values()), rel=1e-12)
        assert set(row["setup_s"]) <= set(stage_costs.SETUP_STAGES)
        assert not set(row["per_frame_s"]) & set(stage_costs.SETUP_STAGES)


def test_stages_timed_inside_others_are_simulation_parts_or_fused_pointwise_effects(costs):
    rows = {r["scene"]: r for r in costs["scenes"]}
    assert rows["default"]["timed_inside"].get("contact") == "simulate"  # the probe pushes the liver
    assert "simulate" not in rows["kidney_static"]["stages"]  # integrator = "none"
    assert rows["zhang_cylinder"]["stages"]["write_vtu"]["calls"] == 2  # formats lists vtu
    # a tone map right after another point-wise effect would be fused; after a blur it has its own timing
    assert stage_costs.timed_inside(["postfx.depth_of_field", "postfx.tonemap", "postfx.laparoscope_mask"],
                                    {"postfx.depth_of_field": {}, "postfx.tonemap": {}}) == {
        "postfx.laparoscope_mask": "postfx.tonemap"}


def test_stage_section_embeds_the_stacked_bar_figure_and_one_row_per_scene(costs):
    machine = {"processor": "cpu", "machine": "x86_64", "cpus": 2}
    text = stage_section(costs, machine)
    assert text.count('data-figure="stage-costs"') == 1 and "data:image/png;base64," in text
    assert all(f"<td>{r['scene']}</td>" in text for r in costs["scenes"])
    assert f"{costs['numba_threads']} numba thread(s)" in text
