"""Scene files: each kind of mistake is rejected with exit status 2 and a message naming the file and key."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tissuerender import SceneError, load_scene
from tissuerender.cli import main


def _error(path) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(path)
    return str(info.value)


def test_minimal_scene_loads_with_defaults(scene_dict, write_scene):
    scene = load_scene(write_scene(scene_dict))
    assert scene.name == "test" and scene.seed == 3
    assert (scene.width, scene.height) == (64, 48)
    assert scene.light.sampling == "adaptive"
    assert scene.simulation.substeps == 10
    assert [name for name, _ in scene.effect_chain()] == ["tonemap"]


def test_toml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text('[scene]\nname = "x"\nseed = = 3\n')
    msg = _error(path)
    assert "broken.toml" in msg and "TOML syntax error" in msg and "line 3" in msg


def test_empty_file(tmp_path):
    path = tmp_path / "empty.toml"
    path.write_text("  \n")
    assert "empty" in _error(path)


def test_binary_file(tmp_path):
    path = tmp_path / "image.toml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    assert "binary" in _error(path)


def test_missing_scene_file(tmp_path):
    assert "no such file" in _error(tmp_path / "nope.toml")


def test_unknown_key_is_an_error_not_ignored(scene_dict, write_scene):
    scene_dict["effects"]["shadow"] = True  # typo for "shadows"
    msg = _error(write_scene(scene_dict))
    assert "effects.shadow" in msg and "unknown key" in msg


def test_wrong_type_names_key_expected_and_found(scene_dict, write_scene):
    scene_dict["camera"]["fov_deg"] = "70"
    msg = _error(write_scene(scene_dict))
    assert "camera.fov_deg" in msg and "number" in msg and "'70'" in msg


def test_out_of_range_value(scene_dict, write_scene):
    scene_dict["output"]["resolution"] = [64, 0]
    msg = _error(write_scene(scene_dict))
    assert "output.resolution[1]" in msg and "greater than or equal to 8" in msg


def test_nan_is_rejected(scene_dict, write_scene):
    scene_dict["light"]["radiance"] = [1.0, float("nan"), 1.0]
    assert "light.radiance[1]" in _error(write_scene(scene_dict))


def test_mesh_file_that_does_not_exist(scene_dict, write_scene):
    obj = scene_dict["objects"][0]
    del obj["shape"], obj["size"], obj["cell_size"]
    obj["mesh"] = "meshes/liver.vtu"
    msg = _error(write_scene(scene_dict))
    assert "objects[0].mesh" in msg and "not found" in msg and "liver.vtu" in msg


def test_unknown_material_lists_presets(scene_dict, write_scene):
    scene_dict["objects"][0]["material"] = "livr"
    msg = _error(write_scene(scene_dict))
    assert "objects[0].material" in msg and "'livr'" in msg and "liver" in msg


def test_missing_required_section(scene_dict, write_scene):
    del scene_dict["camera"]
    assert "camera: missing required key" in _error(write_scene(scene_dict))


def test_unknown_integrator(scene_dict, write_scene):
    scene_dict["simulation"]["integrator"] = "verlet"
    msg = _error(write_scene(scene_dict))
    assert "simulation.integrator" in msg and "'verlet'" in msg


def test_body_needs_one_geometry_source(scene_dict, write_scene):
    scene_dict["objects"][0]["mesh"] = "x.vtu"
    assert "exactly one of 'shape'" in _error(write_scene(scene_dict))


def test_camera_up_parallel_to_view(scene_dict, write_scene):
    scene_dict["camera"].update(position=[0.0, 0.0, 1.0], look_at=[0.0, 0.0, 0.0], up=[0.0, 0.0, 1.0])
    assert "parallel" in _error(write_scene(scene_dict))


def test_keyframes_must_increase(scene_dict, write_scene):
    scene_dict["tools"] = [{"name": "p", "radius": 0.01,
                            "keyframes": [{"t": 1.0, "position": [0, 0, 0]}, {"t": 0.5, "position": [0, 0, 1]}]}]
    msg = _error(write_scene(scene_dict))
    assert "tools[0]" in msg and "increase" in msg


def test_mesh_too_large_for_cell_size(scene_dict, write_scene):
    scene_dict["objects"][0]["cell_size"] = 1e-5
    msg = _error(write_scene(scene_dict))
    assert "objects[0].cell_size" in msg and "tets" in msg


def test_duplicate_object_names(scene_dict, write_scene):
    scene_dict["objects"].append(dict(scene_dict["objects"][0]))
    assert "objects[1].name" in _error(write_scene(scene_dict))


def test_unknown_effect_parameter(scene_dict, write_scene):
    scene_dict["effects"]["tonemap"] = {"exposur": 1.0}
    assert "effects.tonemap.exposur" in _error(write_scene(scene_dict))


def test_cli_exit_status_2_and_no_traceback(scene_dict, write_scene):
    scene_dict["camera"]["fov_deg"] = -5.0
    path = write_scene(scene_dict)
    proc = subprocess.run([sys.executable, "-m", "tissuerender.cli", "plan", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: ") and "camera.fov_deg" in proc.stderr and str(path) in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_cli_validate_accepts_a_good_scene(scene_dict, write_scene, capsys):
    assert main(["validate", str(write_scene(scene_dict))]) == 0
    assert "ok" in capsys.readouterr().out


def _surface_object(scene_dict, tmp_path, **extra):
    (tmp_path / "wall.ply").write_text("ply\n")  # only its existence is checked when the scene loads
    scene_dict["objects"].append({"name": "wall", "kind": "surface", "mesh": "wall.ply", "material": "peritoneum",
                                  **extra})


def _mesh_body(scene_dict, tmp_path, mesh, **extra):
    (tmp_path / mesh).write_text("x\n")
    obj = scene_dict["objects"][0]
    del obj["shape"], obj["size"], obj["cell_size"]
    obj.update(mesh=mesh, **extra)


def _simulated(scene_dict, **simulation):
    scene_dict["simulation"] = {"integrator": "xpbd", "gravity": [0.0, 0.0, -9.81], **simulation}


def _chain(scene_dict, **effects):
    scene_dict["effects"].update(effects)


# (what the scene sets, the key the error names, words of the message): each an option that was accepted and
# then had no effect on the render (issue 16 item 3)
UNUSED = [
    (lambda d, t: d["camera"].update(focus_distance=0.2), "camera.focus_distance", "depth_of_field"),
    (lambda d, t: d["camera"].update(aperture=0.002), "camera.aperture", "not in the effect chain"),
    (lambda d, t: (d["camera"].update(aperture=0.002), _chain(d, depth_of_field={"aperture": 0.003})),
     "camera.aperture", "set twice: also effects.depth_of_field.aperture"),
    (lambda d, t: _chain(d, motion=True), "effects.motion", "not implemented"),
    (lambda d, t: _chain(d, bloom={}, order=["tonemap"]), "effects.order", "'bloom' has an [effects.bloom] table"),
    (lambda d, t: _chain(d, preset="hd_scope", order=["tonemap", "laparoscope_mask"]), "effects.order",
     "'chromatic_aberration' has an entry in preset 'hd_scope'"),
    (lambda d, t: d["output"].update(formats=["png", "vtu"]), "output.formats",
     "simulates nothing (simulation.integrator = \"none\")"),
    (lambda d, t: _simulated(d, gravity=[0.0, 0.0, 0.0], write_vtu=True), "simulation.write_vtu",
     "static scene: no tool, load"),
    (lambda d, t: _mesh_body(d, t, "body.vtu", cell_size=0.01), "objects[0].cell_size", "tet-mesh file"),
    (lambda d, t: _mesh_body(d, t, "body.ply", size=[0.1, 0.1, 0.1]), "objects[0].size", "voxelised"),
    (lambda d, t: _surface_object(d, t, render_subdivision=1), "objects[1].render_subdivision", "static surface"),
    (lambda d, t: _surface_object(d, t, override={"E": 1e4}), "objects[1].override", "never simulated"),
    (lambda d, t: d["light"].update(attach="world", position=[0, 0, 1], normal=[0, 0, -1], offset=[0.0, 0.01, 0.0]),
     "light.offset", "world light"),
    (lambda d, t: d["light"].update(up=[0.0, 1.0, 0.0]), "light.up", "camera-attached"),
    (lambda d, t: d["light"].update(penumbra_samples=32), "light.penumbra_samples", "effects.shadows"),
    (lambda d, t: d["light"].update(cone_samples=8), "light.cone_samples", "reflection_cone"),
    (lambda d, t: _chain(d, sss_thickness="pixel"), "effects.sss_thickness", "effects.sss"),
    (lambda d, t: _chain(d, ao_samples=4), "effects.ao_samples", "effects.ao"),
    (lambda d, t: _chain(d, environment_axis=[0.0, 1.0, 0.0]), "effects.environment_axis", "mucus_reflection"),
    (lambda d, t: ([o.update(material="plastic") for o in d["objects"]],  # every tissue preset has a wet coat
                   _chain(d, mucus_reflection=True, environment_up=[1.0, 1.0, 1.0])), "effects.mucus_reflection",
     "layered material"),
    (lambda d, t: (d["effects"].pop("tonemap"), _chain(d, backend="numpy")), "effects.backend", "has none"),
    (lambda d, t: d["output"].update(jitter=False), "output.jitter", "supersampling = 1"),
    (lambda d, t: d["simulation"].update(substeps=4), "simulation.substeps", "integrator = \"none\""),
    (lambda d, t: _simulated(d, cnn={"K": 2.0}), "simulation.cnn", "not selected (integrator = 'xpbd')"),
    (lambda d, t: _simulated(d, integrator="cnn", iterations=5), "simulation.iterations",
     "the cnn integrator ignores it (ignored: the CNN has no inner iterations)"),
    (lambda d, t: _simulated(d, integrator="reference", substeps=2), "simulation.substeps", "reference"),
    (lambda d, t: _simulated(d, xpbd={"relaxation": 0.5}), "simulation.xpbd.relaxation", "Jacobi"),
    (lambda d, t: _simulated(d, xpbd={"limit_compliance": 1e-6}), "simulation.xpbd.limit_compliance", "Green-strain"),
    (lambda d, t: _simulated(d, xpbd={"limit_axes": [1], "shear_max": 0.1}), "simulation.xpbd.limit_axes",
     "green_stretch_min / green_stretch_max"),
    (lambda d, t: _simulated(d, integrator="cnn", cnn={"energy_rho": 2.0}), "simulation.cnn.energy_rho",
     "force_model = \"energy\""),
    (lambda d, t: _simulated(d, xpbd={"material": "model", "coupled": False}), "simulation.xpbd.coupled",
     "no solver choice or constraint coupling"),
    (lambda d, t: d["objects"][0].update(override={"E": 1e4}), "objects[0].override", "integrator = \"none\""),
    (lambda d, t: d["objects"][0].update(prescribed=[{"side": "z_max", "displacement": [0, 0, -0.01]}]),
     "objects[0].prescribed", "integrator = \"none\""),
    (lambda d, t: d.update(tools=[{"name": "p", "radius": 0.01, "length": 0.02,
                                   "keyframes": [{"t": 0.0, "position": [0, 0, 0.1]}]}]), "tools[0].length", "sphere"),
    (lambda d, t: d.update(tools=[{"name": "p", "radius": 0.01, "visible": False,
                                   "keyframes": [{"t": 0.0, "position": [0, 0, 0.1]}]}]), "tools[0].visible",
     "simulates nothing"),
]


@pytest.mark.parametrize("mutate, key, words", UNUSED, ids=[f"{k}-{i}" for i, (_, k, _) in enumerate(UNUSED)])
def test_an_option_without_effect_is_an_error_naming_its_key(scene_dict, write_scene, tmp_path, mutate, key, words):
    mutate(scene_dict, tmp_path)
    msg = _error(write_scene(scene_dict))
    assert f": {key}: " in msg and words in msg, msg


def test_options_that_do_act_are_accepted(scene_dict, write_scene, tmp_path):
    """The counterparts of the rejections: the same keys where they change the render."""
    scene_dict["camera"].update(focus_distance=0.2, aperture=0.003)
    _chain(scene_dict, depth_of_field={"max_radius_px": 5.0}, sss=True, sss_thickness="pixel",
           order=["depth_of_field", "tonemap"])
    _surface_object(scene_dict, tmp_path, scale=2.0)
    scene_dict["output"].update(supersampling=2, jitter=False)
    scene = load_scene(write_scene(scene_dict))
    chain = dict(scene.effect_chain())
    # the camera's lens feeds the depth of field; the table's own keys stay
    assert (chain["depth_of_field"].focus_distance, chain["depth_of_field"].aperture) == (0.2, 0.003)
    assert chain["depth_of_field"].max_radius_px == 5.0


def test_a_voxelised_body_takes_its_cell_size(scene_dict, write_scene, tmp_path):
    _mesh_body(scene_dict, tmp_path, "body.ply", cell_size=0.01)
    assert load_scene(write_scene(scene_dict)).objects[0].cell_size == 0.01


# Scenes every table of which is valid, but which cannot be built: `validate` builds what `render` builds before
# its first frame (issue 16 item 4), so each exits 2 naming the table or key, where it used to print "ok".
CANNOT_RENDER = [
    ({"simulation": {"integrator": "cnn_chainmail", "gravity": [0.0, 0.0, -9.81]}},
     "[simulation.cnn_chainmail] for object 'block'", "gravity"),
    ({"simulation": {"integrator": "reference", "reference": {"anp": True}}},
     "[simulation.reference] for object 'block'", "average nodal pressure needs a model with a volumetric split"),
    ({"simulation": {"integrator": "ebm", "gravity": [0.0, 0.0, -9.81]},
      "paint": [{"centre": [0.0, 0.0, 0.0], "radius": 0.05, "amount": 2.0}]},
     "[simulation.ebm] for object 'block'", "cannot represent heterogeneous stiffness"),
    ({"mesh": "broken.ply"}, "objects[0]", "broken.ply"),
]


@pytest.mark.parametrize("change, where, words", CANNOT_RENDER, ids=["chainmail_gravity", "anp_stable_nh", "ebm_paint",
                                                                     "broken_mesh"])
def test_validate_builds_the_scene_and_refuses_what_cannot_render(scene_dict, write_scene, tmp_path, capsys,
                                                                  change, where, words):
    change = dict(change)
    if "simulation" in change:
        scene_dict["simulation"] = change.pop("simulation")
    if "mesh" in change:
        (tmp_path / change["mesh"]).write_text("ply\nformat ascii 1.0\nend_header\n")  # no vertices, no faces
        obj = scene_dict["objects"][0]
        del obj["shape"], obj["size"], obj["cell_size"]
    scene_dict["objects"][0].update(change)
    path = write_scene(scene_dict)
    load_scene(path)  # every table is valid on its own
    assert main(["validate", str(path)]) == 2
    out, err = capsys.readouterr()
    assert "ok" not in out and err.startswith(f"error: {path}") and where in err and words in err, err
    assert err.count("\n") == 1


def test_validate_accepts_every_shipped_scene(capsys):
    scenes = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))
    assert len(scenes) >= 5
    assert main(["validate", *map(str, scenes)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(": ok (")[0] for line in out] == [str(p) for p in scenes]
