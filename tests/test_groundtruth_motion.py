"""Motion ground truth (issue 18; docs/ground-truth.md, "Flow, scene flow and tracks"): optical flow, occlusion,
scene flow and point tracks from the known surface motion, checked against the rendered images, the
segmentation and depth passes and ``cameras.json``.

Two small scenes (64 x 48, 3 frames):

- ``STRETCH``: a textured colon-mucosa slab seen close up from above, stretched in its plane by a prescribed
  displacement, lit only by the uniform ambient light (the area light emits nothing). Its colour is then
  ``albedo(uv) x ambient`` with ``uv`` fixed to the material point, so a pixel's colour travels with the
  tissue: warping frame t+1 back by the forward flow must give frame t, up to the error of interpolating
  frame t+1 between its pixels.
- ``PROBE``: a static liver box (nothing simulated: its points do not move at all) under a visible sphere
  that sweeps across it, so a tissue pixel's segmentation changes exactly where the probe covers or
  uncovers it.

Tolerances. *Bilinear interpolation* of an image ``g`` sampled at integer pixels errs, inside a cell, by at
most ``(1/8) max|g_xx|`` per axis for a smooth ``g``; for a ``g`` that is piecewise linear between samples
with one slope kink of jump ``s`` in the cell (the texture is magnified about 2x and sampled bilinearly, so
the image is of that kind) the error is at most ``s/4`` while the second difference at one of the cell's
ends is at least ``s/2``: so ``(1/2) max |second difference|`` over the cell's four corners, per axis and
summed over the two axes, bounds it in either case (``_bilinear``). *float32*: a stored value is rounded by at
most ``2^-24`` relative (``F32``); the geometry behind the motion passes is stored as float32, so a track's
3D point differs from the float64 surface the depth pass saw by about ``2^-24`` of the coordinates' size.
"""
from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
import tomli_w

import tissuerender
from tissuerender import groundtruth, load_scene, make_plan
from tissuerender.errors import SceneError
from tissuerender.pipeline import render

F32 = 2.0 ** -24
TOP = 0.004  # the stretched slab's top face [m]

STRETCH = {
    "scene": {"name": "stretch", "seed": 3},
    "objects": [{"name": "mucosa", "kind": "body", "shape": "box", "size": [0.02, 0.02, TOP], "cell_size": 0.002,
                 "material": "colon_mucosa", "fixed": [{"side": "x_min"}],
                 "prescribed": [{"side": "x_max", "displacement": [0.0006, 0.0002, 0.0], "t_end": 0.125}]}],
    "simulation": {"integrator": "xpbd", "dt": 1.0 / 240.0, "substeps": 4, "iterations": 10,
                   "gravity": [0.0, 0.0, 0.0]},
    # 1 cm above the top face, 20 degrees: about 0.05 mm per pixel, the 0.12 mm texels magnified about 2x
    "camera": {"position": [0.01, 0.01, 0.014], "look_at": [0.01, 0.01, TOP], "up": [0.0, 1.0, 0.0],
               "fov_deg": 20.0, "near": 0.001},
    "light": {"attach": "camera", "size": [0.002, 0.002], "radiance": [0.0, 0.0, 0.0], "samples": 1},
    "effects": {"ambient": [1.0, 1.0, 1.0]},
    "output": {"resolution": [64, 48], "frames": 3, "fps": 24.0, "formats": ["hdr_npy", "png"],
               "passes": ["depth", "segmentation", "flow", "scene_flow", "tracks"], "track_points": 40},
}

