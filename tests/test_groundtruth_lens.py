"""The moving laparoscope and its lens (issue 18 items 2 and 3; docs/ground-truth.md, "Moving camera" and "Lens"),
checked against the models written out here from their published form: OpenCV's fisheye projection (the
``cv::fisheye`` documentation: ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
``x' = (theta_d / r) a``, ``u = fx x' + cx``) and the pose ``X_cam = R X_world + t`` with rows of ``R`` the
camera's right, down and forward axes.

Tolerances. Pure float64 arithmetic (the projection, a few dozen operations) agrees to 1e-12 relative (``F64``);
float32 storage adds half an ulp, ``2^-24`` relative (``F32``). A pass value at a distorted pixel belongs to the
pinhole sample nearest the pixel's ray: half a pinhole pixel in each axis, which the distortion maps to at most
``S`` distorted pixels per pinhole pixel (its Jacobian's largest singular value, computed here), so a silhouette
lies within ``0.5 + S sqrt(2) / 2`` pixels of the transition between its two pixels.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import tomli_w

import tissuerender
from tissuerender import load_scene
from tissuerender.cli import main
from tissuerender.groundtruth import lens as lens_module
from tissuerender.render_inputs import camera_for, lens_for

F64 = 1e-12
F32 = 2.0 ** -24
K_COEFFS = [0.05, -0.01, 0.002, 0.0]
TOP = 0.04  # the slab's top face [m]
EDGE_X = 0.24  # the slab's edge x = 0.24 m on its top face: the straight world line

# A slab seen from above; its top edge at x = EDGE_X crosses the right half of a 100-degree fisheye image, and the
# side face below it turns away from the camera, so the silhouette is that straight edge.
SLAB = {
    "scene": {"name": "lens", "seed": 1},
    "objects": [{"name": "slab", "kind": "body", "shape": "box", "size": [EDGE_X, 0.4, TOP], "cell_size": 0.04,
                 "material": "liver"}],
    "simulation": {"integrator": "none"},
    "camera": {"position": [0.18, 0.2, 0.12], "look_at": [0.18, 0.2, TOP], "up": [0.0, 1.0, 0.0],
               "fov_deg": 100.0, "lens": {"coefficients": K_COEFFS}},
    "light": {"attach": "camera", "size": [0.02, 0.02], "radiance": [3000.0, 3000.0, 3000.0], "samples": 4},
    "effects": {"tonemap": {}},
    "output": {"resolution": [64, 48], "passes": ["depth", "segmentation"]},
}

# The slab and a small visible sphere above it, seen by a laparoscope that moves between two keyframes.
SPHERE_CENTRE = [0.15, 0.21, 0.07]
MOVING = copy.deepcopy(SLAB)
MOVING["tools"] = [{"name": "bead", "kind": "sphere", "radius": 0.008, "keyframes": [{"t": 0.0,
                                                                                      "position": SPHERE_CENTRE}]}]
MOVING["camera"] = {"up": [0.0, 1.0, 0.0], "fov_deg": 80.0, "path": [
    {"t": 0.0, "position": [0.12, 0.17, 0.15], "look_at": [0.13, 0.2, TOP]},
    {"t": 2.0 / 24.0, "position": [0.18, 0.24, 0.14], "look_at": [0.16, 0.2, TOP], "up": [0.2, 1.0, 0.0]}]}
MOVING["output"] = {"resolution": [64, 48], "frames": 3, "fps": 24.0, "passes": ["depth", "segmentation"]}


def _scene(tmp_path, data, name="scene.toml"):
    path = tmp_path / name
    path.write_text(tomli_w.dumps(data))
    return load_scene(path)


def opencv_fisheye(points_camera: np.ndarray, K: np.ndarray, k) -> np.ndarray:
    """OpenCV's fisheye projection as its documentation writes it (alpha = 0)."""
    x, y, z = points_camera[..., 0], points_camera[..., 1], points_camera[..., 2]
    a, b = x / z, y / z
    r = np.sqrt(a ** 2 + b ** 2)
    theta = np.arctan(r)
    theta_d = theta * (1 + k[0] * theta ** 2 + k[1] * theta ** 4 + k[2] * theta ** 6 + k[3] * theta ** 8)
    xp, yp = theta_d / r * a, theta_d / r * b
    return np.stack([K[0, 0] * xp + K[0, 2], K[1, 1] * yp + K[1, 2]], axis=-1)


