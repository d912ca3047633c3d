"""Scene files: each kind of mistake is rejected with exit status 2 and a message naming the file and key."""
from __future__ import annotations

import subprocess
import sys

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
