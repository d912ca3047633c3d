"""Non-finite values are caught where they arise (raster, thickness, shade, resolve, post-effects), reported
with the scene file, frame, object and stage as a user error (exit 2), and never written: not as black
pixels, not in the HDR output."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import postfx
from materials import get_preset
from tissuerender import load_scene, pipeline
from tissuerender.cli import main
from tissuerender.errors import UserError
from tissuerender.files import write_npy, write_png
from tissuerender.finite import NonFiniteError, check_finite, check_image, frame_at
from tissuerender.renderer import frame as frame_module

LUMP = {"name": "lump", "kind": "body", "shape": "box", "size": [0.04, 0.04, 0.03], "cell_size": 0.02,
        "material": "kidney", "position": [0.02, 0.02, 0.04], "fixed": [{"side": "z_min"}]}


def _scene(scene_dict, write_scene, **effects):
    """The minimal scene with a second body (``lump``) on top of the block, two frames, NumPy effects."""
    scene_dict["objects"].append(dict(LUMP))
    scene_dict["output"]["frames"] = 2
    scene_dict["effects"].update({"backend": "numpy", **effects})
    path = write_scene(scene_dict)
    return path, load_scene(path)


def _on_frame_2(monkeypatch, change):
    """Apply ``change(objects)`` to the render objects of frame 2 only (t > 0), on copies."""
    real = pipeline.render_objects

    def objects_of_the_frame(world, scene, t, *args, **kwargs):
        objects, positions = real(world, scene, t, *args, **kwargs)
        if t > 0.0:
            objects = [dataclasses.replace(o, points=np.array(o.points, float)) for o in objects]
            change(objects)
        return objects, positions

    monkeypatch.setattr(pipeline, "render_objects", objects_of_the_frame)


def _fails_on_frame_2(scene, out) -> str:
    with pytest.raises(UserError) as err:
        pipeline.render(scene, out, progress=False)
    assert isinstance(err.value, NonFiniteError)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{scene.path}: frame 2: stage ")
    assert (out / "frame_0001.png").exists()  # frame 1 was fine
    assert not (out / "frame_0002.png").exists() and not list(out.glob(".frame_0002*"))  # nothing of frame 2
    return message


def test_check_finite_names_the_count_the_first_entry_and_its_object():
    values = np.zeros((5, 3))
    values[3, 1] = np.nan
    values[4, 0] = -np.inf
    with pytest.raises(NonFiniteError) as err:
        check_finite(values, "radiance", "shade", object_of=lambda i: [0, 0, 0, 7, 7][i])
    e = err.value.located("s.toml", 4, ["a"] * 7 + ["liver"])
    assert (e.count, e.first, e.object_index, e.object_name, e.frame) == (2, (3, 1), 7, "liver", 4)
    assert str(e) == ("s.toml: frame 4: stage shade: 2 non-finite radiance (first at (3, 1), object 'liver': nan); "
                      "nothing of this frame was written")


def test_thickness_may_be_inf_but_not_nan_or_negative_inf():
    check_finite(np.array([0.01, np.inf]), "thickness", "thickness", allow_inf=True)  # inf: nothing within reach
    for bad in (np.nan, -np.inf):
        with pytest.raises(NonFiniteError, match="stage thickness: 1 non-finite thickness"):
            check_finite(np.array([0.01, np.inf, bad]), "thickness", "thickness", allow_inf=True)


def test_check_image_counts_pixels_not_channels_and_names_the_covering_object():
    image = np.ones((4, 6, 3), np.float32)
    image[2, 5] = np.nan  # three channels, one pixel
    image[3, 0, 1] = np.inf
    with pytest.raises(NonFiniteError) as err:
        check_image(image, "radiance", "resolve", lambda row, col: 2 if (row, col) == (2, 5) else None)
    assert (err.value.count, err.value.first, err.value.object_index) == (2, (2, 5), 2)
    assert "2 pixel(s) with non-finite radiance (first at pixel (2, 5), object #2" in str(err.value)


def test_frame_numbers_follow_the_frame_times():
    assert [frame_at((k - 1) / 24.0, 24.0) for k in (1, 2, 3, 250)] == [1, 2, 3, 250]


def test_a_nan_vertex_stops_frame_2_at_the_raster_stage_naming_the_object(scene_dict, write_scene, tmp_path,
                                                                         monkeypatch):
    _, scene = _scene(scene_dict, write_scene)

    def nan_vertex(objects):
        objects[1].points[5, 2] = np.nan

    _on_frame_2(monkeypatch, nan_vertex)
    message = _fails_on_frame_2(scene, tmp_path / "out")
    assert "stage raster: 1 non-finite vertex positions (first at (5, 2), object 'lump': nan)" in message


def test_nan_optics_stop_the_frame_at_shade_naming_the_pixels_the_object_covers(scene_dict, write_scene,
                                                                               tmp_path, monkeypatch):
    _, scene = _scene(scene_dict, write_scene)
    covered = pipeline.render_frame_arrays(scene)[1].gbuffer  # frame 1, rendered normally
    lump_pixel_count = int((covered["material_id"] == 1).sum())  # supersampling 1: one point per covered pixel
    assert 0 < lump_pixel_count < np.isfinite(covered["depth"]).sum()

    def nan_albedo(objects):
        optics = get_preset("kidney").optics  # layered: its diffuse colour comes from its layers
        objects[1].optics = dataclasses.replace(optics, layers=dataclasses.replace(
            optics.layers, connective_colour=(math.nan, 0.2, 0.2)))

    _on_frame_2(monkeypatch, nan_albedo)
    message = _fails_on_frame_2(scene, tmp_path / "out")
    assert f"stage shade: {lump_pixel_count} pixel(s) with non-finite radiance (first at pixel (" in message
    assert "object 'lump'" in message and "'block'" not in message


def test_nan_thickness_stops_the_frame_at_the_thickness_stage(scene_dict, write_scene, tmp_path, monkeypatch):
    _, scene = _scene(scene_dict, write_scene, sss=True)
    real = frame_module.thickness_map
    calls = []

    def thickness_with_a_nan(rays, surface, raster, points, *args):
        thickness = real(rays, surface, raster, points, *args)
        calls.append(1)
        if len(calls) == 2:  # frame 2
            thickness[np.flatnonzero(points.material == 0)[3]] = np.nan  # one point of the block
        return thickness

    monkeypatch.setattr(frame_module, "thickness_map", thickness_with_a_nan)
    message = _fails_on_frame_2(scene, tmp_path / "out")
    assert "stage thickness: 1 pixel(s) with non-finite thickness (first at pixel (" in message
    assert message.endswith("object 'block': nan); nothing of this frame was written")


def test_radiance_beyond_float32_stops_the_frame_at_resolve(scene_dict, write_scene, tmp_path, monkeypatch):
    """1e44 W m^-2 sr^-1 is finite in the float64 shading but beyond float32 (3.4e38) in the image."""
    _, scene = _scene(scene_dict, write_scene)
    real = pipeline.light_for
    lights = []

    def blinding(scene):
        lights.append(1)
        light = real(scene)
        return dataclasses.replace(light, radiance=(1e44,) * 3) if len(lights) == 2 else light

    monkeypatch.setattr(pipeline, "light_for", blinding)
    message = _fails_on_frame_2(scene, tmp_path / "out")
    assert "stage resolve: " in message and "pixel(s) with non-finite radiance" in message and ": inf)" in message


def test_nan_from_an_effect_stops_the_frame_at_that_effect(scene_dict, write_scene, tmp_path, monkeypatch):
    scene_dict["effects"]["bloom"] = {"threshold": 1.0}
    _, scene = _scene(scene_dict, write_scene)
    real = postfx.chain.apply_effect
    calls = []

    def bloom_with_a_nan(name, img, *args, **kwargs):
        out = real(name, img, *args, **kwargs)
        if name == "bloom":
            calls.append(1)
            if len(calls) == 2:
                out = out.copy()
                out[7, 9, 1] = np.nan
        return out

    monkeypatch.setattr(postfx.chain, "apply_effect", bloom_with_a_nan)
    message = _fails_on_frame_2(scene, tmp_path / "out")
    assert "stage postfx.bloom: 1 pixel(s) with non-finite display values (first at pixel (7, 9)" in message


def test_cli_render_exits_2_with_one_line_and_writes_no_frame(scene_dict, write_scene, tmp_path, monkeypatch,
                                                              capsys):
    path, _ = _scene(scene_dict, write_scene)

    def nan_vertex(objects):
        objects[0].points[0, 0] = np.nan

    _on_frame_2(monkeypatch, nan_vertex)
    assert main(["render", str(path), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "frame 2: stage raster" in err and "object 'block'" in err
    assert not (tmp_path / "out" / "frame_0002.png").exists()


def test_to_uint8_refuses_nan_instead_of_writing_black():
    image = np.full((2, 3, 3), 0.5, np.float32)
    assert postfx.to_uint8(image)[0, 0, 0] == 128  # 0.5 * 255 + 0.5 = 128.0
    image[1, 2, 0] = np.nan
    with pytest.raises(postfx.NonFiniteOutput, match=r"to_uint8: 1 pixel\(s\) with non-finite values \(first at "
                                                     r"pixel \(1, 2\)"):
        postfx.to_uint8(image)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_the_writers_refuse_non_finite_values_and_leave_no_file(tmp_path, bad):
    hdr = np.ones((2, 2, 3), np.float32)
    hdr[0, 1, 2] = bad
    with pytest.raises(ValueError, match="refusing to write 1 non-finite values"):
        write_npy(tmp_path / "frame.npy", hdr)
    with pytest.raises(ValueError, match="refusing to write 1 non-finite values"):
        write_png(tmp_path / "frame.png", hdr)
    assert list(tmp_path.iterdir()) == []
    write_npy(tmp_path / "frame.npy", np.ones((2, 2, 3), np.float32))  # finite values are written
    assert np.load(tmp_path / "frame.npy").sum() == 12.0
