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
2. ``scene_flow = X2 - X`` [m, world]; ``flow = project_t2(X2) - project_t(X)`` [pixels], both through ``K``
   and ``world_to_camera`` as :func:`_project` (``project_t(X)`` is the pixel centre up to rounding).
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

Each frame is re-rasterised once (:func:`frame_raster`) and the raster serves both roles, frame ``t`` of its
own flows and frame ``t2`` of its neighbours' (and the tracks'); steps 1 to 3 run per pixel (per track point)
in ``motion_kernels``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from tissuerender.groundtruth.cameras import intrinsics, world_to_camera
from tissuerender.groundtruth.lens import FisheyeLens, fisheye_lens
from tissuerender.groundtruth.motion_kernels import pixel_motion, point_motion, triangle_gradients
from tissuerender.renderer.camera import Camera
from tissuerender.renderer.gbuffer import RenderSurface, clip_near, rasterise


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
class FrameRaster:
    """A frame re-rasterised once at its pixel centres (step 1), shared by its own flows, its neighbours' flows
    towards it and the tracks. The clipped render surface: ``points`` (m, 3) float64 [m], ``triangles`` (t, 3)
    int64, ``tri_object`` (t,) and ``carried`` (m, 3 j) the vertex positions of the ``j`` other frames it was
    asked to carry, through the near-plane cut like the points. Per output pixel: ``tri_id`` (H, W) (-1: nothing
    seen) and ``bary`` (H, W, 3) (through a lens, the pinhole raster remapped nearest). The visible surface of
    the occlusion test, in the pinhole raster (``view``): ``depth`` (H_p, W_p) camera z (inf: nothing) and
    ``grad_w`` (H_p, W_p) the screen gradient magnitude of ``1/z`` of the triangle seen [1/(m px)]. The rest are
    the cameras as :mod:`motion_kernels` reads them."""

    geometry: Geometry
    lens: FisheyeLens | None
    view: Camera
    points: np.ndarray
    triangles: np.ndarray
    tri_object: np.ndarray
    carried: np.ndarray
    tri_id: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    grad_w: np.ndarray
    pose: np.ndarray  # (3, 4) [R | t] world to OpenCV camera
    fx_fy_cx_cy: np.ndarray  # (4,) of the output image's K (the distorted camera's through a lens)
    lens_k: np.ndarray  # (4,) k1..k4, zeros without a lens
    K_view: np.ndarray  # (3, 3) K of the pinhole raster
    map_col: np.ndarray  # (H, W) int64 the pinhole pixel each distorted pixel samples ((0, 0) without a lens)
    map_row: np.ndarray

    @property
    def covered(self) -> np.ndarray:
        return self.tri_id >= 0


def _camera_coords(points: np.ndarray, camera: Camera) -> np.ndarray:
    """OpenCV camera coordinates (x right, y down, z forward) [m] of world points (..., 3)."""
    T = world_to_camera(camera)
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