def _to_camera(doc: dict, frame: int, points_world: np.ndarray) -> np.ndarray:
    T = np.array(doc["frames"][frame]["world_to_camera"])
    return points_world @ T[:3, :3].T + T[:3, 3]


def _project(doc: dict, frame: int, points_world: np.ndarray) -> np.ndarray:
    """Pixels of world points through cameras.json: its K, pose and distortion (none or kannala_brandt)."""
    X = _to_camera(doc, frame, np.asarray(points_world, float))
    K = np.array(doc["K"])
    if doc["distortion"]["model"] == "none":
        return np.stack([K[0, 0] * X[..., 0] / X[..., 2] + K[0, 2], K[1, 1] * X[..., 1] / X[..., 2] + K[1, 2]], -1)
    assert doc["distortion"]["model"] == "kannala_brandt"
    return opencv_fisheye(X, K, doc["distortion"]["coefficients"])


def test_distort_and_project_follow_the_opencv_fisheye_formula(tmp_path):
    scene = _scene(tmp_path, SLAB)
    lens = lens_for(scene, camera_for(scene))
    # fx from the field of view: the width spans fov_deg, so theta_d(fov / 2) sits at W / 2
    half = np.radians(100.0) / 2
    theta_d = half * (1 + sum(c * half ** (2 * i + 2) for i, c in enumerate(K_COEFFS)))
    assert lens.K[0, 0] == pytest.approx(32.0 / theta_d, rel=F64)
    assert lens.K[1, 1] == lens.K[0, 0] and (lens.K[0, 2], lens.K[1, 2]) == (31.5, 23.5)
    rng = np.random.default_rng(4)
    X = np.column_stack([rng.uniform(-1.0, 1.0, 200), rng.uniform(-0.8, 0.8, 200), rng.uniform(0.6, 2.0, 200)])
    expected = opencv_fisheye(X, lens.K, K_COEFFS)
    assert np.allclose(lens.project(X), expected, rtol=F64, atol=F64 * 100)
    undistorted_px = np.column_stack([lens.K[0, 0] * X[:, 0] / X[:, 2] + lens.K[0, 2],
                                      lens.K[1, 1] * X[:, 1] / X[:, 2] + lens.K[1, 2]])
    assert np.allclose(lens.distort(undistorted_px), expected, rtol=F64, atol=F64 * 100)
    assert np.array_equal(lens.distort_pixels(undistorted_px), lens.distort(undistorted_px))
    assert np.array_equal(lens_module.distort_pixels(undistorted_px, lens), lens.distort(undistorted_px))
    assert np.array_equal(lens_module.distort_pixels(undistorted_px, None), undistorted_px)  # no lens: a pinhole
    assert np.array_equal(lens.distort(lens.K[:2, 2]), lens.K[:2, 2])  # the principal point stays


@pytest.mark.parametrize("coefficients", [[0.0, 0.0, 0.0, 0.0], K_COEFFS, [-0.08, 0.01, -0.002, 0.0001]])
def test_undistort_inverts_distort_to_1e_9_pixels(coefficients):
    K = lens_module.fisheye_intrinsics(100.0, 64, 48, coefficients)
    rng = np.random.default_rng(7)
    # undistorted pixels out to rays 60 degrees from the axis (beyond the image corners)
    angle, turn = rng.uniform(0.0, np.radians(60.0), 500), rng.uniform(0.0, 2 * np.pi, 500)
    p = K[:2, 2] + K[0, 0] * np.tan(angle)[:, None] * np.column_stack([np.cos(turn), np.sin(turn)])
    back = lens_module.undistort(lens_module.distort(p, K, coefficients), K, coefficients)
    assert np.abs(back - p).max() < 1e-9
    grid = np.stack(np.meshgrid(np.arange(64.0), np.arange(48.0)), axis=-1)
    again = lens_module.distort(lens_module.undistort(grid, K, coefficients), K, coefficients)
    assert np.abs(again - grid).max() < 1e-9