PROBE = {
    "scene": {"name": "probe", "seed": 8},
    "objects": [{"name": "liver", "kind": "body", "shape": "box", "size": [0.06, 0.04, 0.01], "cell_size": 0.01,
                 "material": "liver"}],
    "simulation": {"integrator": "none"},
    # a sphere 1 cm above the box sweeping along x, 9 mm a frame
    "tools": [{"name": "probe", "kind": "sphere", "radius": 0.008,
               "keyframes": [{"t": 0.0, "position": [0.012, 0.02, 0.025]},
                             {"t": 1.0, "position": [0.228, 0.02, 0.025]}]}],
    "camera": {"position": [0.03, 0.02, 0.09], "look_at": [0.03, 0.02, 0.01], "up": [0.0, 1.0, 0.0],
               "fov_deg": 45.0},
    "light": {"attach": "camera", "size": [0.002, 0.002], "radiance": [0.0, 0.0, 0.0], "samples": 1},
    "effects": {"ambient": [1.0, 1.0, 1.0]},
    "output": {"resolution": [64, 48], "frames": 3, "fps": 24.0,
               "passes": ["depth", "segmentation", "flow", "tracks"], "track_points": 5000},
}
TISSUE, TOOL = 1, 2  # PROBE's segmentation ids (labels.json)


def _render(tmp_path_factory, data, name):
    folder = tmp_path_factory.mktemp(name)
    path = folder / "scene.toml"
    path.write_text(tomli_w.dumps(data))
    out = folder / "out"
    render(load_scene(path), out, progress=False)
    return out


@pytest.fixture(scope="module")
def stretch(tmp_path_factory):
    return _render(tmp_path_factory, STRETCH, "stretch")


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    return _render(tmp_path_factory, PROBE, "probe")


def _pass(out, name, k):
    return np.load(out / "passes" / f"{name}_{k:04d}.npy")


def _second_differences(image):
    """Per pixel |second difference| along x and along y (max over channels; edges repeat)."""
    img = image if image.ndim == 3 else image[..., None]
    p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    dxx = np.abs(p[1:-1, 2:] - 2 * p[1:-1, 1:-1] + p[1:-1, :-2]).max(-1)
    dyy = np.abs(p[2:, 1:-1] - 2 * p[1:-1, 1:-1] + p[:-2, 1:-1]).max(-1)
    return dxx, dyy


def _bilinear(image, x, y):
    """(``image`` bilinearly interpolated at pixel positions (x, y), its error bound (module docstring)); x, y
    must lie within [0, W-1] x [0, H-1]."""
    h, w = image.shape[:2]
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    tx, ty = x - x0, y - y0
    if image.ndim == 3:
        tx, ty = tx[..., None], ty[..., None]
    top = image[y0, x0] * (1 - tx) + image[y0, x0 + 1] * tx
    bottom = image[y0 + 1, x0] * (1 - tx) + image[y0 + 1, x0 + 1] * tx
    dxx, dyy = _second_differences(image)

    def cell(a):
        return np.maximum.reduce([a[y0, x0], a[y0, x0 + 1], a[y0 + 1, x0], a[y0 + 1, x0 + 1]])

    return top * (1 - ty) + bottom * ty, 0.5 * (cell(dxx) + cell(dyy))


def _targets(flow):
    h, w = flow.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(float)
    x, y = u + np.nan_to_num(flow[..., 0]), v + np.nan_to_num(flow[..., 1])
    return x, y, (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)


def _warp_violations(out, k, flow):
    """Pixels of frame k (seen, not occluded, landing inside frame k+1's pixel grid) whose colour frame k+1
    warped back by ``flow`` misses by more than the interpolation bound; and how many were checked."""
    a, b = np.load(out / f"frame_{k:04d}.npy"), np.load(out / f"frame_{k + 1:04d}.npy")
    x, y, inside = _targets(flow)
    check = np.isfinite(flow).all(axis=2) & ~_pass(out, "occluded_forward", k) & inside
    warped, bound = _bilinear(b.astype(float), x, y)
    # + float32 rounding of the HDR values (at most 1.0 here)
    error = np.abs(warped - a).max(axis=-1)
    return int((error[check] > bound[check] + 4 * F32).sum()), int(check.sum())


