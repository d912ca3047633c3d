"""Motion ground truth from the known surface motion: optical flow, scene flow and occlusion between any two
frames, computed from each frame's render geometry (never estimated from images).

A frame's **geometry** is every render object's vertex positions (the deformed bodies, static surfaces and
visible tools, exactly as the colour image draws them) and the camera that saw them; the triangles are fixed
for a sequence. The motion of frame ``t``'s pixels to frame ``t2``:

1. Re-rasterise frame ``t`` with one sample at each pixel centre (``tissuerender.renderer.gbuffer.rasterise``,
   the same raster as the other passes), carrying frame ``t2``'s vertex positions as a vertex attribute. The
   pixel's surface point is ``X = sum_i b_i P_i`` (perspective-correct barycentrics ``b`` of its triangle) and
   the same material point in frame ``t2`` is ``X2 = sum_i b_i P2_i``. Triangles cut by the near plane carry
   ``P2`` through the cut linearly, like the rest positions of ``material_coords``, so ``X2`` stays exact.
2. ``scene_flow = X2 - X`` [m, world]; ``flow = project_t2(X2) - project_t(X)`` [pixels], both through
   :func:`_project` (``project_t(X)`` is the pixel centre up to rounding).
3. **Occlusion**: ``X2`` is hidden in frame ``t2`` when it projects outside the image, lies outside
   ``[near, far]``, or lies behind frame ``t2``'s visible surface at its nearest pixel ``q``. The test is made
   in inverse depth ``w = 1/z``, which is exactly affine in pixel position over a planar triangle: on the
   continuous surface through ``X2``, ``w`` changes between ``X2``'s pixel position and ``q``'s centre (a
   distance ``r <= sqrt(2)/2`` px) by at most ``(|grad w_A| + |grad w_B|) r``, with ``A`` the triangle
   holding ``X2`` and ``B`` the triangle visible at ``q`` (both in frame ``t2``; the surface between them is
   assumed covered by these two, i.e. triangles about a pixel across or more). So ``X2`` is occluded when

       w(X2) < w_q - (|grad w_A| + |grad w_B|) r - 1e-9 w(X2),

   the last term covering float64 rounding of the few dozen operations behind ``w`` (both sides come from the
   same float32 vertices, so the float32 storage of the geometry cancels). A triangle seen exactly edge-on has
   an infinite gradient, so a point on it is taken as visible. Pixels that see nothing are never occluded;
   their flows are NaN.

**Through a lens** (``Geometry.lens_k``, ``[camera.lens]``): every 2D value is in the distorted image's pixels.
The per-pixel raster of a frame is its lens's pinhole raster remapped by ``FisheyeLens.remap_nearest`` (the
remap of every other pass), so a distorted pixel's ``X`` is the point its depth, segmentation and material
coordinates show; ``project`` is ``FisheyeLens.project`` (so ``project_t(X)`` is within the nearest remap's
half pinhole pixel, carried through the distortion, of the pixel centre). Off-screen is decided in distorted
pixels. The inverse-depth comparison is made in the pinhole raster, where ``w`` is still exactly affine per
planar triangle, so the bound above holds unchanged with ``r`` the exact distance in pinhole pixels between
``X2``'s undistorted position and the centre of the pinhole pixel that ``X2``'s nearest distorted pixel
samples (no longer bounded by ``sqrt(2)/2``: it is computed per point, and the gradients are per pinhole
pixel, ``K`` the pinhole's).

The geometry is stored as float32 (``write_geometry``), so a re-raster may differ from the colour image's
float64 raster on a pixel whose centre lies within float32 rounding of a silhouette edge.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np


from tissuerender.groundtruth.cameras import intrinsics, world_to_camera
from tissuerender.groundtruth.lens import FisheyeLens, fisheye_lens
from tissuerender.renderer.camera import Camera
from tissuerender.renderer.gbuffer import RenderSurface, rasterise

W_ROUNDING = 1e-9  # relative float64 rounding allowance of an inverse depth (module docstring)


@dataclass
class Geometry:
    """One frame's render geometry: vertex ``points`` (n, 3) [m] of every render object in draw order,
    ``triangles`` (t, 3) into them (fixed for a sequence), ``tri_object`` (t,) the render object index of each
    triangle (segmentation id - 1) and the ``camera``; ``lens_k`` the Kannala-Brandt coefficients (k1..k4) of
    ``[camera.lens]`` (None: a pinhole)."""

    points: np.ndarray
    triangles: np.ndarray
    tri_object: np.ndarray
    camera: Camera
    lens_k: tuple | None = None


@lru_cache(maxsize=8)
def _lens_at_origin(fov_deg: float, width: int, height: int, k: tuple) -> FisheyeLens:
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 1.0, 0.0), up=(0.0, 0.0, 1.0), fov_deg=fov_deg,
                    near=1.0, far=2.0, width=width, height=height)
    return fisheye_lens(camera, k)


def lens_of(camera: Camera, lens_k) -> FisheyeLens | None:
    """The lens (no vignetting: it touches no pass) of coefficients ``lens_k`` on ``camera`` (its pinhole posed
    as ``camera``), None for ``lens_k`` None. Built from the field, size and coefficients as the render's."""
    if lens_k is None:
        return None
    lens = _lens_at_origin(float(camera.fov_deg), int(camera.width), int(camera.height),
                           tuple(float(c) for c in lens_k))
    p = lens.pinhole
    return replace(lens, pinhole=replace(camera, width=p.width, height=p.height, fov_deg=p.fov_deg))