def _project(points: np.ndarray, camera: Camera, lens: FisheyeLens | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World points (..., 3) -> output pixel coordinates ((..., 2) (u, v), OpenCV convention, pixel (column u,
    row v)'s centre at integer (u, v); (...,) camera z [m]), through ``K`` and ``world_to_camera`` as written to
    ``cameras.json`` (and the lens's distortion when ``lens`` is given): the projection
    ``motion_kernels.point_motion`` makes for every 2D motion value, for points given in NumPy."""
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
    ``1/z = n . K^-1 (u, v, 1) / d``, so ``grad w = (n^T K^-1)[:2] / d``. inf for a plane through the eye.
    (The NumPy form of ``motion_kernels._inverse_depth_gradient``, which the passes use.)"""
    c = _camera_coords(corners, camera)
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    d = np.einsum("kd,kd->k", n, c[:, 0])
    g = (n @ np.linalg.inv(intrinsics(camera)))[:, :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        grad = np.linalg.norm(g, axis=1) / np.abs(d)
    return np.where(np.isfinite(grad), grad, np.inf)


def _surface(geom: Geometry, attributes: np.ndarray) -> RenderSurface:
    n = geom.points.shape[0]
    # contiguous float64 / int64 whatever the caller's arrays: the kernels keep one compiled signature
    return RenderSurface(np.ascontiguousarray(geom.points, float), np.ascontiguousarray(geom.triangles, np.int64),
                         np.zeros((n, 3)), attributes, np.asarray(geom.tri_object, np.int64))


_NO_MAP = np.zeros((0, 0), np.int64)


def frame_raster(geom: Geometry, targets=()) -> FrameRaster:
    """Re-rasterise ``geom`` at its camera's pixel centres, carrying each of ``targets`` (vertex positions
    (n, 3) of other frames, same triangles) through the near-plane cut, with its visible surface."""
    n = geom.points.shape[0]
    for points in targets:
        if np.shape(points) != (n, 3):
            raise ValueError(f"frame_raster: expected target vertex positions of shape ({n}, 3), found "
                             f"{np.shape(points)}")
    attributes = np.concatenate([np.asarray(p, float) for p in targets], axis=1) if len(targets) else np.zeros((n, 0))
    lens = lens_of(geom.camera, geom.lens_k)
    view = geom.camera if lens is None else lens.pinhole
    surface, raster = rasterise(_surface(geom, attributes), view, 1, False, 0)
    pose = np.ascontiguousarray(world_to_camera(view)[:3, :])
    K_view = intrinsics(view)
    grad_tri = np.empty(surface.triangles.shape[0])
    triangle_gradients(surface.triangles, surface.points, pose, np.linalg.inv(K_view), grad_tri)
    covered = raster.tri_id >= 0
    grad_w = np.zeros(raster.depth.shape)
    grad_w[covered] = grad_tri[raster.tri_id[covered]]
    tri_id, bary = raster.tri_id, raster.bary
    if lens is None:
        K, lens_k, map_col, map_row = K_view, np.zeros(4), _NO_MAP, _NO_MAP
    else:  # the distorted image's pixels: the remap of every other pass
        tri_id, bary = lens.remap_nearest(tri_id), lens.remap_nearest(bary)
        K, lens_k = lens.K, np.asarray(lens.k, float)
        map_col, map_row = np.rint(lens.map_u).astype(np.int64), np.rint(lens.map_v).astype(np.int64)
    return FrameRaster(geom, lens, view, surface.points, surface.triangles, surface.tri_material,
                       surface.attributes, tri_id, bary, raster.depth, grad_w, pose,
                       np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]), lens_k, K_view, map_col, map_row)


def carried_through_cut(source: FrameRaster, points: np.ndarray, corners: np.ndarray | None = None) -> np.ndarray:
    """Vertex positions ``points`` (n, 3) of another frame on ``source``'s clipped surface (m, 3) float64: the
    cut vertices interpolated along their edges as ``clip_near`` interpolates ``source.carried``. When the only
    vertices read are ``corners`` (clipped vertex ids) and none of them is a cut vertex, the cut vertices are
    left NaN instead (no cut to redo)."""
    points = np.asarray(points, float)
    n, m = points.shape[0], source.points.shape[0]
    if m == n:  # nothing was cut
        return points
    if corners is not None and (corners.size == 0 or corners.max() < n):
        return np.concatenate([points, np.full((m - n, 3), np.nan)])
    geom = source.geometry
    return clip_near(np.asarray(geom.points, float), np.zeros((n, 3)), points,
                     np.asarray(geom.triangles, np.int64), np.asarray(geom.tri_object, np.int64), source.view)[2]


def _target_arguments(source: FrameRaster, triangles: np.ndarray, points2: np.ndarray, target: FrameRaster) -> tuple:
    """The arguments of ``motion_kernels.point_motion`` / ``pixel_motion`` from ``pose`` to ``grad_A``: both
    cameras, ``target``'s visible surface and the inverse-depth gradient of ``triangles`` (of ``source``'s
    clipped surface) at ``target``'s vertex positions ``points2`` (in ``target``'s raster)."""
    camera = target.geometry.camera
    grad_A = np.empty(triangles.shape[0])
    triangle_gradients(triangles, points2, target.pose, np.linalg.inv(target.K_view), grad_A)
    return (source.pose, source.fx_fy_cx_cy, source.lens_k, source.lens is not None, target.pose,
            target.fx_fy_cx_cy, target.lens_k, target.lens is not None, float(camera.near), float(camera.far),
            target.K_view, target.depth, target.grad_w, target.map_col, target.map_row, grad_A)


def points_motion(source: FrameRaster, tri: np.ndarray, bary: np.ndarray, points2: np.ndarray,
                  target: FrameRaster) -> tuple:
    """The motion of ``source``'s material points (clipped triangle ``tri`` (k,), barycentrics ``bary`` (k, 3))
    to ``target``'s frame, whose vertex positions on ``source``'s clipped surface are ``points2`` (m, 3):
    (``uv`` (k, 2) in ``source``'s pixels, ``uv2`` (k, 2) in ``target``'s, ``X``, ``X2`` (k, 3) world [m],
    ``occluded`` (k,)); module docstring, steps 1 to 3 (``motion_kernels.point_motion``)."""
    k = tri.shape[0]
    uv, uv2, X, X2 = np.empty((k, 2)), np.empty((k, 2)), np.empty((k, 3)), np.empty((k, 3))
    occluded = np.zeros(k, bool)
    points2 = np.ascontiguousarray(points2, float)
    triangles = source.triangles[np.asarray(tri, np.int64)]  # point i on triangle i: gradients of these only
    point_motion(np.arange(k, dtype=np.int64), np.ascontiguousarray(bary, float), triangles, source.points, points2,
                 *_target_arguments(source, triangles, points2, target), uv, uv2, X, X2, occluded)
    return uv, uv2, X, X2, occluded


def motion_to(source: FrameRaster, j: int, target: FrameRaster) -> tuple:
    """(flow, occluded, scene_flow) of ``source``'s pixels to ``target``'s frame, whose vertex positions
    ``source`` carries as its ``j``-th target (see :func:`flow_between`)."""
    h, w = source.tri_id.shape
    flow = np.empty((h, w, 2), np.float32)
    scene_flow = np.empty((h, w, 3), np.float32)
    occluded = np.empty((h, w), bool)
    points2 = np.ascontiguousarray(source.carried[:, 3 * j:3 * j + 3])
    pixel_motion(source.tri_id, source.bary, source.triangles, source.points, points2,
                 *_target_arguments(source, source.triangles, points2, target), flow, scene_flow, occluded)
    return flow, occluded, scene_flow


def flow_between(geom_t: Geometry, geom_t2: Geometry, cam_t: Camera | None = None, cam_t2: Camera | None = None):
    """Optical flow, occlusion and scene flow of frame ``t``'s pixels to frame ``t2``.

    Parameters
    ----------
    geom_t, geom_t2 : Geometry
        The two frames' render geometry (same triangles).
    cam_t, cam_t2 : Camera, optional
        The cameras (default: each geometry's own).

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
    source = frame_raster(replace(geom_t, camera=cam_t), [geom_t2.points])
    return motion_to(source, 0, frame_raster(replace(geom_t2, camera=cam_t2)))


def no_neighbour(covered: np.ndarray) -> tuple:
    """(flow, occluded, scene_flow) toward a frame that does not exist, for a frame whose seen pixels are
    ``covered`` (H, W): NaN motion, every seen pixel occluded."""
    h, w = covered.shape
    return (np.full((h, w, 2), np.nan, np.float32), covered.copy(), np.full((h, w, 3), np.nan, np.float32))


def neighbour_flows(source: FrameRaster, previous: FrameRaster | None, following: FrameRaster | None) -> dict:
    """A frame's backward (to ``previous``) and forward (to ``following``) motion; ``source`` carries the
    vertex positions of the neighbours that exist, previous first (:func:`frame_raster`): a dict with the pass
    file names ``flow_forward``, ``flow_backward``, ``occluded_forward``, ``occluded_backward``,
    ``scene_flow_forward``, ``scene_flow_backward``; a missing neighbour (None) gives NaN motion and every seen
    pixel occluded."""
    out = {}
    j = 0
    for name, other in (("backward", previous), ("forward", following)):
        if other is None:
            arrays = no_neighbour(source.covered)
        else:
            arrays = motion_to(source, j, other)
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
