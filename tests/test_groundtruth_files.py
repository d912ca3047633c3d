"""The ground truth in other tools' formats (issue 18 items 4 and 5; docs/ground-truth.md, "Other formats" and
"Looking at it"): every file is read back by a standard reader (OpenEXR, Pillow, FFmpeg through PyAV, numpy
following the Middlebury spec) and compared with the ``passes/*.npy`` masters; ``tissuerender show`` draws a
depth panel whose colour is monotone in depth and refuses a folder without passes.

Tolerances: the EXR and ``.flo`` store float32 as is (bit for bit); the depth PNG rounds to its unit (error at
most ``scale / 2``); KITTI rounds to 1/64 px (at most 1/128 px); ``distance`` is float32 depth times a float64
ray length, rounded once more to float32 (at most one float32 ulp, ``2^-23`` relative, off the float64 value).
"""
from __future__ import annotations

import copy
import json
import struct

import numpy as np
import pytest
import tomli_w
from PIL import Image

import tissuerender
from tissuerender.cli import main
from tissuerender.groundtruth import formats
from tissuerender.show import contact_sheet, depth_lut, flow_colours

TOP = 0.02
# a static box seen from above at about 52 degrees from its top face's normal: depth varies across the image
TILTED = {
    "scene": {"name": "tilted", "seed": 3},
    "objects": [{"name": "slab", "kind": "body", "shape": "box", "size": [0.1, 0.1, TOP], "cell_size": 0.02,
                 "material": "liver", "fixed": [{"side": "z_min"}]}],
    "simulation": {"integrator": "none"},
    "camera": {"position": [0.05, -0.12, 0.15], "look_at": [0.05, 0.05, TOP], "fov_deg": 50.0, "far": 1.0},
    "light": {"attach": "camera", "size": [0.02, 0.02], "radiance": [3000.0, 3000.0, 3000.0], "samples": 4},
    "effects": {"tonemap": {}},
    "output": {"resolution": [64, 48], "frames": 2, "fps": 12.0,
               "formats": ["png", "hdr_npy", "exr", "depth_png", "mp4"],
               "passes": ["depth", "normal", "segmentation", "material_coords"]},
}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("files")
    path = tmp / "tilted.toml"
    path.write_text(tomli_w.dumps(TILTED))
    out = tmp / "out"
    run = tissuerender.render(tissuerender.load_scene(path), out, progress=False)
    return out, run


def _npy(out, name, k=1):
    return np.load(out / "passes" / f"{name}_{k:04d}.npy")


def _read_exr(path):
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {name: c.pixels for name, c in f.channels().items()}