def test_warping_frame_t_plus_1_back_by_the_forward_flow_reproduces_frame_t(stretch):
    for k in (1, 2):
        flow = _pass(stretch, "flow_forward", k)
        assert np.nanmax(np.abs(flow)) > 1.0  # the tissue moves by more than a pixel a frame
        bad, checked = _warp_violations(stretch, k, flow)
        assert checked > 0.9 * 64 * 48 and bad == 0
        # the check can fail: no motion, or the motion half a pixel off, misses on many pixels
        assert _warp_violations(stretch, k, np.zeros_like(flow))[0] > 0.3 * checked
        assert _warp_violations(stretch, k, flow + np.float32([0.5, 0.0]))[0] > 0.03 * checked


def test_without_an_occluder_exactly_the_pixels_leaving_the_image_are_occluded(stretch):
    h, w = 48, 64
    for k in (1, 2):
        flow = _pass(stretch, "flow_forward", k)
        x, y, _ = _targets(flow)
        leaving = (x < -0.5) | (x >= w - 0.5) | (y < -0.5) | (y >= h - 0.5)
        assert leaving.sum() > 0
        np.testing.assert_array_equal(_pass(stretch, "occluded_forward", k), leaving)
    # the first frame has no backward neighbour, the last no forward one: NaN motion, all seen pixels occluded
    for name, k in (("backward", 1), ("forward", 3)):
        assert np.isnan(_pass(stretch, f"flow_{name}", k)).all()
        assert np.isnan(_pass(stretch, f"scene_flow_{name}", k)).all()
        assert _pass(stretch, f"occluded_{name}", k).all()


def test_forward_and_backward_flow_are_consistent(stretch):
    for k in (1, 2):
        forward = _pass(stretch, "flow_forward", k).astype(float)
        backward = _pass(stretch, "flow_backward", k + 1).astype(float)
        x, y, inside = _targets(forward)
        check = ~_pass(stretch, "occluded_forward", k) & inside
        back, bound = _bilinear(backward, x, y)
        # the round trip returns to the pixel, up to interpolating the smooth backward field and float32 rounding
        # of flows of a few pixels
        round_trip = np.abs(forward + back).max(axis=-1)
        check &= np.isfinite(round_trip)
        assert check.sum() > 0.9 * 64 * 48
        assert (round_trip[check] <= bound[check] + 16 * F32 * 4).all()
        assert np.median(round_trip[check]) < 1e-3  # and the fields are not merely both small


def test_scene_flow_moves_the_back_projected_depth_onto_the_forward_flow(stretch):
    doc = __import__("json").loads((stretch / "cameras.json").read_text())
    K = np.array(doc["K"])
    for k in (1, 2):
        depth = _pass(stretch, "depth", k).astype(float)
        T0, T1 = (np.array(doc["frames"][j]["world_to_camera"]) for j in (k - 1, k))
        v, u = np.mgrid[0:48, 0:64].astype(float)
        rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
        X = (depth[..., None] * rays - T0[:3, 3]) @ T0[:3, :3]  # world point of each pixel (cameras.json)
        moved = X + _pass(stretch, "scene_flow_forward", k)
        cam = moved @ T1[:3, :3].T + T1[:3, 3]
        uv = (cam @ K.T)[..., :2] / cam[..., 2:]
        flow = _pass(stretch, "flow_forward", k)
        # float32 depth, scene flow and geometry: each about 2^-24 of 1.4 cm or 2 cm, x 1000 px/m ... far below
        # 1e-3 px; the largest error is the float32 scene flow's absolute rounding of world coordinates
        np.testing.assert_allclose(uv - np.stack([u, v], -1), flow, atol=1e-3)


def test_occlusion_flags_exactly_the_tissue_the_probe_covers_and_uncovers(probe):
    for k in (1, 2):
        seg, nxt = _pass(probe, "segmentation", k), _pass(probe, "segmentation", k + 1)
        tissue = seg == TISSUE
        # static tissue: its points stay on their pixels
        assert np.abs(_pass(probe, "flow_forward", k)[tissue]).max() == 0.0
        covered = tissue & (nxt == TOOL)
        uncovered = (nxt == TISSUE) & (seg == TOOL)
        assert covered.sum() > 20 and uncovered.sum() > 20
        np.testing.assert_array_equal(_pass(probe, "occluded_forward", k)[tissue], covered[tissue])
        np.testing.assert_array_equal(_pass(probe, "occluded_backward", k + 1)[nxt == TISSUE],
                                      uncovered[nxt == TISSUE])


