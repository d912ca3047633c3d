"""``tissuerender lookdev`` and the scene's ``[objects.optics]`` table: what an optical value changes in the
pixels, that the printed table reproduces the look, and that bad values are refused by name."""
from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from trimesh.exchange.ply import export_ply

from materials import get_preset
from sim.mesh.io import read_surface
from tissuerender import lookdev
from tissuerender.cli import main
from tissuerender.errors import SceneError
from tissuerender.pipeline import render_image
from tissuerender.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--resolution", "64x48", "--samples", "4", "-q"]


def _run(tmp_path, *args, name="sheet.png"):
    out = tmp_path / name
    assert main(["lookdev", *args, *SMALL, "-o", str(out)]) == 0
    return out, json.loads(out.with_suffix(".json").read_text())


def test_roughness_sweep_sharpens_the_highlight_and_keeps_the_energy(tmp_path):
    out, report = _run(tmp_path, "liver", "--sweep", "coat_roughness=[0.08, 0.6]")
    sheet = np.asarray(Image.open(out))
    assert report["cell_size"] == [64, 48] and report["label_px"] == lookdev.LABEL_PX  # labels fit on one line
    assert sheet.shape == (48 + lookdev.LABEL_PX, 2 * 64, 3)
    smooth, rough = report["cells"]
    assert [c["overrides"] for c in report["cells"]] == [{"coat_roughness": 0.08}, {"coat_roughness": 0.6}]
    assert smooth["object_pixels"] == rough["object_pixels"] > 1000  # same sphere, same view
    # the wet coat's GGX lobe narrows (liver is layered: its highlight is the coat's): a much brighter peak,
    # about the same reflected power over the sphere
    assert smooth["peak_luminance"] > 3.0 * rough["peak_luminance"]
    np.testing.assert_allclose(smooth["mean_linear_rgb"], rough["mean_linear_rgb"], rtol=0.02)
    # the cells differ where the highlight is, not in the label strip's layout
    assert np.abs(sheet[:48, :64].astype(int) - sheet[:48, 64:].astype(int)).max() > 40


def test_grey_albedo_scales_the_diffuse_light(tmp_path):
    _, report = _run(tmp_path, "liver", "--set", "k_sss=0", "--sweep", "albedo=[[0.2, 0.2, 0.2], [0.4, 0.4, 0.4]]")
    dark, light = (np.array(c["mean_linear_rgb"]) for c in report["cells"])
    # a grey Lambertian surface returns the light's colour (radiance 1 : 0.96 : 0.9)
    np.testing.assert_allclose(dark / dark[0], [1.0, 0.96, 0.90], rtol=0.01)
    # doubling the albedo doubles the diffuse part; the specular part stays (the wet coat's Fresnel ~0.02-0.06
    # and the tissue lobe's F0 = 0.027 under it: about a sixth of the dark cell's light, measured 1.83)
    ratio = light / dark
    assert np.all((ratio > 1.75) & (ratio < 2.0)), ratio
    assert report["set"] == {"k_sss": 0}


def test_overriding_with_the_preset_values_changes_no_pixel():
    optics = get_preset("kidney").optics
    same = {"albedo": list(optics.albedo), "roughness": optics.roughness, "ior": optics.ior,
            "k_sss": optics.k_sss, "sigma": list(optics.sigma), "sss_colour": list(optics.sss_colour)}
    cells = [lookdev.Cell("kidney", {}, "preset"), lookdev.Cell("kidney", same, "same values")]
    images, stats = lookdev.render_cells(cells, resolution=(48, 36), samples=4)
    np.testing.assert_array_equal(images[0], images[1])
    assert stats[0]["mean_linear_rgb"] == stats[1]["mean_linear_rgb"]


def test_the_printed_table_reproduces_the_look_in_a_scene(tmp_path):
    """lookdev --scene with a value == the scene with lookdev's [objects.optics] table, to the pixel."""
    scene_path = tmp_path / "kidney.toml"
    shutil.copy(ROOT / "scenes" / "kidney_static.toml", scene_path)
    cells, *_ = lookdev.make_cells(["kidney"], ["roughness=0.12"], ["ior=[1.33, 1.6]"])
    images, stats = lookdev.render_cells(cells, scene_path=str(scene_path), resolution=(64, 48), samples=4)
    base = render_image(load_scene(scene_path), resolution=(64, 48))
    assert not np.array_equal(images[0], base)
    text = scene_path.read_text()
    for image, stat in zip(images, stats):
        assert stat["optics_toml"].startswith("[objects.optics]\nroughness = 0.12\nior = ")
        edited = tmp_path / "edited.toml"
        # the scene's only object is its first [[objects]] table: the optics table goes right after it
        first = text.index("[[objects]]")
        nxt = text.find("\n[", first + 1)
        edited.write_text(text[:nxt] + "\n" + stat["optics_toml"] + text[nxt:])
        scene = load_scene(edited)
        assert scene.objects[0].optics.values()["roughness"] == 0.12
        scene = _with_samples(scene, 4)
        np.testing.assert_array_equal(render_image(scene, resolution=(64, 48)), image)
    assert stats[1]["peak_luminance"] > stats[0]["peak_luminance"]  # higher ior: stronger Fresnel highlight