def _same_bits(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_exr_layers_are_the_npy_passes_bit_for_bit(rendered):
    out, run = rendered
    assert {"write_exr", "write_depth_png", "write_mp4"} <= set(run.recorder.calls)
    channels = _read_exr(out / "frame_0002.exr")
    assert set(channels) == {"R", "G", "B", "depth.Z", "distance.Z", "normal.X", "normal.Y", "normal.Z",
                             "segmentation.id", "material_coords.X", "material_coords.Y", "material_coords.Z"}
    hdr = np.load(out / "frame_0002.npy")
    for i, c in enumerate("RGB"):
        assert _same_bits(channels[c], np.ascontiguousarray(hdr[..., i]))
    depth = _npy(out, "depth", 2)
    assert _same_bits(channels["depth.Z"], depth)  # inf (nothing seen) kept as inf
    for i, axis in enumerate("XYZ"):
        assert _same_bits(channels[f"normal.{axis}"], np.ascontiguousarray(_npy(out, "normal", 2)[..., i]))
        assert _same_bits(channels[f"material_coords.{axis}"],
                          np.ascontiguousarray(_npy(out, "material_coords", 2)[..., i]))
    ids = channels["segmentation.id"]
    assert ids.dtype == np.uint32 and np.array_equal(ids, _npy(out, "segmentation", 2))
    # distance: the camera-space point's length; equal to the depth on the optical axis, longer off it
    K = np.array(json.loads((out / "cameras.json").read_text())["K"])
    v, u = np.mgrid[0:48, 0:64]
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    seen = np.isfinite(depth)
    expected = depth[seen] * np.sqrt(1 + x[seen] ** 2 + y[seen] ** 2)
    assert seen.sum() > 500 and np.isinf(channels["distance.Z"][~seen]).all()
    assert (np.abs(channels["distance.Z"][seen] - expected) <= 2.0 ** -23 * expected).all()
    assert (channels["distance.Z"][seen] >= depth[seen]).all()


def test_depth_png_reads_back_in_pillow_within_half_its_unit(rendered):
    out, _ = rendered
    scale = json.loads((out / "cameras.json").read_text())["depth_png_scale"]
    assert scale == 1e-4  # far = 1 m fits 0.1 mm units
    image = Image.open(out / "passes" / "depth_0001.png")
    assert image.mode == "I;16" and image.size == (64, 48)
    units = np.asarray(image).astype(np.int64)
    depth = _npy(out, "depth").astype(float)
    seen = np.isfinite(depth)
    assert np.array_equal(units == 0, ~seen)
    # float64 division and rounding of a float32 depth: off by at most half a unit, plus float64 rounding
    assert (np.abs(units[seen] * scale - depth[seen]) <= scale / 2 * (1 + 1e-12)).all()


def test_preview_mp4_decodes_with_every_frame_at_the_render_size(rendered):
    import av

    out, _ = rendered
    with av.open(str(out / "preview.mp4")) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) == 2 and frames[0].shape == (48, 64, 3)
    png = np.asarray(Image.open(out / "frame_0001.png").convert("RGB")).astype(float)
    # lossy but close: the mean colour difference is a few levels of 255
    assert np.abs(frames[0] - png).mean() < 8


def _synthetic_flow():
    rng = np.random.default_rng(7)
    flow = rng.uniform(-40, 40, (6, 9, 2)).astype(np.float32)
    flow[0, 0] = np.nan  # no flow (nothing seen)
    flow[1, 2] = [600.0, 0.0]  # beyond KITTI's 16 bits (|u| < 512)
    flow[2, 3] = [-512.0, 511.98]  # the edges of its range
    return flow


def _read_flo(path):
    """A numpy reader following the Middlebury flow-code README: float32 202021.25, int32 width, int32 height,
    then width * height * 2 float32 (u, v) row by row, little-endian."""
    data = path.read_bytes()
    magic, w, h = struct.unpack("<fii", data[:12])
    assert magic == 202021.25
    return np.frombuffer(data[12:], "<f4").reshape(h, w, 2)


def _read_png16(path):
    """FFmpeg's PNG decoder (through PyAV) as 16-bit RGB; Pillow reduces 48-bit PNGs to 8 bits."""
    import av

    with av.open(str(path)) as container:
        frame = next(container.decode(video=0))
    assert frame.format.name == "rgb48be"
    return frame.reformat(format="rgb48le").to_ndarray()


def test_flo_and_kitti_files_read_back_to_the_flow(tmp_path):
    flow = _synthetic_flow()
    written = formats.write_flow_files(tmp_path, 3, {"flow_forward": flow})
    assert [p.name for p in written] == ["flow_forward_0003.flo", "flow_forward_0003.png"]
    flo = _read_flo(tmp_path / "passes" / "flow_forward_0003.flo")
    known = np.isfinite(flow).all(axis=2)
    assert np.array_equal(flo[known], flow[known]) and (flo[~known] == 1e10).all()
    coded = _read_png16(tmp_path / "passes" / "flow_forward_0003.png")
    assert coded.shape == (6, 9, 3)
    valid = coded[..., 2] == 1
    # the KITTI devkit's decoding: (value - 2^15) / 64 where the third channel is set
    decoded = (coded[..., :2].astype(float) - 2 ** 15) / 64.0
    expect_valid = known & ((flow >= -512) & (flow < 511.992)).all(axis=2)  # (2^16 - 1 - 2^15 + 1/2) / 64
    assert np.array_equal(valid, expect_valid) and not valid[1, 2] and valid[2, 3]
    assert (np.abs(decoded[valid] - flow[valid]) <= 1 / 128).all()
    assert (coded[~valid] == 0).all()