@dataclass
class _Carried:
    """A frame re-rasterised at pixel centres, carrying other frames' vertex positions: ``covered`` (H, W),
    per covered pixel (row-major order) the render object ``obj`` (k,), the point ``X`` (k, 3) and per carried
    frame its material point (k, 3) in ``targets`` and its triangle's three corners (k, 3, 3) in ``corners``."""

    covered: np.ndarray
    obj: np.ndarray
    X: np.ndarray
    targets: list
    corners: list


@dataclass
class _Visible:
    """Frame ``t2``'s visible surface for the occlusion test: ``depth`` (H, W) camera z (inf: nothing),
    ``grad_w`` (H, W) the screen gradient magnitude of ``1/z`` of the triangle seen at each pixel [1/(m px)]."""

    depth: np.ndarray
    grad_w: np.ndarray
    lens: FisheyeLens | None = None  # with a lens, both are the pinhole raster's (module docstring)


def _camera_coords(points: np.ndarray, camera: Camera) -> np.ndarray:
    """OpenCV camera coordinates (x right, y down, z forward) [m] of world points (..., 3)."""
    T = world_to_camera(camera)
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


def _project(points: np.ndarray, camera: Camera, lens: FisheyeLens | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The one projection of world points (..., 3) into output pixel coordinates: ((..., 2) (u, v), OpenCV
    convention, pixel (column u, row v)'s centre at integer (u, v); (...,) camera z [m]). Through ``K`` and
    ``world_to_camera`` as written to ``cameras.json`` (and the lens's distortion when ``lens`` is given);
    every 2D motion value is made here."""
    xc = _camera_coords(points, camera)
    if lens is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            return lens.project(xc), xc[..., 2]
    K = intrinsics(camera)
    z = xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * xc[..., 0] / z + K[0, 2]
        v = K[1, 1] * xc[..., 1] / z + K[1, 2]
    return np.stack([u, v], axis=-1), z


def _inverse_depth_gradient(corners: np.ndarray, camera: Camera) -> np.ndarray:
    """|grad w| (k,) over the pinhole raster's pixels of ``w = 1/z`` on the planes of triangles with world
    ``corners`` (k, 3, 3): for the camera-space plane ``n . X = d`` and ``X = z K^-1 (u, v, 1)``,
    ``1/z = n . K^-1 (u, v, 1) / d``, so ``grad w = (n^T K^-1)[:2] / d``. inf for a plane through the eye."""
    c = _camera_coords(corners, camera)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    d = np.einsum("kd,kd->k", n, c[:, 0])
    g = (n @ np.linalg.inv(intrinsics(camera)))[:, :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        grad = np.linalg.norm(g, axis=1) / np.abs(d)
    return np.where(np.isfinite(grad), grad, np.inf)


def _surface(geom: Geometry, attributes: np.ndarray) -> RenderSurface:
    n = geom.points.shape[0]
    return RenderSurface(np.asarray(geom.points, float), np.asarray(geom.triangles, np.int64), np.zeros((n, 3)),
                         attributes, np.asarray(geom.tri_object, np.int64))


def carry(geom: Geometry, targets: list[np.ndarray]) -> _Carried:
    """Re-rasterise ``geom`` at its camera's pixel centres and carry each of ``targets`` (vertex positions
    (n, 3) of other frames, same triangles) to the material points its pixels see."""
    n = geom.points.shape[0]
    for points in targets:
        if np.shape(points) != (n, 3):
            raise ValueError(f"carry: expected target vertex positions of shape ({n}, 3), found {np.shape(points)}")
    attributes = np.concatenate([np.asarray(p, float) for p in targets], axis=1) if targets else np.zeros((n, 0))
    lens = lens_of(geom.camera, geom.lens_k)
    surface, raster = rasterise(_surface(geom, attributes), geom.camera if lens is None else lens.pinhole, 1, False, 0)
    tri_id, bary = raster.tri_id, raster.bary
    if lens is not None:  # the distorted image's pixels: the remap of every other pass
        tri_id, bary = lens.remap_nearest(tri_id), lens.remap_nearest(bary)
    covered = tri_id >= 0
    tri = tri_id[covered]
    bary = bary[covered]
    corners = surface.triangles[tri]  # (k, 3) clipped-surface vertex ids
    X = np.einsum("kc,kcd->kd", bary, surface.points[corners])
    carried, corner_points = [], []
    for j in range(len(targets)):
        P2 = surface.attributes[:, 3 * j:3 * j + 3]
        carried.append(np.einsum("kc,kcd->kd", bary, P2[corners]))
        corner_points.append(P2[corners])
    return _Carried(covered, surface.tri_material[tri], X, carried, corner_points)


def visible_surface(geom: Geometry) -> _Visible:
    """Frame ``geom``'s depth and per-pixel inverse-depth gradient, for :func:`occluded_in`."""
    lens = lens_of(geom.camera, geom.lens_k)
    view = geom.camera if lens is None else lens.pinhole
    surface, raster = rasterise(_surface(geom, np.zeros((geom.points.shape[0], 0))), view, 1, False, 0)
    covered = raster.tri_id >= 0
    grad = np.zeros(raster.depth.shape)
    grad[covered] = _inverse_depth_gradient(surface.points[surface.triangles[raster.tri_id[covered]]], view)
    return _Visible(raster.depth, grad, lens)


def occluded_in(X2: np.ndarray, corners2: np.ndarray, visible: _Visible, camera: Camera) -> np.ndarray:
    """(k,) bool: world points ``X2`` (k, 3) lying on triangles with corners ``corners2`` (k, 3, 3) are hidden
    in the frame whose visible surface is ``visible`` seen by ``camera`` (module docstring, step 3)."""
    if visible.lens is not None:
        return _occluded_through_lens(X2, corners2, visible, camera)
    h, w = visible.depth.shape
    xc = _camera_coords(X2, camera)
    z = xc[:, 2]
    K = intrinsics(camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        # the pinhole raster's pixel position (the raster is undistorted whatever _project adds)
        u = K[0, 0] * xc[:, 0] / z + K[0, 2]
        v = K[1, 1] * xc[:, 1] / z + K[1, 2]
    inside = ((z >= camera.near) & (z <= camera.far) & (u >= -0.5) & (u < w - 0.5) & (v >= -0.5) & (v < h - 0.5))
    occluded = ~inside
    k = np.flatnonzero(inside)
    col = np.floor(u[k] + 0.5).astype(np.int64)
    row = np.floor(v[k] + 0.5).astype(np.int64)
    w_point = 1.0 / z[k]
    w_seen = 1.0 / visible.depth[row, col]  # 0 where nothing is seen: never in front
    r = np.hypot(u[k] - col, v[k] - row)
    grad_A = _inverse_depth_gradient(corners2[k], camera)
    with np.errstate(invalid="ignore"):
        tolerance = (grad_A + visible.grad_w[row, col]) * r + W_ROUNDING * w_point
        occluded[k] = w_point < w_seen - np.nan_to_num(tolerance, nan=np.inf)
    return occluded


def _occluded_through_lens(X2, corners2, visible: _Visible, camera: Camera) -> np.ndarray:
    """:func:`occluded_in` through ``visible.lens``: off-screen in distorted pixels, the inverse-depth test in
    the pinhole raster at the pinhole pixel sampled by ``X2``'s nearest distorted pixel (module docstring)."""
    lens = visible.lens
    h, w = lens.height, lens.width
    xc = _camera_coords(X2, camera)
    z = xc[:, 2]
    ok = z > 0.0
    uv = np.full((z.size, 2), np.nan)
    uv[ok] = lens.project(xc[ok])
    with np.errstate(invalid="ignore"):
        inside = (ok & (z >= camera.near) & (z <= camera.far) & (uv[:, 0] >= -0.5) & (uv[:, 0] < w - 0.5)
                  & (uv[:, 1] >= -0.5) & (uv[:, 1] < h - 0.5))
    occluded = ~inside
    k = np.flatnonzero(inside)
    q_col = np.floor(uv[k, 0] + 0.5).astype(np.int64)
    q_row = np.floor(uv[k, 1] + 0.5).astype(np.int64)
    col = np.rint(lens.map_u[q_row, q_col]).astype(np.int64)  # the pinhole pixel remap_nearest gives q
    row = np.rint(lens.map_v[q_row, q_col]).astype(np.int64)
    K_p = intrinsics(lens.pinhole)
    u_p = K_p[0, 0] * xc[k, 0] / z[k] + K_p[0, 2]  # X2's undistorted position in the pinhole raster
    v_p = K_p[1, 1] * xc[k, 1] / z[k] + K_p[1, 2]
    w_point = 1.0 / z[k]
    w_seen = 1.0 / visible.depth[row, col]  # 0 where nothing is seen: never in front
    r = np.hypot(u_p - col, v_p - row)
    grad_A = _inverse_depth_gradient(corners2[k], lens.pinhole)
    with np.errstate(invalid="ignore"):
        tolerance = (grad_A + visible.grad_w[row, col]) * r + W_ROUNDING * w_point
        occluded[k] = w_point < w_seen - np.nan_to_num(tolerance, nan=np.inf)
    return occluded


def flow_between(geom_t: Geometry, geom_t2: Geometry, cam_t: Camera | None = None, cam_t2: Camera | None = None,
                 visible_t2: _Visible | None = None):
    """Optical flow, occlusion and scene flow of frame ``t``'s pixels to frame ``t2``.

    Parameters
    ----------
    geom_t, geom_t2 : Geometry
        The two frames' render geometry (same triangles).
    cam_t, cam_t2 : Camera, optional
        The cameras (default: each geometry's own).
    visible_t2 : optional
        ``visible_surface(geom_t2)`` when already computed.

    Returns
    -------
    flow : (H, W, 2) float32
        pixels (du, dv) from frame ``t`` to ``t2``, NaN where nothing is seen.
    occluded : (H, W) bool
        the pixel's surface point is hidden or off-screen in frame ``t2`` (False where nothing is seen).
    scene_flow : (H, W, 3) float32
        world motion [m] of the surface point, NaN where nothing is seen.
    """
    cam_t = geom_t.camera if cam_t is None else cam_t
    cam_t2 = geom_t2.camera if cam_t2 is None else cam_t2
    if geom_t.triangles.shape != geom_t2.triangles.shape or not np.array_equal(geom_t.triangles, geom_t2.triangles):
        raise ValueError("flow_between: the two frames' geometries have different triangles (not one sequence)")
    geom = Geometry(geom_t.points, geom_t.triangles, geom_t.tri_object, cam_t, geom_t.lens_k)
    carried = carry(geom, [geom_t2.points])
    if visible_t2 is None:
        visible_t2 = visible_surface(Geometry(geom_t2.points, geom_t2.triangles, geom_t2.tri_object, cam_t2,
                                              geom_t2.lens_k))
    return _motion_arrays(carried, 0, cam_t, cam_t2, visible_t2, lens_of(cam_t, geom_t.lens_k))


def _motion_arrays(carried: _Carried, j: int, cam_t: Camera, cam_t2: Camera, visible_t2: _Visible,
                   lens_t: FisheyeLens | None = None):
    """(flow, occluded, scene_flow) of target ``j`` of ``carried`` (see :func:`flow_between`); ``lens_t`` frame
    ``t``'s lens (frame ``t2``'s is ``visible_t2.lens``)."""
    h, w = carried.covered.shape
    X, X2 = carried.X, carried.targets[j]
    flow = np.full((h, w, 2), np.nan, np.float32)
    scene_flow = np.full((h, w, 3), np.nan, np.float32)
    occluded = np.zeros((h, w), bool)
    flow[carried.covered] = _project(X2, cam_t2, visible_t2.lens)[0] - _project(X, cam_t, lens_t)[0]
    scene_flow[carried.covered] = X2 - X
    occluded[carried.covered] = occluded_in(X2, carried.corners[j], visible_t2, cam_t2)
    return flow, occluded, scene_flow


def no_neighbour(covered: np.ndarray) -> tuple:
    """(flow, occluded, scene_flow) toward a frame that does not exist, for a frame whose seen pixels are
    ``covered`` (H, W): NaN motion, every seen pixel occluded."""
    h, w = covered.shape
    return (np.full((h, w, 2), np.nan, np.float32), covered.copy(), np.full((h, w, 3), np.nan, np.float32))


def neighbour_flows(geom: Geometry, previous: Geometry | None, following: Geometry | None,
                    visible_previous: _Visible | None = None, visible_following: _Visible | None = None) -> dict:
    """Frame ``geom``'s backward (to ``previous``) and forward (to ``following``) motion from one re-raster:
    a dict with the pass file names ``flow_forward``, ``flow_backward``, ``occluded_forward``,
    ``occluded_backward``, ``scene_flow_forward``, ``scene_flow_backward``; a missing neighbour (None) gives
    NaN motion and every seen pixel occluded."""
    neighbours = [g for g in (previous, following) if g is not None]
    carried = carry(geom, [g.points for g in neighbours])
    out = {}
    j = 0
    for name, other, visible in (("backward", previous, visible_previous), ("forward", following, visible_following)):
        if other is None:
            arrays = no_neighbour(carried.covered)
        else:
            visible = visible_surface(other) if visible is None else visible
            arrays = _motion_arrays(carried, j, geom.camera, other.camera, visible, lens_of(geom.camera, geom.lens_k))
            j += 1
        out[f"flow_{name}"], out[f"occluded_{name}"], out[f"scene_flow_{name}"] = arrays
    return out


def frame_geometry(objects, camera: Camera, lens_k=None) -> Geometry:
    """The render ``objects``' geometry (``tissuerender.renderer.RenderObject`` list, in draw order) as
    :class:`Geometry` with float32 points (as ``write_geometry`` stores them); ``lens_k`` the lens's
    coefficients (None: a pinhole)."""
    lens_k = None if lens_k is None else tuple(float(c) for c in lens_k)
    points, triangles, tri_object = [], [], []
    offset = 0
    for k, obj in enumerate(objects):
        p = np.asarray(obj.points, float)
        t = np.asarray(obj.triangles, np.int64)
        points.append(p)
        triangles.append(t + offset)
        tri_object.append(np.full(t.shape[0], k, np.int32))
        offset += p.shape[0]
    if not points:
        return Geometry(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros(0, np.int32), camera,
                        lens_k)
    return Geometry(np.concatenate(points).astype(np.float32), np.concatenate(triangles).astype(np.int32),
                    np.concatenate(tri_object), camera, lens_k)
