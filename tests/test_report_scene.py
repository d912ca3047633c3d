"""``tissuerender report accuracy SCENE`` (issue 17 item 2): on a tiny xpbd scene (a 0.1 m liver block made
stiffer, E = 10 kPa, so the solver's error shows beside the step's; 4 x 4 x 4 cells, sheared and compressed by a
ramp on its top face, 3 frames measured, 64 x 48 pixels) the simulation error falls as
the iterations rise, the reference's own error falls under refinement, the cheapest setting named is within the
budget and nothing cheaper is, FLIP falls with light samples, and bad budgets exit 2. The report runs once per
module, in-process, at the "tiny" sweep (``tissuerender.report.scene.SCENE_SWEEPS``)."""
from __future__ import annotations

import json

import pytest

from tissuerender import cli, load_scene
from tissuerender.errors import UserError
from tissuerender.report import accuracy
from tissuerender.report.scene import cheapest, parse_budget

TINY_SCENE = """
[scene]
name = "tiny_block"
seed = 3

[[objects]]
name = "block"
shape = "box"
size = [0.1, 0.1, 0.1]
cell_size = 0.025
material = "liver"
override = { E = 1e4 }
fixed = [{ side = "z_min" }]
prescribed = [{ side = "z_max", displacement = [0.02, 0.0, -0.02], t_start = 0.0, t_end = 0.5 }]

[simulation]
integrator = "xpbd"
dt = 0.020833333333333332
substeps = 4
iterations = 4
gravity = [0.0, 0.0, 0.0]

[simulation.xpbd]
material = "model"

[camera]
position = [0.0, -0.3, 0.15]
look_at = [0.0, 0.0, 0.0]

[light]
attach = "camera"
size = [0.05, 0.05]
radiance = [3000.0, 3000.0, 3000.0]
samples = 4
sampling = "uniform"

[effects]
shadows = true
sss = true

[output]
resolution = [64, 48]
frames = 4
fps = 24.0
"""
BUDGET = {"sim": 0.06, "flip": 0.002}


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "tiny.toml"
    path.write_text(TINY_SCENE)
    return path


@pytest.fixture(scope="module")
def scene_report(scene_path, tmp_path_factory):
    out = tmp_path_factory.mktemp("scene_report")
    report = accuracy.run_report(out, scene=load_scene(scene_path), budget=BUDGET, level="tiny")
    return out, report


def test_simulation_error_falls_monotonically_as_iterations_rise(scene_report):
    _, report = scene_report
    sim = report["scene"]["simulation"]
    assert sim["integrator"] == "xpbd" and sim["frames"] == 3
    sweep = sorted((p for p in sim["points"] if p["substeps"] == 4), key=lambda p: p["iterations"])
    assert [p["iterations"] for p in sweep] == [1, 2, 4, 8]
    errors = [p["rel_l2"] for p in sweep]
    assert all(a > b for a, b in zip(errors, errors[1:])), errors
    # frame 1 is the rest state (no error measured), every later frame has one
    assert all(p["rel_l2_per_frame"][0] is None and None not in p["rel_l2_per_frame"][1:] for p in sweep)
    # halving the substep (dt / substeps) also brings the setting nearer the reference's backward Euler
    by_substeps = sorted((p for p in sim["points"] if p["iterations"] == 4), key=lambda p: p["substeps"])
    assert [p["substeps"] for p in by_substeps] == [1, 2, 4, 8]
    assert all(a["rel_l2"] > b["rel_l2"] for a, b in zip(by_substeps, by_substeps[1:]))


def test_reference_error_falls_under_time_step_refinement(scene_report):
    _, report = scene_report
    ref = report["scene"]["simulation"]["reference"]
    # steps 4h, 2h, h with h a quarter of the scene's substep (dt / 4 / 4)
    assert ref["levels_s"] == pytest.approx([4 * ref["step_s"], 2 * ref["step_s"], ref["step_s"]], rel=1e-15)
    assert ref["step_s"] == pytest.approx(0.020833333333333332 / 16, rel=1e-15)
    assert ref["differences"][1] < ref["differences"][0] and ref["falls"]


