"""The per-point arithmetic of the motion passes (``motion`` module docstring, steps 1 to 3) as numba kernels:
interpolate a material point in two frames, project it through each frame's camera (and lens), and test it
against the other frame's visible surface. Pure functions over structure-of-arrays data; the cameras come
packed as arrays (``pose`` (3, 4) ``[R | t]`` world to OpenCV camera, ``fx_fy_cx_cy`` (4,), ``lens_k`` (4,)
Kannala-Brandt coefficients, read only when ``has_lens``), so each kernel has one compiled signature.

Every point is independent of the others, so ``pixel_motion``'s ``prange`` over rows gives the same result for
any number of threads; ``triangle_gradients`` and ``point_motion`` (the few track points) do too little work
per call for a parallel region to pay for itself on a shared machine and run serially (docs/ground-truth.md,
"Cost").

Sums run in the order of the NumPy expressions they replace (``b0 P0 + b1 P1 + b2 P2``, ``R x + t`` row by
row) without fused multiply-adds (no ``fastmath``); BLAS may sum or fuse ``R x + t`` differently, so a value
can differ from the NumPy form in its last float64 bit.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

W_ROUNDING = 1e-9  # relative float64 rounding allowance of an inverse depth (motion module docstring, step 3)


@njit(cache=True, inline="always")
def _to_camera(pose, x0, x1, x2):
    """OpenCV camera coordinates of world point ``(x0, x1, x2)``: ``R X + t``."""
    c0 = pose[0, 0] * x0 + pose[0, 1] * x1 + pose[0, 2] * x2 + pose[0, 3]
    c1 = pose[1, 0] * x0 + pose[1, 1] * x1 + pose[1, 2] * x2 + pose[1, 3]
    c2 = pose[2, 0] * x0 + pose[2, 1] * x1 + pose[2, 2] * x2 + pose[2, 3]
    return c0, c1, c2


@njit(cache=True, inline="always")
def _pixel(c0, c1, c2, fx_fy_cx_cy, lens_k, has_lens):
    """Output pixel ``(u, v)`` of camera point ``c``: ``K`` as a pinhole, or the Kannala-Brandt projection
    (``lens`` module docstring: ``theta_d = theta (1 + k1 theta^2 + ...)``, ``(x_d, y_d) = theta_d / r (a, b)``)."""
    if not has_lens:
        return fx_fy_cx_cy[0] * c0 / c2 + fx_fy_cx_cy[2], fx_fy_cx_cy[1] * c1 / c2 + fx_fy_cx_cy[3]
    a = c0 / c2
    b = c1 / c2
    r = np.hypot(a, b)
    scale = 1.0  # theta_d / r -> 1 on the axis
    if r > 0.0:
        theta = np.arctan(r)
        t2 = theta * theta
        scale = theta * (1.0 + t2 * (lens_k[0] + t2 * (lens_k[1] + t2 * (lens_k[2] + t2 * lens_k[3])))) / r
    return fx_fy_cx_cy[0] * (a * scale) + fx_fy_cx_cy[2], fx_fy_cx_cy[1] * (b * scale) + fx_fy_cx_cy[3]


@njit(cache=True)
def _inverse_depth_gradient(pose, K_inv, p, q, s):
    """|grad w| over the pinhole raster's pixels of ``w = 1/z`` on the plane through world points ``p``, ``q``,
    ``s`` (3,): ``(n^T K^-1)[:2] / d`` for the camera-space plane ``n . X = d``; inf for a plane through the eye
    (``motion._inverse_depth_gradient``)."""
    a0, a1, a2 = _to_camera(pose, p[0], p[1], p[2])
    b0, b1, b2 = _to_camera(pose, q[0], q[1], q[2])
    e0, e1, e2 = _to_camera(pose, s[0], s[1], s[2])
    u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
    v0, v1, v2 = e0 - a0, e1 - a1, e2 - a2
    n0 = u1 * v2 - u2 * v1
    n1 = u2 * v0 - u0 * v2
    n2 = u0 * v1 - u1 * v0
    d = n0 * a0 + n1 * a1 + n2 * a2
    g0 = n0 * K_inv[0, 0] + n1 * K_inv[1, 0] + n2 * K_inv[2, 0]
    g1 = n0 * K_inv[0, 1] + n1 * K_inv[1, 1] + n2 * K_inv[2, 1]
    grad = np.sqrt(g0 * g0 + g1 * g1) / abs(d)
    return grad if np.isfinite(grad) else np.inf


@njit(cache=True)
def triangle_gradients(triangles, points, pose, K_inv, grad):
    """``grad`` (t,) = ``_inverse_depth_gradient`` of each of ``triangles`` (t, 3) into ``points`` (n, 3)
    [m, world], seen by the camera of ``pose`` in the raster of inverse intrinsics ``K_inv``."""
    for t in range(triangles.shape[0]):
        grad[t] = _inverse_depth_gradient(pose, K_inv, points[triangles[t, 0]], points[triangles[t, 1]],
                                          points[triangles[t, 2]])


@njit(cache=True, inline="always")
def _motion(t, b0, b1, b2, triangles, points, points2, pose, fx_fy_cx_cy, lens_k, has_lens,
            pose2, fx_fy_cx_cy2, lens_k2, has_lens2, near2, far2, K_p2, depth2, grad_w2, map_col2, map_row2,
            grad_A):
    """One material point (triangle ``t``, barycentrics ``b``) of the frame: (X, X2, uv, uv2, occluded) as
    (Xx, Xy, Xz, Yx, Yy, Yz, u1, v1, u2, v2, occluded), ``Y`` standing for X2; see :func:`point_motion`."""
    c0, c1, c2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
    Xx = b0 * points[c0, 0] + b1 * points[c1, 0] + b2 * points[c2, 0]
    Xy = b0 * points[c0, 1] + b1 * points[c1, 1] + b2 * points[c2, 1]
    Xz = b0 * points[c0, 2] + b1 * points[c1, 2] + b2 * points[c2, 2]
    Yx = b0 * points2[c0, 0] + b1 * points2[c1, 0] + b2 * points2[c2, 0]
    Yy = b0 * points2[c0, 1] + b1 * points2[c1, 1] + b2 * points2[c2, 1]
    Yz = b0 * points2[c0, 2] + b1 * points2[c1, 2] + b2 * points2[c2, 2]
    p0, p1, p2 = _to_camera(pose, Xx, Xy, Xz)
    u1, v1 = _pixel(p0, p1, p2, fx_fy_cx_cy, lens_k, has_lens)
    y0, y1, z = _to_camera(pose2, Yx, Yy, Yz)
    u, v = _pixel(y0, y1, z, fx_fy_cx_cy2, lens_k2, has_lens2)
    # the pinhole raster's position of X2 (the raster is undistorted whatever the lens adds)
    u_p = K_p2[0, 0] * y0 / z + K_p2[0, 2]
    v_p = K_p2[1, 1] * y1 / z + K_p2[1, 2]
    if has_lens2:
        h2, w2 = map_col2.shape[0], map_col2.shape[1]
        inside = z > 0.0 and z >= near2 and z <= far2 and u >= -0.5 and u < w2 - 0.5 and v >= -0.5 \
            and v < h2 - 0.5
    else:
        h2, w2 = depth2.shape[0], depth2.shape[1]
        inside = z >= near2 and z <= far2 and u_p >= -0.5 and u_p < w2 - 0.5 and v_p >= -0.5 and v_p < h2 - 0.5
    if not inside:
        return Xx, Xy, Xz, Yx, Yy, Yz, u1, v1, u, v, True
    if has_lens2:
        q_col = int(np.floor(u + 0.5))
        q_row = int(np.floor(v + 0.5))
        col, row = map_col2[q_row, q_col], map_row2[q_row, q_col]
    else:
        col, row = int(np.floor(u_p + 0.5)), int(np.floor(v_p + 0.5))
    w_point = 1.0 / z
    w_seen = 1.0 / depth2[row, col]  # 0 where nothing is seen: never in front
    r = np.hypot(u_p - col, v_p - row)
    tolerance = (grad_A[t] + grad_w2[row, col]) * r + W_ROUNDING * w_point
    # an edge-on triangle (infinite gradient, or inf * 0): the point counts as visible
    return Xx, Xy, Xz, Yx, Yy, Yz, u1, v1, u, v, np.isfinite(tolerance) and w_point < w_seen - tolerance


@njit(cache=True)
def point_motion(tri, bary, triangles, points, points2, pose, fx_fy_cx_cy, lens_k, has_lens,
                 pose2, fx_fy_cx_cy2, lens_k2, has_lens2, near2, far2, K_p2, depth2, grad_w2, map_col2, map_row2,
                 grad_A, uv, uv2, X, X2, occluded):
    """The motion of material points ``(tri, bary)`` (k,), (k, 3) of a frame's surface (``triangles`` into
    ``points``, its vertex positions; ``points2`` the same vertices in frame 2): writes the
    point ``X`` (k, 3) and ``X2`` in frame 2, their output pixels ``uv`` (frame 1's camera) and ``uv2`` (frame
    2's) (k, 2), and ``occluded`` (k,), whether ``X2`` is off frame 2's image, outside ``[near2, far2]`` or
    behind frame 2's visible surface (``depth2``, ``grad_w2`` (H_p, W_p), its pinhole raster of intrinsics
    ``K_p2``):

        w(X2) < w_q - (|grad w_A| + |grad w_B|) r - 1e-9 w(X2)

    with ``grad_A`` (t,) the ``triangle_gradients`` of ``triangles`` in frame 2 (``motion`` module docstring,
    step 3). Through a lens (``has_lens2``) off-screen is decided in distorted pixels (the image is
    ``map_col2``'s shape) and ``q`` is the pinhole pixel (``map_col2``, ``map_row2``) the nearest distorted pixel
    samples; without one, the output image is the raster itself."""
    for i in range(tri.shape[0]):
        X[i, 0], X[i, 1], X[i, 2], X2[i, 0], X2[i, 1], X2[i, 2], u1, v1, u, v, hidden = _motion(
            tri[i], bary[i, 0], bary[i, 1], bary[i, 2], triangles, points, points2, pose, fx_fy_cx_cy,
            lens_k, has_lens, pose2, fx_fy_cx_cy2, lens_k2, has_lens2, near2, far2, K_p2, depth2, grad_w2,
            map_col2, map_row2, grad_A)
        uv[i, 0], uv[i, 1], uv2[i, 0], uv2[i, 1] = u1, v1, u, v
        occluded[i] = hidden


@njit(cache=True, parallel=True)
def pixel_motion(tri_id, bary, triangles, points, points2, pose, fx_fy_cx_cy, lens_k, has_lens,
                 pose2, fx_fy_cx_cy2, lens_k2, has_lens2, near2, far2, K_p2, depth2, grad_w2, map_col2, map_row2,
                 grad_A, flow, scene_flow, occluded):
    """:func:`point_motion` of every pixel's material point (``tri_id`` (H, W), -1 where nothing is seen;
    ``bary`` (H, W, 3)) written as images: ``flow`` (H, W, 2) float32 ``uv2 - uv``, ``scene_flow`` (H, W, 3)
    float32 ``X2 - X`` (both NaN where nothing is seen) and ``occluded`` (H, W) (False there)."""
    h, w = tri_id.shape
    for row in prange(h):
        for col in range(w):
            t = tri_id[row, col]
            if t < 0:
                flow[row, col, 0] = np.nan
                flow[row, col, 1] = np.nan
                for d in range(3):
                    scene_flow[row, col, d] = np.nan
                occluded[row, col] = False
                continue
            x0, x1, x2, y0, y1, y2, u1, v1, u, v, hidden = _motion(
                t, bary[row, col, 0], bary[row, col, 1], bary[row, col, 2], triangles, points, points2,
                pose, fx_fy_cx_cy, lens_k, has_lens, pose2, fx_fy_cx_cy2, lens_k2, has_lens2, near2, far2, K_p2,
                depth2, grad_w2, map_col2, map_row2, grad_A)
            flow[row, col, 0] = u - u1
            flow[row, col, 1] = v - v1
            scene_flow[row, col, 0] = y0 - x0
            scene_flow[row, col, 1] = y1 - x1
            scene_flow[row, col, 2] = y2 - x2
            occluded[row, col] = hidden