def test_a_straight_world_line_projects_onto_the_curve_the_model_predicts(tmp_path):
    scene = _scene(tmp_path, SLAB)
    arrays = tissuerender.render_passes(scene, passes=["segmentation", "depth"])
    doc = arrays["camera"]
    ids = arrays["segmentation"]
    assert doc["distortion"] == {"model": "kannala_brandt", "coefficients": K_COEFFS}
    assert np.array_equal(np.isfinite(arrays["depth"]), ids > 0)
    # the edge through cameras.json, densely: a curve in the distorted image (v increases along it)
    y = np.linspace(0.1, 0.3, 4001)
    curve = _project(doc, 0, np.column_stack([np.full_like(y, EDGE_X), y, np.full_like(y, TOP)]))
    order = np.argsort(curve[:, 1])
    rows = np.arange(ids.shape[0], dtype=float)
    predicted = np.interp(rows, curve[order, 1], curve[order, 0])
    # the same line without the lens: straight, as a pinhole would draw it
    K = np.array(doc["K"])
    X = _to_camera(doc, 0, np.column_stack([np.full_like(y, EDGE_X), y, np.full_like(y, TOP)]))
    straight = np.interp(rows, (K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2])[order], (K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2])[order])
    # every row: slab pixels, then background, with one transition between pixels u and u + 1
    transition = np.empty(len(rows))
    for v, row in enumerate(ids):
        u_last = np.flatnonzero(row == 1).max()
        assert (row[:u_last + 1] == 1).all() and (row[u_last + 1:] == 0).all()
        transition[v] = u_last + 0.5
    lens = lens_for(scene, camera_for(scene))
    S = _largest_stretch(lens)
    bound = 0.5 + S * np.sqrt(2.0) / 2.0
    error = predicted - transition
    assert np.abs(error).max() <= bound, (np.abs(error).max(), bound)
    assert np.sqrt(np.mean(error ** 2)) < 0.5  # the fit: quantisation noise, no systematic offset
    # the test tells the lens from a pinhole: the straight line misses the drawn edge by far more
    assert np.abs(straight - transition).max() > 3 * bound
    assert np.ptp(predicted) > 2.0  # and the edge is visibly curved (2.8 px here)


def _largest_stretch(lens) -> float:
    """Largest singular value of the distortion's Jacobian (distorted px per pinhole px) at the image's samples,
    by central differences of the model (the pinhole's focal length is the lens's fx)."""
    grid = np.stack(np.meshgrid(np.arange(lens.width, dtype=float), np.arange(lens.height, dtype=float)), -1)
    p = lens.undistort(grid).reshape(-1, 2)
    h = 1e-4
    du = (lens.distort(p + [h, 0.0]) - lens.distort(p - [h, 0.0])) / (2 * h)
    dv = (lens.distort(p + [0.0, h]) - lens.distort(p - [0.0, h])) / (2 * h)
    J = np.stack([du, dv], axis=-1)
    return float(np.linalg.svd(J, compute_uv=False).max())


