"""Ground truth for vision (issue 18; docs/ground-truth.md): depth, normals, segmentation and material
coordinates checked against geometry computed here from ``cameras.json`` alone, and the files read back.

Tolerances. A pass value is computed in float64 and stored as float32: rounding to nearest moves it by at most
half an ulp, ``2^-24 |x|`` (``F32``). The float64 work behind it (projection, edge functions, perspective-correct
interpolation: a few dozen operations on well-conditioned, non-grazing hits) is good to far better than
``1e-12`` relative, which ``F64`` covers with a wide margin; the checks below add the two.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import tomli_w

import tissuerender
from tissuerender import load_scene, make_plan
from tissuerender.checks import check_scene
from tissuerender.cli import main
from tissuerender.world import advance

F32 = 2.0 ** -24  # float32 rounding, relative
F64 = 1e-12  # float64 arithmetic before the rounding, relative (see the module docstring)
TOP = 0.02  # the plane scene's box top [m]

PLANE = {
    "scene": {"name": "plane", "seed": 5},
    "objects": [{"name": "slab", "kind": "body", "shape": "box", "size": [0.1, 0.1, TOP], "cell_size": 0.02,
                 "material": "liver", "fixed": [{"side": "z_min"}]}],
    "simulation": {"integrator": "none"},
    # looks down at the top face at about 52 degrees from its normal, from 0.13 m above it
    "camera": {"position": [0.05, -0.12, 0.15], "look_at": [0.05, 0.05, TOP], "fov_deg": 50.0},
    "light": {"attach": "camera", "size": [0.02, 0.02], "radiance": [3000.0, 3000.0, 3000.0], "samples": 4},
    "effects": {"tonemap": {}},
    # odd size: the principal point (W/2 - 1/2, H/2 - 1/2) is a pixel centre
    "output": {"resolution": [65, 49], "frames": 1, "fps": 24.0,
               "passes": ["depth", "normal", "segmentation", "material_coords"]},
}

# a box pressed by a visible sphere probe, supersampled 2 x 2 with jitter; its render surface subdivided once
PRESSED = copy.deepcopy(PLANE)
PRESSED["scene"]["name"] = "pressed"
PRESSED["objects"][0].update(size=[0.1, 0.1, 0.04], render_subdivision=1)
PRESSED["simulation"] = {"integrator": "xpbd", "dt": 1.0 / 240.0, "substeps": 4, "iterations": 10,
                         "gravity": [0.0, 0.0, 0.0]}
PRESSED["tools"] = [{"name": "probe", "kind": "sphere", "radius": 0.015,
                     "keyframes": [{"t": 0.0, "position": [0.04, 0.04, 0.056]},
                                   {"t": 0.1, "position": [0.04, 0.04, 0.044]}]}]
PRESSED["camera"] = {"position": [0.05, -0.1, 0.16], "look_at": [0.05, 0.05, 0.03], "fov_deg": 50.0}
PRESSED["output"].update(supersampling=2, frames=3)
FRAME = 3  # t = 2/24 s: the probe is about 9 mm into the top face, right above a node of the tet mesh


def _scene(tmp_path, data, name="scene.toml"):
    path = tmp_path / name
    path.write_text(tomli_w.dumps(data))
    return load_scene(path)


def _camera(doc: dict, frame: int = 0):
    """(K, R, t, camera centre C) from a cameras.json document."""
    K = np.array(doc["K"])
    T = np.array(doc["frames"][frame]["world_to_camera"])
    R, t = T[:3, :3], T[:3, 3]
    return K, R, t, -R.T @ t


def _rays(doc: dict, frame: int = 0):
    """Per pixel centre the world direction D (H, W, 3) whose camera z is 1: the point at camera depth z of
    pixel (u, v) is C + z D."""
    K, R, _, C = _camera(doc, frame)
    v, u = np.mgrid[0:doc["height"], 0:doc["width"]].astype(float)
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    return C, (pix @ np.linalg.inv(K).T) @ R


@pytest.fixture(scope="module")
def plane(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plane")
    scene = _scene(tmp, PLANE)
    out = tmp / "out"
    tissuerender.render(scene, out, progress=False)
    return scene, out


def _load(out, name, k=1):
    return np.load(out / "passes" / f"{name}_{k:04d}.npy")


def test_every_file_reads_back_with_the_documented_shapes_and_dtypes(plane):
    _, out = plane
    cams = json.loads((out / "cameras.json").read_text())
    labels = json.loads((out / "labels.json").read_text())
    assert (cams["width"], cams["height"]) == (65, 49)
    assert cams["distortion"] == {"model": "none", "coefficients": []} and "OpenCV" in cams["conventions"]
    assert np.array(cams["K"]).shape == (3, 3) and len(cams["frames"]) == 1
    assert cams["frames"][0]["index"] == 1 and cams["frames"][0]["time"] == 0.0
    T = np.array(cams["frames"][0]["world_to_camera"])
    assert T.shape == (4, 4) and np.array_equal(T[3], [0, 0, 0, 1])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-15)  # a rotation
    assert labels["instances"] == [{"id": 0, "name": "background", "kind": "background", "class": "background"},
                                   {"id": 1, "name": "slab", "kind": "body", "class": "liver"}]
    expected = {"depth": ((49, 65), np.float32), "normal": ((49, 65, 3), np.float32),
                "segmentation": ((49, 65), np.int32), "material_coords": ((49, 65, 3), np.float32)}
    for name, (shape, dtype) in expected.items():
        a = _load(out, name)
        assert (a.shape, a.dtype) == (shape, dtype), name
    ids, depth = _load(out, "segmentation"), _load(out, "depth")
    assert 0 < (ids == 1).sum() < ids.size  # the slab and some background are in view
    assert np.array_equal(ids == 0, np.isinf(depth))  # background: id 0 exactly where depth is inf
    assert np.isnan(_load(out, "normal")[ids == 0]).all() and np.isnan(_load(out, "material_coords")[ids == 0]).all()


def test_K_follows_the_horizontal_fov_with_pixel_centres_at_integers(plane):
    _, out = plane
    K = np.array(json.loads((out / "cameras.json").read_text())["K"])
    f = 65 / (2 * np.tan(np.radians(50.0) / 2))
    assert np.allclose(K, [[f, 0, 32.0], [0, f, 24.0], [0, 0, 1]], rtol=1e-15, atol=0)


def test_depth_and_normal_of_a_plane_are_exact_to_float32(plane):
    _, out = plane
    cams = json.loads((out / "cameras.json").read_text())
    _, R, _, C = _camera(cams)
    _, D = _rays(cams)
    z = (TOP - C[2]) / D[..., 2]  # camera z of the ray's hit on the plane z = TOP
    hit = C + z[..., None] * D
    # the top face away from its border, where the vertex normals average in the side faces
    inner = ((hit[..., 0] > 0.02 + 1e-9) & (hit[..., 0] < 0.08 - 1e-9) & (hit[..., 1] > 0.02 + 1e-9)
             & (hit[..., 1] < 0.08 - 1e-9) & (z > 0))
    assert inner.sum() > 200
    depth, normal = _load(out, "depth"), _load(out, "normal")
    err = np.abs(depth[inner] - z[inner])
    assert (err <= (F32 + F64) * z[inner]).all(), err.max() / z[inner].max()
    n_cam = R @ np.array([0.0, 0.0, 1.0])  # the plane's normal, towards the camera above it
    assert n_cam[2] < 0 and abs(n_cam[2]) == pytest.approx(0.13 / np.hypot(0.13, 0.17))  # camera z points down at it
    assert (np.abs(normal[inner] - n_cam) <= F32 + F64).all()
    # and a known point: the look-at point is on the optical axis, so it lands on the principal point's pixel
    look_at = np.array([0.05, 0.05, TOP])
    assert depth[24, 32] == np.float32(np.linalg.norm(look_at - C))
    assert np.array_equal(_load(out, "material_coords")[24, 32], look_at.astype(np.float32))


def test_projecting_vertices_through_cameras_json_lands_on_their_pixels(plane):
    scene, out = plane
    cams = json.loads((out / "cameras.json").read_text())
    K, R, t, _ = _camera(cams)
    body = check_scene(scene).world.bodies[0]
    p = body.surface.points
    top = p[(p[:, 2] == TOP) & (p[:, 0] > 0) & (p[:, 0] < 0.1) & (p[:, 1] > 0) & (p[:, 1] < 0.1)]  # off the edges
    cam = top @ R.T + t
    uv = cam[:, :2] / cam[:, 2:] @ K[:2, :2].T + K[:2, 2]
    depth, coords = _load(out, "depth"), _load(out, "material_coords")
    pixel = np.round(uv).astype(int)
    inside = (pixel[:, 0] > 0) & (pixel[:, 0] < 64) & (pixel[:, 1] > 0) & (pixel[:, 1] < 48)
    assert inside.sum() >= 12
    for (u, v), x, (du, dv), zc in zip(pixel[inside], top[inside], (uv - pixel)[inside], cam[inside, 2]):
        # the pixel centre's ray hits within half a pixel's footprint of the vertex: at most (1/2)(z/f)/cos on
        # each image axis, cos = |n . view| >= 0.5 here; and its depth differs by the plane's slope over it
        footprint = np.hypot(du, dv) * zc / K[0, 0] / 0.5
        assert np.linalg.norm(coords[v, u] - x) <= footprint + 1e-7
        assert abs(depth[v, u] - zc) <= footprint
    # all covered pixels: material coordinates (at rest = where the surface is) are the depth reprojected
    _, D = _rays(cams)
    _, _, _, C = _camera(cams)
    seen = np.isfinite(depth)
    X = C + depth[seen][:, None].astype(float) * D[seen]
    bound = F32 * np.abs(X).max() + (F32 + F64) * depth[seen].max() * np.linalg.norm(D[seen], axis=1).max()
    assert np.abs(coords[seen] - X).max() <= bound


@pytest.fixture(scope="module")
def pressed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pressed")
    scene = _scene(tmp, PRESSED)
    arrays = tissuerender.render_passes(scene, frame=FRAME)
    checked = check_scene(scene)
    for _ in range(1, FRAME):
        advance(checked.world, scene, checked.recorder)
    return scene, arrays, checked.world


def _first_hits(C, D, A, B, Cc):
    """Nearest ray-triangle hit (Moller-Trumbore) of rays C + s D against triangles (A, B, Cc): per ray the
    triangle index (-1: none), s (= camera z, D has camera z 1) and barycentrics (1 - b1 - b2, b1, b2)."""
    e1, e2 = B - A, Cc - A
    p = np.cross(D[:, None, :], e2[None])
    det = np.einsum("ktd,td->kt", p, e1)
    ok = np.abs(det) > 1e-30
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s0 = C - A
    b1 = np.einsum("ktd,td->kt", p, s0[:, :]) * inv
    q = np.cross(s0, e1)
    b2 = np.einsum("kd,td->kt", D, q) * inv
    s = np.einsum("td,td->t", e2, q)[None] * inv
    valid = ok & (b1 >= -1e-12) & (b2 >= -1e-12) & (b1 + b2 <= 1 + 1e-12) & (s > 0)
    s = np.where(valid, s, np.inf)
    tri = np.argmin(s, axis=1)
    rows = np.arange(D.shape[0])
    best = s[rows, tri]
    bary = np.stack([1 - b1[rows, tri] - b2[rows, tri], b1[rows, tri], b2[rows, tri]], axis=1)
    return np.where(np.isfinite(best), tri, -1), best, bary


def test_material_coords_of_a_pressed_body_are_the_rest_positions_of_the_points_seen(pressed):
    scene, arrays, world = pressed
    body = world.bodies[0]
    x = body.surface_points(world.states[0].x)  # the deformed render surface at frame 3
    X = body.surface.points  # its rest positions
    T = body.surface.triangles
    cams = arrays["camera"]
    C, D = _rays(cams)
    ids, depth, coords = arrays["segmentation"], arrays["depth"], arrays["material_coords"]
    on_body = ids == 1
    assert on_body.sum() > 500
    tri, s, bary = _first_hits(C, D[on_body], x[T[:, 0]], x[T[:, 1]], x[T[:, 2]])
    assert (tri >= 0).all()
    # the depth pass is the camera z of the surface point each pixel's ray meets first
    assert (np.abs(depth[on_body] - s) <= (F32 + F64) * s).all()
    expected = np.einsum("kc,kcd->kd", bary, X[T[tri]])  # that material point's rest position
    err = np.linalg.norm(coords[on_body] - expected, axis=1)
    assert err.max() <= 2 * F32 * np.abs(X).max() + F64, err.max()
    # the body is deformed where it is seen: rest and current positions differ by up to millimetres
    current = C + depth[on_body][:, None].astype(float) * D[on_body]
    assert np.linalg.norm(current - coords[on_body], axis=1).max() > 0.004
    # nothing but the body has material coordinates
    assert np.isnan(coords[~on_body]).all() and np.isfinite(coords[on_body]).all()


def test_segmentation_ids_never_blend_with_supersampling(pressed):
    scene, arrays, world = pressed
    labels = arrays["labels"]
    assert [(e["id"], e["name"], e["kind"]) for e in labels] == [(0, "background", "background"),
                                                                 (1, "slab", "body"), (2, "probe", "tool")]
    ids = arrays["segmentation"]
    assert ids.dtype == np.int32 and set(np.unique(ids)) == {0, 1, 2}
    # every probe pixel sees the probe's sphere: its reprojected point is on the tessellated sphere (within
    # the icosphere's sagitta) and not on the body or the background, which a blended id would not be
    C, D = _rays(arrays["camera"])
    depth = arrays["depth"]
    probe = ids == 2
    centre = np.array([0.04, 0.04, 0.056 + (0.044 - 0.056) * (2 / 24) / 0.1])
    r = np.linalg.norm(C + depth[probe][:, None].astype(float) * D[probe] - centre, axis=1)
    sagitta = 0.015 * (1 - np.cos(np.radians(8.0)))  # icosphere level 3: edges span under 8 degrees of arc
    assert probe.sum() > 50 and (r <= 0.015 + 1e-9).all() and (r >= 0.015 - sagitta).all()
    assert np.array_equal(ids == 0, np.isinf(depth))
    assert arrays["colour"].shape == (49, 65, 3) and arrays["hdr"].dtype == np.float32


def test_passes_are_planned_only_when_asked_for_and_unknown_names_are_refused(tmp_path, capsys):
    plain = copy.deepcopy(PLANE)
    del plain["output"]["passes"]
    assert not any(n.startswith("passes.") or n == "write_passes" for n in make_plan(_scene(tmp_path, plain)).names)
    some = copy.deepcopy(PLANE)
    some["output"]["passes"] = ["segmentation"]
    names = make_plan(_scene(tmp_path, some)).names
    assert [n for n in names if "passes" in n] == ["passes.raster", "passes.segmentation", "write_passes"]
    bad = copy.deepcopy(PLANE)
    bad["output"]["passes"] = ["depth", "disparity"]
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(bad))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "output.passes" in err and "disparity" in err and len(err.splitlines()) == 1


def test_resume_keeps_frames_with_their_pass_files_and_cameras_json_lists_every_finished_frame(tmp_path):
    data = copy.deepcopy(PLANE)
    data["output"].update(frames=3, passes=["depth", "segmentation"])
    scene = _scene(tmp_path, data)
    out = tmp_path / "out"
    tissuerender.render(scene, out, progress=False, frames=2)  # an interrupted run: two of three frames
    cams = json.loads((out / "cameras.json").read_text())
    assert [f["index"] for f in cams["frames"]] == [1, 2] and cams["frames"][1]["time"] == 1 / 24
    reference = _load(out, "depth", 2).copy()
    (out / "passes" / "segmentation_0002.npy").unlink()  # frame 2 is no longer complete
    run = tissuerender.render(scene, out, resume=True, progress=False)
    assert [p.name for p in run.skipped] == ["frame_0001.png"]
    assert "segmentation_0002.npy" in [p.name for p in run.written]
    assert [f["index"] for f in json.loads((out / "cameras.json").read_text())["frames"]] == [1, 2, 3]
    assert np.array_equal(_load(out, "depth", 2), reference)
    assert sorted(p.name for p in (out / "passes").iterdir()) == [
        f"{n}_{k:04d}.npy" for n in ("depth", "segmentation") for k in (1, 2, 3)]


def test_render_passes_refuses_a_pass_it_cannot_make(plane):
    scene, _ = plane
    with pytest.raises(tissuerender.UserError, match="render_passes: passes: .* found 'flow'"):
        tissuerender.render_passes(scene, passes=["depth", "flow"])


def test_material_coords_survive_the_near_plane_cut(plane, tmp_path):
    # the near plane at 0.2 m cuts the slab's near part away: the triangles it crosses get new vertices on
    # their edges, whose rest positions must be carried along (a static body: rest = where it is)
    data = copy.deepcopy(PLANE)
    data["camera"]["near"] = 0.2
    arrays = tissuerender.render_passes(_scene(tmp_path, data))
    depth, coords = arrays["depth"], arrays["material_coords"]
    C, D = _rays(arrays["camera"])
    seen = np.isfinite(depth)
    assert seen.sum() > 200 and depth[seen].min() >= np.float32(0.2)
    X = C + depth[seen][:, None].astype(float) * D[seen]
    assert (np.abs(X[:, 2] - TOP) < 1e-7).mean() > 0.5  # mostly the top face (to float32 depth), beyond the cut
    assert _load(plane[1], "depth").min() < 0.18  # which, without the cut, is seen from 0.175 m on
    bound = F32 * np.abs(X).max() + (F32 + F64) * depth[seen].max() * np.linalg.norm(D[seen], axis=1).max()
    assert np.abs(coords[seen] - X).max() <= bound
