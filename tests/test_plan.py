"""The plan is derived from the scene alone, and stages it does not list never run."""
from __future__ import annotations

from pathlib import Path

import pytest

import sim.integrators
import tissuerender
from tissuerender import load_scene, make_plan
from tissuerender.cli import main

SCENES = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))


# What each shipped scene file asks for, read from the file (besides raster and shade, which every frame needs):
# a body meshes; an integrator with a tool, gravity or prescribed motion simulates; a viscoelastic material
# (colon_mucosa) keeps Prony state; a tool makes contact; shadows / sss need the BVH; postfx are the listed
# tables plus the preset's (hd_scope: chromatic_aberration, tonemap, laparoscope_mask); formats decide the writers.
SHIPPED_PLANS = {
    "colon_mucosa": ["mesh", "simulate", "prony_state", "embed", "bvh", "thickness", "postfx.depth_of_field",
                     "postfx.chromatic_aberration", "postfx.tonemap", "postfx.laparoscope_mask", "write_png"],
    "default": ["mesh", "simulate", "contact", "embed", "bvh", "shadow_rays", "thickness",
                "postfx.chromatic_aberration", "postfx.tonemap", "postfx.laparoscope_mask", "write_png"],
    "kidney_static": ["mesh", "bvh", "thickness", "postfx.tonemap", "postfx.laparoscope_mask", "write_png"],
    "liver_probe": ["mesh", "load_surface", "simulate", "contact", "embed", "bvh", "shadow_rays", "thickness",
                    "postfx.chromatic_aberration", "postfx.tonemap", "postfx.laparoscope_mask", "write_png"],
    "zhang_cylinder": ["mesh", "simulate", "embed", "write_vtu", "bvh", "shadow_rays", "postfx.tonemap", "write_png"],
}


def test_every_shipped_scene_is_listed():
    assert sorted(p.stem for p in SCENES) == sorted(SHIPPED_PLANS)


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_shipped_scene_plans_what_its_file_asks_for(path, capsys):
    """The plan of each shipped scene, in order, and `plan` prints exactly those stages as running and every
    other known stage as not running (with a reason)."""
    assert main(["plan", str(path)]) == 0
    out = capsys.readouterr().out
    running, _, rest = out.partition("stages that will run:\n")[2].partition("stages that will not run:\n")
    printed = [line.split()[0] for line in running.splitlines()]
    expected = SHIPPED_PLANS[path.stem]
    assert [n for n in printed if n not in ("raster", "shade")] == expected
    assert printed.index("raster") < printed.index("shade")
    plan = make_plan(load_scene(path))
    assert printed == list(plan.names)
    skipped = [line.split(maxsplit=1) for line in rest.splitlines() if line.strip()]
    assert {name for name, _ in skipped} == {s.name for s in plan.skipped} and all(len(r) == 2 for r in skipped)
    assert not set(printed) & {s.name for s in plan.skipped}


def test_static_scene_plans_no_simulation(scene_dict, write_scene):
    plan = make_plan(load_scene(write_scene(scene_dict)))
    assert "simulate" not in plan and "embed" not in plan and "contact" not in plan
    assert any(s.name == "simulate" and "integrator" in s.reason for s in plan.skipped)


def test_integrator_without_anything_moving_is_static(scene_dict, write_scene):
    scene_dict["simulation"] = {"integrator": "xpbd", "gravity": [0.0, 0.0, 0.0]}
    plan = make_plan(load_scene(write_scene(scene_dict)))
    assert "simulate" not in plan
    assert any(s.name == "simulate" and "static scene" in s.reason for s in plan.skipped)


def test_gravity_or_tool_makes_it_dynamic(scene_dict, write_scene):
    scene_dict["simulation"] = {"integrator": "xpbd", "gravity": [0.0, 0.0, 0.0]}
    scene_dict["tools"] = [{"name": "probe", "radius": 0.01, "keyframes": [{"t": 0.0, "position": [0, 0, 0.1]}]}]
    plan = make_plan(load_scene(write_scene(scene_dict)))
    assert "simulate" in plan and "contact" in plan and "embed" in plan