def test_exr_carries_the_motion_layers_a_frame_has(tmp_path):
    h, w = 4, 5
    rng = np.random.default_rng(1)
    passes = {"flow_forward": rng.normal(size=(h, w, 2)).astype(np.float32),
              "occluded_forward": rng.random((h, w)) < 0.5,
              "scene_flow_backward": rng.normal(size=(h, w, 3)).astype(np.float32)}
    passes["flow_forward"][0, 0] = np.nan
    formats.write_exr(tmp_path / "f.exr", np.ones((h, w, 3), np.float32), passes)
    channels = _read_exr(tmp_path / "f.exr")
    assert set(channels) == {"R", "G", "B", "flow_forward.X", "flow_forward.Y", "occluded_forward.mask",
                             "scene_flow_backward.X", "scene_flow_backward.Y", "scene_flow_backward.Z"}
    assert _same_bits(channels["flow_forward.Y"], np.ascontiguousarray(passes["flow_forward"][..., 1]))
    assert np.array_equal(channels["occluded_forward.mask"], passes["occluded_forward"].astype(np.uint32))
    assert _same_bits(channels["scene_flow_backward.Z"], np.ascontiguousarray(passes["scene_flow_backward"][..., 2]))


def test_flow_masters_written_after_the_frames_get_their_files_and_exr_layers(rendered, tmp_path):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(rendered[0], out)
    flow = _synthetic_flow()[:, :, :].repeat(8, axis=0).repeat(8, axis=1)[:48, :64]
    np.save(out / "passes" / "flow_forward_0001.npy", flow)
    written = formats.complete_from_masters(out, [1, 2], ["png", "exr"])
    assert sorted(p.name for p in written) == ["flow_forward_0001.flo", "flow_forward_0001.png"]
    channels = _read_exr(out / "frame_0001.exr")
    assert _same_bits(channels["flow_forward.X"], np.ascontiguousarray(flow[..., 0]))
    assert _same_bits(channels["depth.Z"], _npy(out, "depth"))  # the frame's own layers kept
    assert formats.complete_from_masters(out, [1, 2], ["png", "exr"]) == []  # up to date: nothing rewritten


def test_flow_colours_follow_the_middlebury_wheel():
    flow = np.array([[[0.0, 0.0], [2.0, 0.0], [-2.0, 0.0], [1.0, 0.0], [4.0, 0.0], [np.nan, 1.0]]])
    rgb = flow_colours(flow, max_radius=2.0)
    assert rgb[0, 0].tolist() == [255, 255, 255]  # no motion: white
    assert rgb[0, 1].tolist() == [255, 0, 0]  # rightwards at full radius: the wheel's first colour, red
    assert rgb[0, 2, 0] < 50 and rgb[0, 2, 2] > 200  # leftwards: cyan to blue, opposite red
    assert rgb[0, 3].tolist() == [255, 128, 128]  # half the radius: half saturated
    assert rgb[0, 4].tolist() == [191, 0, 0]  # beyond the radius: darkened to 75 %
    assert rgb[0, 5].tolist() == [0, 0, 0]  # no flow: black


