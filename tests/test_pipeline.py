"""End to end: a scene renders to PNG frames with a manifest, deterministically, atomically, resumably."""
from __future__ import annotations

import json
import re
import subprocess
import sys

import meshio
import numpy as np
import pytest
from PIL import Image

import tissuerender
from tissuerender import load_scene, pipeline
from tissuerender.bodies import build_body
from tissuerender.cli import main


def _pixels(path):
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)


def test_render_writes_frames_and_manifest(scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(scene_dict))
    result = tissuerender.render(scene, tmp_path / "out", progress=False)
    frame = tmp_path / "out" / "frame_0001.png"
    assert result.written == [frame]
    img = _pixels(frame)
    assert img.shape == (48, 64, 3)
    # The lit block fills the middle of the view; the corners see only the background.
    centre = img[18:30, 24:40].mean()
    corners = np.mean([img[:4, :4].mean(), img[:4, -4:].mean()])
    assert centre > corners + 10.0
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["scene_sha256"] == scene.sha256 and manifest["seed"] == 3
    assert manifest["complete"] is True and manifest["frames_done"] == 1
    assert manifest["versions"]["numpy"] == np.__version__
    assert "raster" in manifest["plan"]["stages"] and manifest["executed"]["raster"]["calls"] == 1


def test_same_scene_and_seed_give_identical_pixels(scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(scene_dict))
    a = tissuerender.render_image(scene)
    b = tissuerender.render_image(scene)
    assert a.dtype == np.uint8 and np.array_equal(a, b)


def _dynamic(scene_dict):
    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1 / 24, "substeps": 4, "iterations": 4}
    scene_dict["tools"] = [{"name": "probe", "radius": 0.015, "keyframes": [
        {"t": 0.0, "position": [0.05, 0.05, 0.07]}, {"t": 0.2, "position": [0.05, 0.05, 0.02]}]}]
    scene_dict["output"]["frames"] = 4
    return scene_dict


def test_resume_renders_only_missing_frames_identically(scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(_dynamic(scene_dict)))
    out = tmp_path / "out"
    first = tissuerender.render(scene, out, progress=False)
    assert len(first.written) == 4
    original = (out / "frame_0003.png").read_bytes()
    (out / "frame_0003.png").unlink()
    second = tissuerender.render(scene, out, resume=True, progress=False)
    assert [p.name for p in second.written] == ["frame_0003.png"]
    assert len(second.skipped) == 3
    assert (out / "frame_0003.png").read_bytes() == original


def test_simulated_frames_change_as_the_probe_presses(scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(_dynamic(scene_dict)))
    out = tmp_path / "out"
    tissuerender.render(scene, out, progress=False)
    diff = np.abs(_pixels(out / "frame_0004.png") - _pixels(out / "frame_0001.png")).mean()
    assert diff > 0.5