def test_no_bvh_thickness_or_ao_when_effects_are_off(scene_dict, write_scene):
    plan = make_plan(load_scene(write_scene(scene_dict)))
    for name in ("bvh", "shadow_rays", "thickness", "ao", "velocity_channel"):
        assert name not in plan


def test_sss_needs_thickness_and_bvh(scene_dict, write_scene):
    scene_dict["effects"]["sss"] = True
    plan = make_plan(load_scene(write_scene(scene_dict)))
    assert "thickness" in plan and "bvh" in plan and "shadow_rays" not in plan
    assert "effects.sss" in dict((s.name, s.reason) for s in plan.stages)["bvh"]


def test_prony_state_only_for_viscoelastic_material(scene_dict, write_scene):
    scene_dict["simulation"] = {"integrator": "xpbd"}
    elastic = make_plan(load_scene(write_scene(scene_dict)))
    assert "simulate" in elastic and "prony_state" not in elastic and "fibre_terms" not in elastic
    scene_dict["objects"][0]["material"] = "colon_mucosa"
    visco = make_plan(load_scene(write_scene(scene_dict, "visco.toml")))
    # XPBD relaxes Prony series as Maxwell branches (sim.xpbd_prony), as EBM and the reference do
    assert "prony_state" in visco
    scene_dict["simulation"] = {"integrator": "ebm"}
    assert "prony_state" in make_plan(load_scene(write_scene(scene_dict, "visco_ebm.toml")))
    # an integrator without viscoelastic terms: the plan says so instead of pretending
    scene_dict["simulation"] = {"integrator": "cnn"}
    cnn = make_plan(load_scene(write_scene(scene_dict, "visco_cnn.toml")))
    assert "prony_state" not in cnn
    assert "cnn integrator has no viscoelastic terms" in {s.name: s.reason for s in cnn.skipped}["prony_state"]
    scene_dict["objects"][0]["material"] = "fascia"
    assert "fibre_terms" in make_plan(load_scene(write_scene(scene_dict, "aniso.toml")))
    scene_dict["simulation"] = {"integrator": "xpbd"}
    assert "fibre_terms" not in make_plan(load_scene(write_scene(scene_dict, "aniso_xpbd.toml")))


def test_only_listed_post_effects_are_planned(scene_dict, write_scene):
    plan = make_plan(load_scene(write_scene(scene_dict)))
    post = [n for n in plan.names if n.startswith("postfx.")]
    assert post == ["postfx.tonemap"]


def test_static_render_never_builds_an_integrator_or_bvh(scene_dict, write_scene, monkeypatch, tmp_path):
    def refuse(*args, **kwargs):
        raise AssertionError("an unplanned stage ran")

    monkeypatch.setattr(sim.integrators, "make_integrator", refuse)
    scene = load_scene(write_scene(scene_dict))
    result = tissuerender.render(scene, tmp_path / "out", progress=False)
    executed = result.manifest["executed"]
    assert "simulate" not in executed and "bvh" not in executed and "thickness" not in executed
    assert {"mesh", "raster", "shade", "write_png"} <= set(executed)
    assert set(executed) <= set(result.plan.names)


def test_executed_stages_are_a_subset_of_the_plan_for_a_dynamic_scene(scene_dict, write_scene, tmp_path):
    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1 / 24, "substeps": 2, "iterations": 2}
    scene_dict["output"]["frames"] = 2
    scene = load_scene(write_scene(scene_dict))
    recorder_names = set(tissuerender.render(scene, tmp_path / "out", progress=False).manifest["executed"])
    plan = make_plan(scene)
    assert {"simulate", "embed"} <= recorder_names <= set(plan.names)
