"""A bounding-volume hierarchy over triangles for shadow and thickness rays (numba).

Built top-down with median splits along the longest centroid axis (leaves of at most 4 triangles),
stored as flat arrays in depth-first order: a node's children always follow it, so a bottom-up
refit for a deformed frame is one reverse sweep. Ray–triangle tests use Möller–Trumbore.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

LEAF_SIZE = 4


@njit(cache=True)
def _build(centroids, lo_tri, hi_tri):
    n = centroids.shape[0]
    cap = 2 * n + 1
    node_lo = np.empty((cap, 3))
    node_hi = np.empty((cap, 3))
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    start = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    order = np.arange(n)
    # explicit stack of (node, begin, end)
    stack_node = np.empty(cap, np.int64)
    stack_b = np.empty(cap, np.int64)
    stack_e = np.empty(cap, np.int64)
    sp = 0
    n_nodes = 1
    stack_node[0], stack_b[0], stack_e[0] = 0, 0, n
    sp = 1
    while sp > 0:
        sp -= 1
        node, b, e = stack_node[sp], stack_b[sp], stack_e[sp]
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        clo = np.full(3, np.inf)
        chi = np.full(3, -np.inf)
        for k in range(b, e):
            t = order[k]
            for a in range(3):
                lo[a] = min(lo[a], lo_tri[t, a])
                hi[a] = max(hi[a], hi_tri[t, a])
                clo[a] = min(clo[a], centroids[t, a])
                chi[a] = max(chi[a], centroids[t, a])
        node_lo[node] = lo
        node_hi[node] = hi
        if e - b <= LEAF_SIZE:
            start[node], count[node] = b, e - b
            continue
        axis = 0
        ext = chi - clo
        if ext[1] > ext[axis]:
            axis = 1
        if ext[2] > ext[axis]:
            axis = 2
        sub = order[b:e].copy()
        keys = centroids[sub, axis]
        idx = np.argsort(keys)
        order[b:e] = sub[idx]
        mid = (b + e) // 2
        l_node, r_node = n_nodes, n_nodes + 1
        n_nodes += 2
        left[node], right[node] = l_node, r_node
        stack_node[sp], stack_b[sp], stack_e[sp] = r_node, mid, e
        sp += 1
        stack_node[sp], stack_b[sp], stack_e[sp] = l_node, b, mid
        sp += 1
    return node_lo[:n_nodes], node_hi[:n_nodes], left[:n_nodes], right[:n_nodes], start[:n_nodes], count[:n_nodes], order


class BVH:
    """BVH over triangles ``points[triangles]``; ``occluded`` and ``closest_hit`` query batches of rays."""

    name = "numba"

    def __init__(self, points: np.ndarray, triangles: np.ndarray):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        tri = self.points[self.triangles]
        (self.lo, self.hi, self.left, self.right, self.start, self.count, self.order) = _build(
            tri.mean(axis=1), tri.min(axis=1), tri.max(axis=1))

    def occluded(self, origins: np.ndarray, targets: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        """True where a triangle lies strictly between ``origins`` and ``targets`` (segment test)."""
        return _occluded(self.lo, self.hi, self.left, self.right, self.start, self.count, self.order, self.points,
                         self.triangles, np.ascontiguousarray(origins), np.ascontiguousarray(targets), eps)

    def occluded_rays(self, origins: np.ndarray, directions: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """True where a unit ray hits a triangle within its length."""
        return _occluded_rays(self.lo, self.hi, self.left, self.right, self.start, self.count, self.order,
                              self.points, self.triangles, np.ascontiguousarray(origins, dtype=np.float64),
                              np.ascontiguousarray(directions, dtype=np.float64),
                              np.ascontiguousarray(lengths, dtype=np.float64))

    def closest_hit(self, origins: np.ndarray, directions: np.ndarray, t_max: float = np.inf) -> np.ndarray:
        """Distance to the first triangle along each unit ray (``inf`` when none within ``t_max``)."""
        t = _closest(self.lo, self.hi, self.left, self.right, self.start, self.count, self.order, self.points,
                     self.triangles, np.ascontiguousarray(origins), np.ascontiguousarray(directions), t_max)
        t[t >= t_max] = np.inf
        return t


@njit(cache=True, inline="always")
def _ray_box(ox, oy, oz, ix, iy, iz, lo, hi, node, t_max):
    """Slab test of the ray o + t d (inverse direction i) against node's box, for t in [0, t_max]."""
    ta = (lo[node, 0] - ox) * ix
    tb = (hi[node, 0] - ox) * ix
    t0 = max(0.0, min(ta, tb))
    t1 = min(t_max, max(ta, tb))
    ta = (lo[node, 1] - oy) * iy
    tb = (hi[node, 1] - oy) * iy
    t0 = max(t0, min(ta, tb))
    t1 = min(t1, max(ta, tb))
    ta = (lo[node, 2] - oz) * iz
    tb = (hi[node, 2] - oz) * iz
    t0 = max(t0, min(ta, tb))
    t1 = min(t1, max(ta, tb))
    return t0 <= t1