def test_show_sheet_depth_panel_is_monotone_in_depth(rendered, tmp_path, capsys):
    out, _ = rendered
    sheet_path = tmp_path / "sheet.png"
    assert main(["show", str(out), "-o", str(sheet_path), "--frame", "2"]) == 0
    sheet = np.asarray(Image.open(sheet_path).convert("RGB"))
    _, layout, s = contact_sheet(out, 2)
    assert set(layout) == {"colour + outlines", "depth (near bright)", "normal (camera axes)", "segmentation",
                           "material_coords"}
    x0, y0, x1, y1 = layout["depth (near bright)"]
    panel = sheet[y0 + s // 2:y1:s, x0 + s // 2:x1:s].astype(int)  # one sample per rendered pixel
    depth = _npy(out, "depth", 2)
    assert panel.shape[:2] == depth.shape
    seen = np.isfinite(depth)
    assert (panel[~seen] == 0).all()
    lut = depth_lut().astype(int)
    index = np.argmin(((panel[seen][:, None, :] - lut[None]) ** 2).sum(axis=2), axis=1)
    assert (((panel[seen] - lut[index]) ** 2).sum(axis=1) == 0).all()  # every depth colour is a LUT colour
    order = np.argsort(depth[seen], kind="stable")
    assert (np.diff(index[order]) <= 0).all()  # farther: never brighter in the map
    assert index.max() - index.min() >= 250  # the map spans the colour range


def test_show_writes_a_video_of_the_sheets(rendered, tmp_path):
    import av

    out, _ = rendered
    assert main(["show", str(out), "-o", str(tmp_path / "sheets.mp4")]) == 0
    sheet = contact_sheet(out, 1)[0]
    with av.open(str(tmp_path / "sheets.mp4")) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) == 2 and frames[0].shape == sheet.shape