def test_every_pass_is_the_nearest_pinhole_sample_and_ids_never_blend(tmp_path):
    data = copy.deepcopy(MOVING)
    data["camera"] = copy.deepcopy(SLAB["camera"])
    data["output"] = copy.deepcopy(SLAB["output"])
    scene = _scene(tmp_path, data)
    every = ["depth", "normal", "segmentation", "material_coords"]
    distorted = tissuerender.render_passes(scene, passes=every)
    lens = lens_for(scene, camera_for(scene))
    # the same frame through the pinhole the lens renders with, as a scene of its own
    pin = copy.deepcopy(data)
    del pin["camera"]["lens"]
    pin["camera"]["fov_deg"] = lens.pinhole.fov_deg
    pin["output"]["resolution"] = [lens.pinhole.width, lens.pinhole.height]
    pinhole = tissuerender.render_passes(_scene(tmp_path, pin, "pinhole.toml"), passes=every)
    assert set(np.unique(pinhole["segmentation"])) == {0, 1, 2}
    for name in ("segmentation", "depth", "normal", "material_coords"):
        assert np.array_equal(distorted[name], lens.remap_nearest(pinhole[name]), equal_nan=True), name
    assert set(np.unique(distorted["segmentation"])) <= set(np.unique(pinhole["segmentation"]))
    # a bilinear remap would have blended them: ids 0 / 7 / 100 in a checkerboard
    checker = np.where((np.indices((lens.pinhole.height, lens.pinhole.width)).sum(0) % 3) == 0, 7, 100)
    checker[:, : lens.pinhole.width // 3] = 0
    assert set(np.unique(lens.remap_nearest(checker))) == {0, 7, 100}
    assert not set(np.unique(lens.remap_bilinear(checker[..., None].astype(float)))) <= {0.0, 7.0, 100.0}


def test_vignetting_scales_linear_colour_by_the_stated_cos4_falloff(tmp_path):
    plain = tissuerender.render_passes(_scene(tmp_path, SLAB), passes=["segmentation"])
    data = copy.deepcopy(SLAB)
    s = 0.8
    data["camera"]["lens"]["vignetting"] = s
    vignetted = tissuerender.render_passes(_scene(tmp_path, data, "vignetted.toml"), passes=["segmentation"])
    assert np.array_equal(plain["segmentation"], vignetted["segmentation"])  # colour only
    # each pixel's ray angle: theta_d = r_d in normalised distorted units, inverted by bisection here
    K = np.array(plain["camera"]["K"])
    v, u = np.mgrid[0:48, 0:64].astype(float)
    r_d = np.hypot((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1])
    lo, hi = np.zeros_like(r_d), np.full_like(r_d, np.pi / 2)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        theta_d = mid * (1 + sum(c * mid ** (2 * i + 2) for i, c in enumerate(K_COEFFS)))
        lo, hi = np.where(theta_d < r_d, mid, lo), np.where(theta_d < r_d, hi, mid)
    falloff = 1.0 - s * (1.0 - np.cos(0.5 * (lo + hi)) ** 4)
    lit = plain["hdr"] > 0.0
    ratio = vignetted["hdr"][lit].astype(np.float64) / plain["hdr"][lit]
    expected = np.broadcast_to(falloff[..., None], plain["hdr"].shape)[lit]
    # one float32 rounding of the vignetted value (F32) plus float64 work (F64)
    assert np.allclose(ratio, expected, rtol=F32 + F64, atol=0.0)
    assert expected.min() < 0.75  # the corners darken markedly at 100 degrees


@pytest.mark.parametrize("with_lens", [False, True])
def test_a_moving_camera_poses_every_frame_and_cameras_json_projects_where_it_is_drawn(tmp_path, with_lens):
    data = copy.deepcopy(MOVING)
    if with_lens:
        data["camera"]["lens"] = {"coefficients": K_COEFFS}
    scene = _scene(tmp_path, data)
    run = tissuerender.render(scene, tmp_path / "out", progress=False)
    doc = json.loads((run.out_dir / "cameras.json").read_text())
    assert doc["distortion"]["model"] == ("kannala_brandt" if with_lens else "none")
    keys = data["camera"]["path"]
    centres = []
    for k, frame in enumerate(doc["frames"]):
        t = k / 24.0
        assert frame["time"] == t
        # the pose from the keyframes, linear in time in position, look_at and up
        w = t / keys[1]["t"]
        position, look_at = [(1 - w) * np.array(keys[0][n]) + w * np.array(keys[1][n]) for n in ("position", "look_at")]
        up = (1 - w) * np.array(data["camera"]["up"]) + w * np.array(keys[1]["up"])
        forward = (look_at - position) / np.linalg.norm(look_at - position)
        right = np.cross(forward, up) / np.linalg.norm(np.cross(forward, up))
        down = np.cross(forward, right)
        T = np.array(frame["world_to_camera"])
        assert np.allclose(T[:3, :3], np.stack([right, down, forward]), rtol=0, atol=F64)
        assert np.allclose(T[:3, 3], -T[:3, :3] @ position, rtol=0, atol=F64)
        # the bead is drawn where cameras.json projects its centre (a small symmetric blob: its centroid)
        ids = np.load(run.out_dir / "passes" / f"segmentation_{k + 1:04d}.npy")
        rows, cols = np.nonzero(ids == 2)
        assert rows.size > 20
        centroid = np.array([cols.mean(), rows.mean()])
        projected = _project(doc, k, np.array(SPHERE_CENTRE))
        assert np.linalg.norm(centroid - projected) < 0.5, (k, centroid, projected)
        # and its depth pass is the camera z of the bead's near side
        depth = np.load(run.out_dir / "passes" / f"depth_{k + 1:04d}.npy")
        z_centre = _to_camera(doc, k, np.array(SPHERE_CENTRE))[2]
        assert z_centre - 0.008 - 1e-6 <= depth[ids == 2].min() < z_centre
        centres.append(projected)
    assert np.linalg.norm(centres[2] - centres[0]) > 8.0  # the camera moved: the bead moved in the image
    frames = [(run.out_dir / f"frame_{k:04d}.png").read_bytes() for k in (1, 2, 3)]
    assert frames[0] != frames[1] != frames[2]


def test_a_path_of_one_keyframe_renders_bit_identically_to_the_fixed_camera(tmp_path):
    fixed = copy.deepcopy(SLAB)
    del fixed["camera"]["lens"]
    path = copy.deepcopy(fixed)
    position, look_at = path["camera"].pop("position"), path["camera"].pop("look_at")
    path["camera"]["path"] = [{"t": 0.5, "position": position, "look_at": look_at}]  # held before its time
    a = tissuerender.render_passes(_scene(tmp_path, fixed), passes=["depth"])
    b = tissuerender.render_passes(_scene(tmp_path, path, "path.toml"), passes=["depth"])
    assert np.array_equal(a["colour"], b["colour"]) and np.array_equal(a["depth"], b["depth"])
    assert a["camera"] == b["camera"] and a["camera"]["distortion"] == {"model": "none", "coefficients": []}
    assert "lens" not in tissuerender.make_plan(_scene(tmp_path, fixed)).names


@pytest.mark.parametrize("change, key, words", [
    ({"position": [0.0, 0.0, 0.1]}, "camera", "remove 'position' and 'look_at'"),
    ({"path": [{"t": 0.1, "position": [0.0, 0.0, 0.1], "look_at": [0.0, 0.0, 0.0]},
               {"t": 0.1, "position": [0.0, 0.0, 0.2], "look_at": [0.0, 0.0, 0.0]}]}, "camera", "increase strictly"),
    ({"fov_deg": 150.0, "lens": {"coefficients": [-0.3, 0.0, 0.0, 0.0]}}, "camera.lens", "stops increasing"),
    ({"fov_deg": 170.0, "lens": {"coefficients": [0.0, 0.0, 0.0, 0.0]}}, "camera.lens", "pinhole"),
    ({"path": [{"t": 0.0, "position": [0.0, 0.0, 0.1], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0]}]},
     "camera.up", "no effect"),
    # frame 2 (t = 1/24 s) is half way: up (1, 0, 0) -> (-1, 0, 0) passes through zero
    ({"up": None, "path": [{"t": 0.0, "position": [0.1, 0.2, 0.15], "look_at": [0.1, 0.2, 0.0], "up": [1.0, 0.0, 0.0]},
                           {"t": 2.0 / 24.0, "position": [0.1, 0.2, 0.15], "look_at": [0.1, 0.2, 0.0],
                            "up": [-1.0, 0.0, 0.0]}]}, "camera.path", "at t = 0.0416667 s"),
])
def test_a_camera_the_model_cannot_follow_is_refused_with_its_key(tmp_path, capsys, change, key, words):
    data = copy.deepcopy(MOVING)
    data["camera"].update(change)
    data["camera"] = {key: value for key, value in data["camera"].items() if value is not None}
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(data))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert key in err and words in err and len(err.splitlines()) == 1, err