def test_cheapest_setting_is_within_budget_and_no_cheaper_setting_is(scene_report):
    _, report = scene_report
    for part, error_key, time_key, limit in (("simulation", "rel_l2", "wall_s_per_frame", BUDGET["sim"]),
                                             ("rendering", "flip", "seconds", BUDGET["flip"])):
        done = report["scene"][part]
        chosen = done["cheapest"]
        assert chosen["setting"] is not None, part
        best = done["points"][chosen["index"]]
        assert best["label"] == chosen["setting"] and best[error_key] <= limit
        for p in done["points"]:
            if p[time_key] < best[time_key]:
                assert p[error_key] is None or p[error_key] > limit, (part, p["label"])
    # the sweep straddles the budget: one iteration is outside it, so the choice is not vacuous
    assert any(p["rel_l2"] > BUDGET["sim"] for p in report["scene"]["simulation"]["points"])


def test_flip_falls_with_light_samples_at_the_reference_supersampling(scene_report):
    _, report = scene_report
    ren = report["scene"]["rendering"]
    assert ren["resolution"] == [64, 48]
    sweep = sorted((p for p in ren["points"] if p["supersampling"] == 2), key=lambda p: p["samples"])
    assert [p["samples"] for p in sweep] == [1, 4, 16]
    assert all(a["flip"] > b["flip"] and a["rel_rmse"] > b["rel_rmse"] for a, b in zip(sweep, sweep[1:]))
    # without supersampling the aliasing against the 2x2 reference dominates whatever the samples
    assert min(p["flip"] for p in ren["points"] if p["supersampling"] == 1) > max(p["flip"] for p in sweep)


def test_scene_section_in_html_and_json_and_a_rerun_reuses_both_parts(scene_report, scene_path):
    out, report = scene_report
    text = (out / "report.html").read_text()
    assert 'id="scene"' in text and 'data-figure="scene-simulation"' in text and 'data-figure="scene-rendering"' in text
    assert json.loads((out / "report.json").read_text())["scene"] == report["scene"]
    assert report["cases"] == {}  # a scene's report runs no theses' case unless --cases names one
    assert 'id="claims"' not in text  # so no claims table of "not comparable" rows
    again = accuracy.run_report(out, scene=load_scene(scene_path), budget=BUDGET, level="tiny")
    assert again["scene"]["simulation"]["cached"] and again["scene"]["rendering"]["cached"]
    assert again["scene"]["simulation"]["points"] == report["scene"]["simulation"]["points"]


def test_cheapest_says_none_when_no_setting_is_within_the_budget():
    points = [{"label": "a", "e": 0.5, "t": 1.0}, {"label": "b", "e": 0.2, "t": 2.0},
              {"label": "c", "e": None, "t": 0.1}]
    assert cheapest(points, {"e": 0.1}, "t")["setting"] is None
    assert cheapest(points, {"e": 0.3}, "t")["setting"] == "b"
    assert cheapest(points, {"e": 0.5}, "t")["setting"] == "a"


def test_budget_parses_percentages_and_keeps_defaults():
    assert parse_budget("sim=2%") == {"sim": pytest.approx(0.02, rel=1e-15), "flip": 0.002}
    assert parse_budget("flip=0.01, rmse=0.05") == {"sim": 0.01, "flip": 0.01, "rmse": 0.05}
    for bad in ("sim=abc", "speed=1", "sim=-1%", "sim", "flip=inf"):
        with pytest.raises(UserError, match="--budget"):
            parse_budget(bad)


@pytest.mark.parametrize("budget, expected", [("sim=abc", "sim='abc': expected a positive number"),
                                              ("speed=3", "'speed=3': expected key=value with key one of sim, flip")])
def test_bad_budget_exits_2_with_one_line(scene_path, tmp_path, capsys, budget, expected):
    status = cli.main(["report", "accuracy", str(scene_path), "-o", str(tmp_path / "out"), "--budget", budget])
    err = capsys.readouterr().err
    assert status == 2 and expected in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()  # refused before anything ran or was written


def test_budget_without_a_scene_exits_2(tmp_path, capsys):
    status = cli.main(["report", "accuracy", "-o", str(tmp_path / "out"), "--budget", "sim=1%"])
    err = capsys.readouterr().err
    assert status == 2 and "--budget: applies to a scene's report" in err and not (tmp_path / "out").exists()
