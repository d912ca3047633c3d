"""The per-pixel arithmetic of the single-frame passes (``passes`` module docstring) and of the KITTI flow PNG
(``formats.encode_kitti_flow``) as numba kernels. A covered pixel's pass value is ``sum_i b_i V_i`` over the
corners of the triangle it sees, summed in the order ``b0 V0 + b1 V1 + b2 V2`` (the order of the ``einsum``
they replace), without fused multiply-adds (no ``fastmath``). ``camera_normals`` runs its rows in ``prange``
(pixels are independent: the same result for any number of threads); the others do too little work per pixel
for a parallel region to pay for itself on a shared machine and run serially (docs/ground-truth.md, "Cost").
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def interpolate_pixels(values, triangles, tri_id, bary, out):
    """``out`` (H, W, d) = ``sum_i b_i values[corner_i]`` of the triangle ``tri_id`` (H, W) sees (``triangles``
    (t, 3) into ``values`` (n, d), barycentrics ``bary`` (H, W, 3)); NaN where ``tri_id`` is -1."""
    h, w = tri_id.shape
    d = values.shape[1]
    for row in range(h):
        for col in range(w):
            t = tri_id[row, col]
            if t < 0:
                for j in range(d):
                    out[row, col, j] = np.nan
                continue
            c0, c1, c2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            b0, b1, b2 = bary[row, col, 0], bary[row, col, 1], bary[row, col, 2]
            for j in range(d):
                out[row, col, j] = b0 * values[c0, j] + b1 * values[c1, j] + b2 * values[c2, j]


@njit(cache=True, parallel=True)
def camera_normals(normals, points, triangles, tri_id, bary, eye, R, out):
    """``out`` (H, W, 3): the interpolated vertex normal (``normals`` (n, 3)) of each covered pixel, normalised,
    turned towards the ``eye`` (3,) [m, world] when the surface point (``points`` (n, 3)) is seen from behind,
    and rotated into camera axes by ``R`` (3, 3) (rows: the camera's axes in world coordinates); NaN where
    ``tri_id`` is -1."""
    h, w = tri_id.shape
    for row in prange(h):
        for col in range(w):
            t = tri_id[row, col]
            if t < 0:
                out[row, col, 0] = np.nan
                out[row, col, 1] = np.nan
                out[row, col, 2] = np.nan
                continue
            c0, c1, c2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            b0, b1, b2 = bary[row, col, 0], bary[row, col, 1], bary[row, col, 2]
            n0 = b0 * normals[c0, 0] + b1 * normals[c1, 0] + b2 * normals[c2, 0]
            n1 = b0 * normals[c0, 1] + b1 * normals[c1, 1] + b2 * normals[c2, 1]
            n2 = b0 * normals[c0, 2] + b1 * normals[c1, 2] + b2 * normals[c2, 2]
            length = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)
            n0, n1, n2 = n0 / length, n1 / length, n2 / length
            p0 = b0 * points[c0, 0] + b1 * points[c1, 0] + b2 * points[c2, 0]
            p1 = b0 * points[c0, 1] + b1 * points[c1, 1] + b2 * points[c2, 1]
            p2 = b0 * points[c0, 2] + b1 * points[c1, 2] + b2 * points[c2, 2]
            if n0 * (eye[0] - p0) + n1 * (eye[1] - p1) + n2 * (eye[2] - p2) < 0.0:
                n0, n1, n2 = -n0, -n1, -n2  # seen from behind: the normal faces the viewer, as in shading
            for i in range(3):
                out[row, col, i] = R[i, 0] * n0 + R[i, 1] * n1 + R[i, 2] * n2


@njit(cache=True)
def kitti_flow_code(flow, scale, offset, out):
    """``out`` (H, W, 3) uint16: the KITTI flow PNG's ``rint(u * scale + offset)``, ``rint(v * scale + offset)``
    and 1 where both fit in 16 bits, (0, 0, 0) elsewhere (NaN fails every comparison) for ``flow`` (H, W, 2)
    float64 (``formats.encode_kitti_flow``)."""
    h, w = flow.shape[0], flow.shape[1]
    for row in range(h):
        for col in range(w):
            cu = np.rint(flow[row, col, 0] * scale + offset)
            cv = np.rint(flow[row, col, 1] * scale + offset)
            if cu >= 0.0 and cu <= 65535.0 and cv >= 0.0 and cv <= 65535.0:
                out[row, col, 0] = np.uint16(cu)
                out[row, col, 1] = np.uint16(cv)
                out[row, col, 2] = 1
            else:
                out[row, col, 0] = 0
                out[row, col, 1] = 0
                out[row, col, 2] = 0