def test_interrupted_render_keeps_finished_frames_and_leaves_no_partial_file(scene_dict, write_scene, tmp_path,
                                                                             monkeypatch):
    scene_dict["output"]["frames"] = 3
    scene = load_scene(write_scene(scene_dict))
    real = pipeline.write_png
    calls = {"n": 0}

    def flaky(path, image):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        real(path, image)

    monkeypatch.setattr(pipeline, "write_png", flaky)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        tissuerender.render(scene, out, progress=False)
    assert sorted(p.name for p in out.iterdir()) == ["frame_0001.png", "manifest.json"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is False and manifest["frames_done"] == 1
    monkeypatch.setattr(pipeline, "write_png", real)
    resumed = tissuerender.render(scene, out, resume=True, progress=False)
    assert [p.name for p in resumed.written] == ["frame_0002.png", "frame_0003.png"]


def test_cli_render_end_to_end(scene_dict, write_scene, tmp_path, capsys):
    path = write_scene(scene_dict)
    assert main(["render", str(path), "-o", str(tmp_path / "cli"), "--quiet"]) == 0
    assert (tmp_path / "cli" / "frame_0001.png").exists()


@pytest.mark.parametrize("integrator, table, message", [
    ("cnn", {}, None),
    ("explicit", {"rayleigh_beta": 0.001}, None),
    ("ebm", {"update": "average"}, None),
    ("cnn", {"force_model": "energy_propagation"}, "force_model"),
    ("xpbd", {"strain_max": 1.1, "strain_min": 0.9}, None),
])
def test_integrator_choice_renders_or_exits_2_with_the_reason(scene_dict, write_scene, tmp_path, capsys,
                                                              integrator, table, message):
    # 1/504 s: 21 steps per 1/24 s frame, substeps of 0.99 ms (cnn inverts elements at 1/480 s, 1.04 ms substeps)
    scene_dict["simulation"] = {"integrator": integrator, "dt": 1 / 504, "substeps": 2,
                                "gravity": [0.0, 0.0, -9.81], integrator: table}
    scene_dict["output"].update(frames=2, formats=["png", "vtu"])
    path = write_scene(scene_dict)
    code = main(["render", str(path), "-o", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    if message is None:
        assert code == 0 and (tmp_path / "out" / "frame_0002.png").exists(), err
        manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
        assert manifest["executed"]["simulate"]["calls"] == 1  # one frame interval between frames 1 and 2
        # the block, fixed at z_min, sags under gravity: its top goes down, no node falls faster than free
        # fall over the frame interval (at most 0.042 s: 21 steps of 2 ms; g t^2 / 2 = 8.7 mm), the base stays put
        rest = meshio.read(tmp_path / "out" / "block_0001.vtu")
        moved = meshio.read(tmp_path / "out" / "block_0002.vtu")
        u0, u = rest.point_data["displacement"], moved.point_data["displacement"]
        z = rest.points[:, 2]
        assert np.abs(u0).max() == 0.0 and np.all(u[z == z.min()] == 0.0)
        free_fall = 0.5 * 9.81 * 0.042**2
        assert -free_fall * (1 + 1e-9) <= u[:, 2].min() and u[z == z.max(), 2].mean() < -1e-3 * free_fall, \
            (u[:, 2].min(), u[z == z.max(), 2].mean())
    else:
        assert code == 2 and re.search(message, err) and "Traceback" not in err
        assert str(path) in err


def test_paint_strokes_stiffen_the_model_and_bad_ones_exit_2(scene_dict, write_scene, tmp_path, capsys):
    scene_dict["simulation"] = {"integrator": "xpbd"}  # paint acts on the simulation only
    scene_dict["objects"][0]["paint"] = [{"centre": [0.0, 0.0, 0.0], "radius": 0.05, "amount": 3.0}]
    scene = load_scene(write_scene(scene_dict))
    body = build_body(scene.objects[0], 0, scene)
    E = body.model.E
    assert E.max() > 2.0 * E.min() and np.isclose(E.min(), np.median(E))  # only near the corner
    scene_dict["objects"][0]["paint"] = [{"centre": [0.0, 0.0, 0.0], "radius": 0.05, "amount": -0.99}] * 3
    path = write_scene(scene_dict, "bad.toml")
    assert main(["render", str(path), "-o", str(tmp_path / "bad"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "objects[0].paint" in err and "non-positive" in err and "Traceback" not in err


@pytest.mark.parametrize("case", ["existing_file", "below_a_file"])
def test_output_path_that_cannot_be_a_folder_is_a_user_error(scene_dict, write_scene, tmp_path, case):
    """`-o` naming an existing file, or a folder that cannot be created, used to end in a traceback."""
    blocker = tmp_path / "taken.png"
    blocker.write_bytes(b"not a folder")
    out = blocker if case == "existing_file" else blocker / "frames"
    proc = subprocess.run([sys.executable, "-m", "tissuerender.cli", "render", str(write_scene(scene_dict)),
                           "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert proc.stderr.startswith("error: ") and str(out) in proc.stderr
    assert blocker.read_bytes() == b"not a folder"  # nothing overwritten