def test_a_point_behind_the_probe_is_occluded(probe):
    with np.load(probe / "tracks.npz") as tracks:
        query, occluded, points_2d = tracks["query_points"], tracks["occluded"], tracks["points_2d"]
    rows, cols = query[:, 1].astype(int), query[:, 2].astype(int)
    seg = np.stack([_pass(probe, "segmentation", k) for k in (1, 2, 3)])
    assert (seg[0, rows, cols] == TISSUE).all()  # queries on the tissue seen in frame 1
    assert len(query) == (seg[0] == TISSUE).sum()  # track_points exceeds the tissue pixels: all of them
    # static tissue: every track stays on its query pixel's centre (to float64 rounding of the projection)
    np.testing.assert_allclose(points_2d, np.broadcast_to(np.stack([cols, rows], -1)[:, None], points_2d.shape),
                               atol=1e-4)
    behind = (seg[:, rows, cols] == TOOL).T
    assert behind.sum() > 20
    np.testing.assert_array_equal(occluded, behind)


def test_tracks_project_through_cameras_json_onto_the_depth_pass(stretch):
    doc = __import__("json").loads((stretch / "cameras.json").read_text())
    K = np.array(doc["K"])
    with np.load(stretch / "tracks.npz") as tracks:
        t = {name: tracks[name] for name in tracks}
    n = len(t["query_points"])
    assert n == 40 and t["points_2d"].shape == (n, 3, 2) and t["points_3d"].shape == (n, 3, 3)
    assert t["occluded"].shape == (n, 3) and not t["occluded"][:, 0].any()
    for k in range(3):
        T = np.array(doc["frames"][k]["world_to_camera"])
        cam = t["points_3d"][:, k].astype(float) @ T[:3, :3].T + T[:3, 3]
        uv = (cam @ K.T)[:, :2] / cam[:, 2:]
        np.testing.assert_allclose(t["points_2d"][:, k], uv, atol=0.01)
        depth = _pass(stretch, "depth", k + 1).astype(float)
        visible = ~t["occluded"][:, k] & (uv[:, 0] >= 0) & (uv[:, 0] <= 63) & (uv[:, 1] >= 0) & (uv[:, 1] <= 47)
        if k == 0:
            # the query pixel's own centre: equal to float32 rounding of the depth and of the geometry's
            # coordinates (about 2^-24 x 1.4 cm each, a few operations)
            rows, cols = t["query_points"][:, 1].astype(int), t["query_points"][:, 2].astype(int)
            np.testing.assert_allclose(cam[:, 2], depth[rows, cols], rtol=16 * F32)
        else:
            at, bound = _bilinear(depth, uv[visible, 0], uv[visible, 1])
            assert visible.sum() > 0.8 * n
            assert (np.abs(cam[visible, 2] - at) <= bound + 16 * F32 * cam[visible, 2]).all()


def test_flow_to_any_frame_from_the_folder_follows_the_tracks(stretch):
    flow, occluded, scene_flow = groundtruth.flow_between_frames(stretch, 1, 3)
    with np.load(stretch / "tracks.npz") as tracks:
        query, points_2d, points_3d = tracks["query_points"], tracks["points_2d"], tracks["points_3d"]
    rows, cols = query[:, 1].astype(int), query[:, 2].astype(int)
    # the same material points, the same float32 geometry: equal to float32 rounding of pixels and metres
    np.testing.assert_allclose(flow[rows, cols], points_2d[:, 2] - points_2d[:, 0], atol=1e-4)
    np.testing.assert_allclose(scene_flow[rows, cols], points_3d[:, 2] - points_3d[:, 0], atol=1e-9)
    assert np.nanmax(np.abs(flow)) > 2.0  # two frames of motion
    with pytest.raises(tissuerender.errors.UserError, match="geometry_0009.npz"):
        groundtruth.flow_between_frames(stretch, 1, 9)


