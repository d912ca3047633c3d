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

    def closest_hit(self, origins: np.ndarray, directions: np.ndarray, t_max: float = np.inf) -> np.ndarray:
        """Distance to the first triangle along each unit ray (``inf`` when none within ``t_max``)."""
        return _closest(self.lo, self.hi, self.left, self.right, self.start, self.count, self.order, self.points,
                        self.triangles, np.ascontiguousarray(origins), np.ascontiguousarray(directions), t_max)


@njit(cache=True, inline="always")
def _ray_box(o, inv_d, lo, hi, t_max):
    t0, t1 = 0.0, t_max
    for a in range(3):
        ta = (lo[a] - o[a]) * inv_d[a]
        tb = (hi[a] - o[a]) * inv_d[a]
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
        if t0 > t1:
            return False
    return True


@njit(cache=True, inline="always")
def _ray_tri(o, d, p0, p1, p2):
    """Möller–Trumbore: distance along d to the triangle, or inf."""
    e1 = p1 - p0
    e2 = p2 - p0
    pv = np.cross(d, e2)
    det = e1[0] * pv[0] + e1[1] * pv[1] + e1[2] * pv[2]
    if abs(det) < 1e-18:
        return np.inf
    inv = 1.0 / det
    tv = o - p0
    u = (tv[0] * pv[0] + tv[1] * pv[1] + tv[2] * pv[2]) * inv
    if u < 0.0 or u > 1.0:
        return np.inf
    qv = np.cross(tv, e1)
    v = (d[0] * qv[0] + d[1] * qv[1] + d[2] * qv[2]) * inv
    if v < 0.0 or u + v > 1.0:
        return np.inf
    t = (e2[0] * qv[0] + e2[1] * qv[1] + e2[2] * qv[2]) * inv
    return t if t > 0.0 else np.inf


@njit(cache=True)
def _trace(lo, hi, left, right, start, count, order, pts, tris, o, d, t_max, any_hit):
    inv_d = np.empty(3)
    for a in range(3):
        inv_d[a] = 1.0 / d[a] if d[a] != 0.0 else 1e300
    stack = np.empty(128, np.int64)
    sp = 1
    stack[0] = 0
    best = t_max
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if not _ray_box(o, inv_d, lo[node], hi[node], best):
            continue
        if left[node] < 0:
            for k in range(start[node], start[node] + count[node]):
                t = order[k]
                th = _ray_tri(o, d, pts[tris[t, 0]], pts[tris[t, 1]], pts[tris[t, 2]])
                if th < best:
                    best = th
                    if any_hit:
                        return best
        else:
            stack[sp] = left[node]
            stack[sp + 1] = right[node]
            sp += 2
    return best


@njit(cache=True, parallel=True)
def _occluded(lo, hi, left, right, start, count, order, pts, tris, origins, targets, eps):
    n = origins.shape[0]
    out = np.zeros(n, np.bool_)
    for i in prange(n):
        d = targets[i] - origins[i]
        length = np.sqrt((d * d).sum())
        if length <= 2 * eps:
            continue
        d = d / length
        o = origins[i] + eps * d
        t = _trace(lo, hi, left, right, start, count, order, pts, tris, o, d, length - 2 * eps, True)
        out[i] = t < length - 2 * eps
    return out


@njit(cache=True, parallel=True)
def _closest(lo, hi, left, right, start, count, order, pts, tris, origins, directions, t_max):
    n = origins.shape[0]
    out = np.empty(n)
    for i in prange(n):
        out[i] = _trace(lo, hi, left, right, start, count, order, pts, tris, origins[i], directions[i], t_max, False)
    return out
