"""The plan is derived from the scene alone, and stages it does not list never run."""
from __future__ import annotations

from pathlib import Path

import pytest

import sim.integrators
import tissuerender
from tissuerender import load_scene, make_plan
from tissuerender.cli import main

SCENES = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))


# Each shipped scene's stages, read off its file by hand: what moves it, which switches are on, which effects
# it lists (or its preset brings), which formats it writes.
SURGICAL = ["mesh", "load_surface", "simulate", "contact", "embed", "raster", "bvh", "shadow_rays", "thickness",
            "shade", "postfx.depth_of_field", "postfx.chromatic_aberration", "postfx.tonemap",
            "postfx.laparoscope_mask", "write_png"]
SHIPPED_PLANS = {
    # xpbd, a prescribed ramp, viscoelastic colon_mucosa; sss; preset hd_scope plus a depth_of_field table
    "colon_mucosa": ["mesh", "simulate", "prony_state", "embed", "raster", "bvh", "thickness", "shade",
                     "postfx.depth_of_field", "postfx.chromatic_aberration", "postfx.tonemap",
                     "postfx.laparoscope_mask", "write_png"],
    # integrator "none": nothing simulated; sss; two effect tables
    "kidney_static": ["mesh", "raster", "bvh", "thickness", "shade", "postfx.tonemap", "postfx.laparoscope_mask",
                      "write_png"],
    # the surgical scenes: bodies, a static wall or fat, probes; shadows and sss; preset hd_scope plus depth_of_field
    **{name: SURGICAL for name in ("default", "liver_probe", "kidney_ebm", "cholecystectomy")},
    # cnn inside a tube (a tet-mesh file: no static surface), a probe; shadows and sss; hd_scope and depth_of_field
    "colon_cnn": [s for s in SURGICAL if s != "load_surface"],
    # integrator "none", one slab; sss, no shadows; hd_scope and depth_of_field
    "mucosa_closeup": ["mesh", "raster", "bvh", "thickness", "shade", "postfx.depth_of_field",
                       "postfx.chromatic_aberration", "postfx.tonemap", "postfx.laparoscope_mask", "write_png"],
    # prescribed compression, no gravity, no tools; no shadows (a colour map); png and vtu
    "zhang_cylinder": ["mesh", "simulate", "embed", "write_vtu", "raster", "shade", "postfx.tonemap", "write_png"],
    # gravity on a held beam; no shadows, no sss
    "beam": ["mesh", "simulate", "embed", "raster", "shade", "postfx.tonemap", "write_png"],
    # prescribed shear, no gravity; shadows
    "cube_shear": ["mesh", "simulate", "embed", "raster", "bvh", "shadow_rays", "shade", "postfx.tonemap",
                   "write_png"],
}


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_shipped_scene_plans_exactly_its_stages(path, capsys):
    assert make_plan(load_scene(path)).names == SHIPPED_PLANS[path.stem]
    assert main(["plan", str(path)]) == 0
    out = capsys.readouterr().out
    ran, _, skipped = out.partition("stages that will not run:")
    assert [line.split()[0] for line in ran.splitlines()[2:]] == SHIPPED_PLANS[path.stem]
    assert all(line.split()[0] not in SHIPPED_PLANS[path.stem] for line in skipped.splitlines()[1:])


def test_an_order_must_list_every_effect_with_a_table_and_the_plan_follows_it(scene_dict, write_scene, capsys):
    scene_dict["effects"].update(preset="hd_scope", bloom={}, order=["bloom", "tonemap", "chromatic_aberration"])
    path = write_scene(scene_dict)
    assert main(["plan", str(path)]) == 2
    err = capsys.readouterr().err
    assert "effects.order: 'laparoscope_mask' has an entry in preset 'hd_scope' but is missing from the order" in err
    scene_dict["effects"]["order"] = ["bloom", "tonemap", "chromatic_aberration", "laparoscope_mask"]
    plan = make_plan(load_scene(write_scene(scene_dict)))
    # the plan lists the post-effects in the order they run (the scene's, not the default)
    assert [n for n in plan.names if n.startswith("postfx.")] == ["postfx.bloom", "postfx.tonemap",
                                                                   "postfx.chromatic_aberration", "postfx.laparoscope_mask"]
    # "not listed" now means just that: no table and no preset entry
    assert {s.name for s in plan.skipped if s.reason == "not listed in effects"} == {
        "postfx.depth_of_field", "postfx.lens_flare", "postfx.blur", "postfx.sensor_noise", "postfx.color_grade",
        "postfx.sharpen"}


def test_every_shipped_scene_is_listed():
    assert sorted(p.stem for p in SCENES) == sorted(SHIPPED_PLANS)


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


def test_output_passes_add_one_pass_raster_each_asked_pass_and_the_writer(scene_dict, write_scene, capsys):
    base = make_plan(load_scene(write_scene(scene_dict))).names
    scene_dict["output"]["passes"] = ["material_coords", "depth"]
    path = write_scene(scene_dict)
    plan = make_plan(load_scene(path))
    # the passes run after the colour stages, in their fixed order, whatever the order of the list
    assert plan.names == base + ["passes.raster", "passes.depth", "passes.material_coords", "write_passes"]
    skipped = {s.name: s.reason for s in plan.skipped}
    assert skipped["passes.normal"] == "normal not in output.passes"
    assert skipped["passes.segmentation"] == "segmentation not in output.passes"
    assert main(["plan", str(path)]) == 0
    lines = [line.split(None, 1) for line in capsys.readouterr().out.splitlines()]
    assert ["passes.raster", "output.passes lists material_coords, depth"] in lines