def test_tapvid_pickle_and_tapvid3d_npz_read_back_with_the_documented_layouts(stretch):
    with open(stretch / "tracks_tapvid.pkl", "rb") as f:
        data = pickle.load(f)
    assert list(data) == ["stretch"]
    video = data["stretch"]
    assert video["video"].dtype == np.uint8 and video["video"].shape == (3, 48, 64, 3)
    assert video["video"].max() > 0  # the PNG frames
    assert video["points"].shape == (40, 3, 2) and video["occluded"].shape == (40, 3)
    assert video["occluded"].dtype == bool
    points, hidden = video["points"], video["occluded"]
    outside = ((points < 0.0) | (points > 1.0)).any(axis=-1)
    assert not (outside & ~hidden).any()  # a point off the image is occluded
    with np.load(stretch / "tracks.npz") as tracks:
        np.testing.assert_allclose(video["points"] * [64, 48] - 0.5, tracks["points_2d"], atol=1e-4)
        points_3d, occluded = tracks["points_3d"], tracks["occluded"]
    with np.load(stretch / "tracks_tapvid3d.npz") as d3:
        assert d3["tracks_XYZ"].shape == (3, 40, 3) and d3["visibility"].shape == (3, 40)
        np.testing.assert_array_equal(d3["visibility"], ~occluded.T)
        fx, fy, cx, cy = d3["fx_fy_cx_cy"]
        xyz = d3["tracks_XYZ"].astype(float)
        uv = np.stack([fx * xyz[..., 0] / xyz[..., 2] + cx, fy * xyz[..., 1] / xyz[..., 2] + cy], -1)
        with np.load(stretch / "tracks.npz") as tracks:
            np.testing.assert_allclose(uv, tracks["points_2d"].transpose(1, 0, 2), atol=0.01)
    assert points_3d.dtype == np.float32


def test_motion_passes_are_planned_with_the_geometry_and_track_points_needs_tracks(tmp_path):
    data = copy.deepcopy(PROBE)
    path = tmp_path / "scene.toml"
    path.write_text(tomli_w.dumps(data))
    plan = make_plan(load_scene(path))
    assert {"passes.flow", "passes.tracks", "write_geometry"} <= set(plan.names)
    assert "passes.scene_flow" not in plan.names
    data["output"]["passes"] = ["depth"]
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(SceneError, match="output.track_points"):
        load_scene(path)
    data["output"].pop("track_points")
    path.write_text(tomli_w.dumps(data))
    assert "write_geometry" not in make_plan(load_scene(path)).names