def _with_samples(scene, samples):
    return dataclasses.replace(scene, light=scene.light.model_copy(update={"samples": samples}))


@pytest.mark.parametrize("table, key, words", [
    ("material = \"plastic\"\n[objects.optics]\ncoat_roughness = 0.1", "objects[0].optics.coat_roughness",
     "no layer stack"),
    ("material = \"plastic\"\n[objects.optics]\nsigma = [1.0, 2.0, 3.0]", "objects[0].optics.sigma", "subsurface"),
    ("material = \"liver\"\n[objects.optics]\nroughness = 1.5", "objects[0].optics.roughness", "less than or equal"),
    ("material = \"liver\"\n[objects.optics]\nglossiness = 0.5", "objects[0].optics.glossiness", "unknown key"),
])
def test_scene_optics_errors_name_the_key(tmp_path, table, key, words):
    path = tmp_path / "bad.toml"
    path.write_text("[scene]\nname = \"bad\"\n[[objects]]\nname = \"o\"\nshape = \"slab\"\n" + table
                    + "\n[camera]\nposition = [0, -0.3, 0.1]\nlook_at = [0, 0, 0]\n")
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert f"{path}: {key}: " in str(err.value) and words in str(err.value)


def test_a_bad_scene_stage_is_reported_as_the_scene_error(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text((ROOT / "scenes" / "kidney_static.toml").read_text().replace('material = "kidney"',
                                                                               'material = "kidney"\noptics = "shiny"'))
    assert main(["lookdev", "kidney", "--scene", str(path), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: objects[0].optics: expected") and err.count("\n") == 1, err


@pytest.mark.parametrize("args, words", [
    (["livr"], "material: expected one of liver"),
    (["liver", "--set", "roughness=2"], "--set roughness: expected input should be less than or equal to 1"),
    (["liver", "--set", "rough=0.3"], "--set rough: not an optical key"),
    (["liver", "--set", "albedo=[0.5, 0.2"], "--set albedo: expected a TOML value"),
    (["liver", "--set", "albedo=[0.5, 0.2]"], "--set albedo: expected list should have at least 3 items"),
    (["liver", "--set", "roughness"], "--set: expected KEY=VALUE"),
    (["plastic", "--set", "coat_ior=1.3"], "--set coat_ior: a layer key"),
    (["plastic", "--sweep", "k_sss=[0, 0.5]"], "--sweep k_sss: the plastic reference"),
    (["liver", "--sweep", "roughness=0.3"], "--sweep roughness: expected a non-empty TOML list"),
    (["liver", "--set", "ior=1.4", "--sweep", "ior=[1.3, 1.5]"], "--sweep ior: the key is already set or swept"),
    (["liver", "--sweep", "ior=[1.3]", "--sweep", "k_sss=[0]", "--sweep", "roughness=[0.2]"], "at most 2 (rows and columns), found 3"),
    (["liver", "--sweep", f"ior={[1.0 + k / 100 for k in range(9)]}", "--sweep", f"k_sss={[k / 10 for k in range(8)]}"],
     "at most 64 cells, found 8 x 9 = 72"),
    (["liver", "fat", "--sweep", "ior=[1.3]", "--sweep", "k_sss=[0]"], "at most 1 (columns; the materials are the rows)"),
    (["liver", "liver"], "material: each material once"),
    (["liver", "plastic", "--set", "granular_weight=0.5"], "--set granular_weight: a layer key"),
    (["liver", "fat", "--scene", str(ROOT / "scenes" / "default.toml")], "no object is made of 'fat'"),
    (["kidney", "--scene", str(ROOT / "scenes" / "default.toml")], "no object is made of 'kidney'"),
    (["liver", "--resolution", "10x"], "--resolution: expected WxH"),
    (["liver", "--samples", "0"], "--samples: expected 1 ... 1024"),
])
def test_cli_errors_exit_2_with_one_line(tmp_path, capsys, args, words):
    assert main(["lookdev", *args, "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and words in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.png").exists()


def test_materials_side_by_side(tmp_path):
    out, report = _run(tmp_path, "liver", "fat", "plastic", "--sweep", "roughness=[0.1, 0.5]")
    assert report["label_px"] == 2 * lookdev.LABEL_PX  # "plastic  roughness=0.5" is wider than 64 px: two lines
    assert np.asarray(Image.open(out)).shape == (3 * (48 + 2 * lookdev.LABEL_PX), 2 * 64, 3)
    assert (report["rows"], report["columns"]) == (3, 2)
    assert [c["material"] for c in report["cells"]] == ["liver", "liver", "fat", "fat", "plastic", "plastic"]
    assert report["cells"][2]["label"] == "fat  roughness=0.1"
    liver, fat, plastic = (np.array(report["cells"][k]["mean_linear_rgb"]) for k in (0, 2, 4))
    # the presets' albedos: liver (0.40, 0.09, 0.07) deep red, fat (0.78, 0.65, 0.38) yellow, plastic grey
    assert liver[1] / liver[0] < 0.35 < fat[2] / fat[0] < fat[1] / fat[0] < 0.95
    assert abs(plastic[1] / plastic[0] - 0.96) < 0.03  # grey under the light's colour (1 : 0.96 : 0.9)


def test_sheet_is_deterministic_and_written_atomically(tmp_path):
    a, _ = _run(tmp_path, "fat", "--set", "roughness=0.3", name="a.png")
    b, report = _run(tmp_path, "fat", "--set", "roughness=0.3", name="b.png")
    assert a.read_bytes() == b.read_bytes()
    assert report["cells"][0]["optics_toml"] == "[objects.optics]\nroughness = 0.3\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "a.png", "b.json", "b.png"]  # no temp files


def test_binary_ply_with_vertex_normals_keeps_them(tmp_path):
    """A binary PLY (as trimesh writes it) holds its vertex data as a structured array: its normals are read."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    path = tmp_path / "sphere.ply"
    path.write_bytes(export_ply(sphere, encoding="binary", vertex_normal=True))
    surface = read_surface(path)
    radial = surface.points / np.linalg.norm(surface.points, axis=1, keepdims=True)
    assert surface.normals is not None
    assert np.einsum("ij,ij->i", surface.normals, radial).min() > 0.999


@pytest.mark.parametrize("shape", ["liver", "kidney"])
def test_organ_stages_frame_the_organ(tmp_path, shape):
    _, report = _run(tmp_path, "liver", "--shape", shape)
    covered = report["cells"][0]["object_pixels"] / (64 * 48)
    assert 0.25 < covered < 0.9, covered  # in view, not cut off by the frame
    lum = np.array(report["cells"][0]["mean_linear_rgb"]) @ lookdev.LUMA
    assert 0.02 < lum < 0.5, lum  # exposed like the sphere: neither black nor blown out


def test_object_pixels_with_supersampling_are_the_wholly_covered_ones(tmp_path):
    """With 2x2 supersampling a pixel counts when all four samples show the object: the count is at most the
    1x1 count plus the silhouette, and at least it minus the silhouette."""
    text = (ROOT / "scenes" / "kidney_static.toml").read_text()
    counts = {}
    for ss in (1, 2):
        path = tmp_path / f"ss{ss}.toml"
        path.write_text(text.replace("[output]", f"[output]\nsupersampling = {ss}"))
        cells, *_ = lookdev.make_cells(["kidney"], ["roughness=0.2"], [])
        _, stats = lookdev.render_cells(cells, scene_path=str(path), resolution=(96, 72), samples=4)
        counts[ss] = stats[0]["object_pixels"]
    assert 0.8 * counts[1] < counts[2] <= counts[1] + 5 and counts[1] > 200, counts


@pytest.mark.parametrize("out, words", [
    ("sheet.jpg", "expected a .png file name for the contact sheet, found suffix '.jpg'"),
    ("sheet", "found suffix 'none'"),
    ("taken.png", "is an existing folder"),
    ("report_taken.png", "report_taken.json is an existing folder"),
    ("a_file/sheet.png", "names an existing file; expected a folder"),
    ("a_file/sub/sheet.png", "cannot create the output folder"),
])
def test_a_bad_output_path_fails_before_any_cell_renders(tmp_path, capsys, monkeypatch, out, words):
    (tmp_path / "taken.png").mkdir()
    (tmp_path / "report_taken.json").mkdir()
    (tmp_path / "a_file").write_text("not a folder")

    def must_not_render(*args, **kwargs):
        raise AssertionError("a cell rendered before the output path was checked")

    monkeypatch.setattr(lookdev, "render_frame_arrays", must_not_render)
    assert main(["lookdev", "liver", *SMALL, "-o", str(tmp_path / out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: -o ") and words in err and err.count("\n") == 1, err