@njit(cache=True, inline="always")
def _ray_tri(ox, oy, oz, dx, dy, dz, pts, a, b, c):
    """Möller–Trumbore in scalars: distance along d to triangle (a, b, c), or inf."""
    e1x, e1y, e1z = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1], pts[b, 2] - pts[a, 2]
    e2x, e2y, e2z = pts[c, 0] - pts[a, 0], pts[c, 1] - pts[a, 1], pts[c, 2] - pts[a, 2]
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if abs(det) < 1e-18:
        return np.inf
    inv = 1.0 / det
    tx, ty, tz = ox - pts[a, 0], oy - pts[a, 1], oz - pts[a, 2]
    u = (tx * px + ty * py + tz * pz) * inv
    if u < 0.0 or u > 1.0:
        return np.inf
    qx, qy, qz = ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return np.inf
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t if t > 0.0 else np.inf


@njit(cache=True)
def _trace(lo, hi, left, right, start, count, order, pts, tris, ox, oy, oz, dx, dy, dz, t_max, any_hit, stack):
    """Nearest hit distance (or any hit when ``any_hit``) below t_max; ``stack`` is scratch space."""
    ix = 1.0 / dx if dx != 0.0 else 1e300
    iy = 1.0 / dy if dy != 0.0 else 1e300
    iz = 1.0 / dz if dz != 0.0 else 1e300
    sp = 1
    stack[0] = 0
    best = t_max
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if not _ray_box(ox, oy, oz, ix, iy, iz, lo, hi, node, best):
            continue
        if left[node] < 0:
            for k in range(start[node], start[node] + count[node]):
                t = order[k]
                th = _ray_tri(ox, oy, oz, dx, dy, dz, pts, tris[t, 0], tris[t, 1], tris[t, 2])
                if th < best:
                    best = th
                    if any_hit:
                        return best
        else:
            stack[sp] = left[node]
            stack[sp + 1] = right[node]
            sp += 2
    return best


RAYS_PER_TASK = 256  # rays per parallel task: one traversal stack each


@njit(cache=True, parallel=True)
def _occluded(lo, hi, left, right, start, count, order, pts, tris, origins, targets, eps):
    n = origins.shape[0]
    out = np.zeros(n, np.bool_)
    for task in prange((n + RAYS_PER_TASK - 1) // RAYS_PER_TASK):
        stack = np.empty(128, np.int64)
        for i in range(task * RAYS_PER_TASK, min(n, (task + 1) * RAYS_PER_TASK)):
            dx = targets[i, 0] - origins[i, 0]
            dy = targets[i, 1] - origins[i, 1]
            dz = targets[i, 2] - origins[i, 2]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if length <= 2 * eps:
                continue
            dx, dy, dz = dx / length, dy / length, dz / length
            t = _trace(lo, hi, left, right, start, count, order, pts, tris, origins[i, 0] + eps * dx,
                       origins[i, 1] + eps * dy, origins[i, 2] + eps * dz, dx, dy, dz, length - 2 * eps, True, stack)
            out[i] = t < length - 2 * eps
    return out


@njit(cache=True, parallel=True)
def _closest(lo, hi, left, right, start, count, order, pts, tris, origins, directions, t_max):
    n = origins.shape[0]
    out = np.empty(n)
    for task in prange((n + RAYS_PER_TASK - 1) // RAYS_PER_TASK):
        stack = np.empty(128, np.int64)
        for i in range(task * RAYS_PER_TASK, min(n, (task + 1) * RAYS_PER_TASK)):
            out[i] = _trace(lo, hi, left, right, start, count, order, pts, tris, origins[i, 0], origins[i, 1],
                            origins[i, 2], directions[i, 0], directions[i, 1], directions[i, 2], t_max, False, stack)
    return out


@njit(cache=True, parallel=True)
def _occluded_rays(lo, hi, left, right, start, count, order, pts, tris, origins, directions, lengths):
    n = origins.shape[0]
    out = np.zeros(n, np.bool_)
    for task in prange((n + RAYS_PER_TASK - 1) // RAYS_PER_TASK):
        stack = np.empty(128, np.int64)
        for i in range(task * RAYS_PER_TASK, min(n, (task + 1) * RAYS_PER_TASK)):
            t = _trace(lo, hi, left, right, start, count, order, pts, tris, origins[i, 0], origins[i, 1],
                       origins[i, 2], directions[i, 0], directions[i, 1], directions[i, 2], lengths[i], True, stack)
            out[i] = t < lengths[i]
    return out