def test_show_refuses_a_folder_without_passes_in_one_line(rendered, tmp_path, capsys):
    empty = tmp_path / "render"
    empty.mkdir()
    Image.new("RGB", (8, 8)).save(empty / "frame_0001.png")
    cases = [([str(empty), "-o", str(tmp_path / "a.png")], [str(empty), "no ground-truth passes"]),
             ([str(tmp_path / "missing"), "-o", str(tmp_path / "a.png")], ["missing", "expected a render output"]),
             ([str(rendered[0]), "-o", str(tmp_path / "a.gif")], ["a.gif", "expected a .png", ".gif"]),
             ([str(rendered[0]), "-o", str(tmp_path / "a.png"), "--frame", "7"], ["--frame 7", "1-2"])]
    for args, words in cases:
        assert main(["show", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and all(w in err for w in words), err
    assert not (tmp_path / "a.png").exists()


def test_new_formats_are_planned_only_when_asked_and_need_what_they_are_made_from(tmp_path, capsys):
    plain = copy.deepcopy(TILTED)
    plain["output"]["formats"] = ["png"]
    path = tmp_path / "plain.toml"
    path.write_text(tomli_w.dumps(plain))
    names = tissuerender.make_plan(tissuerender.load_scene(path)).names
    assert not {"write_exr", "write_depth_png", "write_mp4"} & set(names)
    for formats_, passes, words in ((["mp4"], ["depth"], ["output.formats", "mp4", "png"]),
                                    (["png", "depth_png"], ["normal"], ["output.formats", "depth_png", "depth"])):
        bad = copy.deepcopy(TILTED)
        bad["output"].update(formats=formats_, passes=passes)
        path = tmp_path / "bad.toml"
        path.write_text(tomli_w.dumps(bad))
        assert main(["validate", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and all(w in err for w in words), err


def test_resume_renders_again_a_frame_whose_exr_is_missing(rendered, tmp_path):
    import shutil

    out, run = rendered
    copy_ = tmp_path / "resumed"
    shutil.copytree(out, copy_)
    (copy_ / "frame_0002.exr").unlink()
    again = tissuerender.render(tissuerender.load_scene(run.manifest["scene"]), copy_, resume=True, progress=False)
    assert [p.name for p in again.skipped] == ["frame_0001.png"]
    assert {"frame_0002.exr", "depth_0002.png", "preview.mp4"} <= {p.name for p in again.written}
    assert again.manifest["formats"] == ["png", "hdr_npy", "exr", "depth_png", "mp4"]
    assert _same_bits(_read_exr(copy_ / "frame_0002.exr")["depth.Z"], _read_exr(out / "frame_0002.exr")["depth.Z"])


def test_show_draws_flow_and_tracks_hollow_where_occluded(rendered, tmp_path):
    import shutil

    out = tmp_path / "with_tracks"
    shutil.copytree(rendered[0], out)
    flow = np.zeros((48, 64, 2), np.float32)
    flow[:, :, 0] = np.linspace(-3, 3, 64)[None, :]  # leftwards on the left, rightwards on the right
    np.save(out / "passes" / "flow_forward_0001.npy", flow)
    points = np.array([[[20.0, 30.0], [20.0, 30.0]], [[40.0, 12.0], [40.0, 12.0]]])  # (N, T, 2) x, y
    occluded = np.array([[False, False], [True, True]])
    np.savez(out / "tracks.npz", query_points=np.zeros((2, 3)), points_2d=points, points_3d=np.zeros((2, 2, 3)),
             occluded=occluded)
    sheet, layout, s = contact_sheet(out, 1)
    x0, y0, x1, y1 = layout["flow_forward"]
    assert np.array_equal(sheet[y0 + s // 2:y1:s, x0 + s // 2:x1:s], flow_colours(flow))
    x0, y0, _, _ = layout["tracks (ring: occluded)"]
    colour = np.asarray(Image.open(out / "frame_0001.png").convert("RGB"))

    def at(x, y, dx=0):  # the sheet pixel at rendered pixel (x, y)'s centre, dx sheet pixels to the right
        return sheet[y0 + int((y + 0.5) * s), x0 + int((x + 0.5) * s) + dx]

    assert not np.array_equal(at(20, 30), colour[30, 20])  # visible: a filled dot over the pixel
    assert np.array_equal(at(40, 12), colour[12, 40])  # occluded: the centre shows the frame through the ring
    assert not np.array_equal(at(40, 12, dx=s), colour[12, 40])  # ... and the ring is drawn around it


def test_exr_without_passes_holds_the_colour_and_a_resume_keeps_it(tmp_path):
    data = copy.deepcopy(TILTED)
    data["output"].update(frames=1, formats=["hdr_npy", "exr"], passes=[])
    path = tmp_path / "colour.toml"
    path.write_text(tomli_w.dumps(data))
    scene = tissuerender.load_scene(path)
    tissuerender.render(scene, tmp_path / "out", progress=False)
    channels = _read_exr(tmp_path / "out" / "frame_0001.exr")
    hdr = np.load(tmp_path / "out" / "frame_0001.npy")
    assert set(channels) == {"R", "G", "B"} and _same_bits(channels["G"], np.ascontiguousarray(hdr[..., 1]))
    again = tissuerender.render(scene, tmp_path / "out", resume=True, progress=False)
    assert [p.name for p in again.skipped] == ["frame_0001.png"] and again.written == []


def test_ray_distance_through_a_fisheye_lens_is_depth_over_cos_theta():
    """With a lens, a pixel's ray is its undistorted one: for a plane at camera z = d every pixel's distance is
    d / cos(theta), theta the ray's angle from the axis, found here independently by bracketing the model's
    theta_d(theta) = r_d (OpenCV fisheye: theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)). The lens
    inverts the same polynomial by Newton to ~1e-15 rad; float32 storage of the distance bounds the error by
    2^-24 relative."""
    from scipy.optimize import brentq

    from tissuerender.groundtruth.formats import ray_distance
    from tissuerender.groundtruth.lens import fisheye_lens
    from tissuerender.renderer.camera import Camera

    k = (-0.02, 0.003, 0.0, 0.0)
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0), fov_deg=100.0,
                    near=0.001, far=1.0, width=32, height=24)
    lens = fisheye_lens(camera, k)
    d = 0.05
    distance = ray_distance(np.full((24, 32), d, np.float32), lens.K, lens)
    fx, cx, cy = lens.K[0, 0], lens.K[0, 2], lens.K[1, 2]
    for v, u in [(0, 0), (23, 31), (12, 5), (3, 20)]:
        r_d = np.hypot((u - cx) / fx, (v - cy) / fx)
        theta = brentq(lambda t: t * (1 + t**2 * (k[0] + t**2 * (k[1] + t**2 * (k[2] + t**2 * k[3])))) - r_d,
                       0.0, np.pi / 2 - 1e-9, xtol=1e-15)
        assert distance[v, u] == pytest.approx(d / np.cos(theta), rel=2.0**-23)
    # without the lens the same pixels would be read as a pinhole's, which is measurably different at the corner
    assert abs(ray_distance(np.full((24, 32), d, np.float32), lens.K)[0, 0] - distance[0, 0]) > 1e-3 * d