def test_resume_rerenders_a_frame_without_its_geometry_and_finishes_the_sequence(probe, tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(tomli_w.dumps(PROBE))
    scene = load_scene(path)
    out = tmp_path / "out"
    render(scene, out, progress=False, frames=2)  # an interrupted run: two of three frames
    assert np.isnan(_pass(out, "flow_forward", 2)).all()  # no third frame yet
    (out / "passes" / "geometry_0002.npz").unlink()  # frame 2 is no longer complete
    run = render(scene, out, resume=True, progress=False)
    assert [p.name for p in run.skipped] == ["frame_0001.png"]
    assert "geometry_0002.npz" in [p.name for p in run.written]
    # the same files as an uninterrupted run
    for name in ("flow_forward", "flow_backward", "occluded_forward", "occluded_backward"):
        for k in (1, 2, 3):
            np.testing.assert_array_equal(_pass(out, name, k), _pass(probe, name, k))
    with np.load(out / "tracks.npz") as resumed, np.load(probe / "tracks.npz") as reference:
        for name in ("query_points", "points_2d", "points_3d", "occluded"):
            np.testing.assert_array_equal(resumed[name], reference[name])


def test_inverse_depth_gradient_matches_the_plane_seen_through_neighbouring_pixels():
    from tissuerender.groundtruth.motion import _camera_coords, _inverse_depth_gradient, _project
    from tissuerender.renderer.camera import Camera

    camera = Camera(position=(0.01, -0.02, 0.1), look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov_deg=50.0,
                    near=0.001, far=10.0, width=64, height=48)
    corners = np.array([[[-0.02, -0.01, 0.0], [0.03, -0.015, 0.01], [0.0, 0.02, -0.005]]])
    centre = corners[0].mean(axis=0)
    (u, v), z = _project(centre, camera)
    n = np.cross(corners[0, 1] - corners[0, 0], corners[0, 2] - corners[0, 0])
    K = tissuerender.groundtruth.intrinsics(camera)
    T = tissuerender.groundtruth.world_to_camera(camera)

    def w_at(du, dv):
        # 1/z of the plane's point on the ray through pixel (u + du, v + dv)
        ray_cam = np.linalg.inv(K) @ [u + du, v + dv, 1.0]
        ray = T[:3, :3].T @ ray_cam
        C = -T[:3, :3].T @ T[:3, 3]
        s = n @ (corners[0, 0] - C) / (n @ ray)
        return 1.0 / _camera_coords(C + s * ray, camera)[2]

    # 1/z is affine in pixels over a plane: central differences are exact up to rounding (about 1e-12 relative)
    expected = np.hypot(w_at(1, 0) - w_at(-1, 0), w_at(0, 1) - w_at(0, -1)) / 2
    np.testing.assert_allclose(_inverse_depth_gradient(corners, camera), [expected], rtol=1e-9)
    assert expected > 0 and abs(1.0 / z - w_at(0, 0)) < 1e-9 / z


@pytest.mark.parametrize("lens_k", [None, (-0.05, 0.01, 0.0, 0.0)])
def test_motion_kernels_project_and_take_gradients_as_the_numpy_forms(lens_k):
    """``motion_kernels`` (the flows' and tracks' arithmetic) against the NumPy ``_project`` (cameras.json's K,
    pose and lens) and ``_inverse_depth_gradient`` (checked against the plane above), on a small pinhole or
    fisheye frame looking at two triangles. Both evaluate the same expressions; only the summation of ``R X + t``
    may differ (BLAS against a plain loop), a few float64 ulps of coordinates about 0.1 m, so the pixels agree to
    1e-9 px (a few hundred ulps of 64 px) and the gradients to 1e-12 relative (the cross product of corner
    differences amplifies the coordinates' rounding by their size over the triangle's, about 3 here)."""
    from tissuerender.groundtruth.motion import (Geometry, _inverse_depth_gradient, _project, frame_raster,
                                                 lens_of, points_motion)
    from tissuerender.groundtruth.motion_kernels import triangle_gradients
    from tissuerender.renderer.camera import Camera

    camera = Camera(position=(0.01, -0.02, 0.1), look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov_deg=50.0,
                    near=0.001, far=10.0, width=64, height=48)
    points = np.array([[-0.02, -0.01, 0.0], [0.03, -0.015, 0.01], [0.0, 0.02, -0.005], [0.01, 0.01, 0.02]],
                      np.float32)
    geom = Geometry(points, np.array([[0, 1, 2], [0, 1, 3]], np.int32), np.zeros(2, np.int32), camera, lens_k)
    moved = points + np.float32(0.002)
    source = frame_raster(geom, [moved])
    target = frame_raster(Geometry(moved, geom.triangles, geom.tri_object, camera, lens_k))
    covered = source.covered
    assert covered.sum() > 100
    uv, uv2, X, X2, occluded = points_motion(source, source.tri_id[covered], source.bary[covered],
                                             source.carried, target)
    lens = lens_of(camera, lens_k)
    np.testing.assert_allclose(uv, _project(X, camera, lens)[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(uv2, _project(X2, camera, lens)[0], rtol=0, atol=1e-9)
    corners = source.points[source.triangles]
    grad = np.empty(len(corners))
    triangle_gradients(source.triangles, source.points, source.pose, np.linalg.inv(source.K_view), grad)
    np.testing.assert_allclose(grad, _inverse_depth_gradient(corners, source.view), rtol=1e-12)
