"""Which tets a blade sweeps through: an exact capsule–tet intersection test over the blade's positions in a substep.

A blade capsule (segment ``a``-``b``, radius ``r``) meets a tet when the distance between the segment and the solid
tet is at most ``r``. The distance is exact for a convex polyhedron:

- zero when the segment meets the tet: the segment ``p(s) = a + s (b - a)``, ``s`` in [0, 1], is clipped against
  the four face planes (Cyrus–Beck; each face's normal turned away from its opposite vertex, so a deformed, even
  inverted, tet is handled as the convex hull of its corners) and the interval left is not empty;
- otherwise the minimum over the segment's endpoints to the four face triangles (closest point on a triangle,
  Ericson, *Real-Time Collision Detection* §5.1.5) and over the segment to the six tet edges (closest points of two
  segments, Ericson §5.1.9): the nearest point of a convex polyhedron to a segment that misses it lies on a face
  seen from an endpoint, or on an edge.

The blade moves between the two ends of a substep; :func:`blade_hits` tests the capsule at sample times close
enough that consecutive positions of each end are at most ``r`` apart (``sim.cutting.CutState.sweep``), so every
tet the blade's segment passes through is found (a point of the segment's sweep lies within ``r / 2`` of a sampled
segment when the motion between samples is linear), and no tet farther than ``r`` from every sampled blade.
"""
from __future__ import annotations

import numpy as np
from numba import njit

_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)  # face k is opposite corner k
_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


# 3-vectors as tuples of floats: values in registers, no array allocated per test
@njit(cache=True, inline="always")
def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


@njit(cache=True, inline="always")
def _add_scaled(u, s, v):
    return (u[0] + s * v[0], u[1] + s * v[1], u[2] + s * v[2])


@njit(cache=True, inline="always")
def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@njit(cache=True, inline="always")
def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


@njit(cache=True)
def point_triangle_distance2(p, a, b, c):
    """Squared distance from point ``p`` to the triangle ``a b c`` (3-tuples; Ericson §5.1.5, Voronoi regions)."""
    ab = _sub(b, a)
    ac = _sub(c, a)
    ap = _sub(p, a)
    d1 = _dot(ab, ap)
    d2 = _dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        q = a
    else:
        bp = _sub(p, b)
        d3 = _dot(ab, bp)
        d4 = _dot(ac, bp)
        if d3 >= 0.0 and d4 <= d3:
            q = b
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                q = _add_scaled(a, d1 / (d1 - d3), ab)
            else:
                cp = _sub(p, c)
                d5 = _dot(ab, cp)
                d6 = _dot(ac, cp)
                if d6 >= 0.0 and d5 <= d6:
                    q = c
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        q = _add_scaled(a, d2 / (d2 - d6), ac)
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            q = _add_scaled(b, (d4 - d3) / ((d4 - d3) + (d5 - d6)), _sub(c, b))
                        else:
                            denom = 1.0 / (va + vb + vc)
                            q = _add_scaled(_add_scaled(a, vb * denom, ab), vc * denom, ac)
    d = _sub(p, q)
    return _dot(d, d)


@njit(cache=True)
def segment_segment_distance2(p1, q1, p2, q2):
    """Squared distance between the segments ``p1 q1`` and ``p2 q2`` (3-tuples; Ericson §5.1.9, degenerate cases
    included)."""
    d1 = _sub(q1, p1)
    d2 = _sub(q2, p2)
    r = _sub(p1, p2)
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    if a <= 1e-300 and e <= 1e-300:
        return _dot(r, r)
    if a <= 1e-300:
        s = 0.0
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = _dot(d1, r)
        if e <= 1e-300:
            t = 0.0
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = _dot(d1, d2)
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    d = _sub(_add_scaled(p1, s, d1), _add_scaled(p2, t, d2))
    return _dot(d, d)


@njit(cache=True)
def segment_meets_tet(a, b, corners):
    """Whether the segment ``a b`` (3-tuples) meets the solid tet with ``corners`` (a 4-tuple of 3-tuples):
    Cyrus–Beck clipping of ``a + s (b - a)`` against the four face planes, normals turned away from the opposite
    corner."""
    lo, hi = 0.0, 1.0
    d = _sub(b, a)
    for k in range(4):
        i, j, l = _FACES[k, 0], _FACES[k, 1], _FACES[k, 2]
        n = _cross(_sub(corners[j], corners[i]), _sub(corners[l], corners[i]))
        if _dot(n, _sub(corners[k], corners[i])) > 0.0:  # outward: away from the opposite corner
            n = (-n[0], -n[1], -n[2])
        f0 = _dot(n, _sub(a, corners[i]))  # > 0: a is outside this face
        fd = _dot(n, d)
        if fd == 0.0:
            if f0 > 0.0:
                return False
        elif fd > 0.0:
            hi = min(hi, -f0 / fd)
        else:
            lo = max(lo, -f0 / fd)
        if lo > hi:
            return False
    return True


@njit(cache=True)
def capsule_meets_tet(a, b, radius, corners):
    """Whether the capsule ``a b`` (3-tuples) of ``radius`` meets the solid tet with ``corners`` (a 4-tuple of
    3-tuples; module docstring)."""
    if segment_meets_tet(a, b, corners):
        return True
    r2 = radius * radius
    for k in range(4):
        c0, c1, c2 = corners[_FACES[k, 0]], corners[_FACES[k, 1]], corners[_FACES[k, 2]]
        if point_triangle_distance2(a, c0, c1, c2) <= r2 or point_triangle_distance2(b, c0, c1, c2) <= r2:
            return True
    for k in range(6):
        if segment_segment_distance2(a, b, corners[_EDGES[k, 0]], corners[_EDGES[k, 1]]) <= r2:
            return True
    return False


@njit(cache=True)
def blade_hits(x, tets, seg_a, seg_b, radius, hit):
    """Mark in ``hit`` (m,) bool every tet of ``tets`` (m, 4) at node positions ``x`` that meets one of the capsules
    ``seg_a[k]``-``seg_b[k]`` of ``radius[k]`` (k sampled blade positions); a bounding-box test first."""
    k_count = seg_a.shape[0]
    lo = np.empty((k_count, 3))
    hi = np.empty((k_count, 3))
    for k in range(k_count):
        for c in range(3):
            lo[k, c] = min(seg_a[k, c], seg_b[k, c]) - radius[k]
            hi[k, c] = max(seg_a[k, c], seg_b[k, c]) + radius[k]
    all_lo = np.empty(3)
    all_hi = np.empty(3)
    for c in range(3):
        all_lo[c] = lo[:, c].min()
        all_hi[c] = hi[:, c].max()
    # per node, on which sides of the box around every sample it lies (bit 2c: below it along axis c, bit 2c + 1:
    # above): a tet whose four nodes share a bit misses the box, the box test below without reading its corners
    side = np.zeros(x.shape[0], dtype=np.uint8)
    for i in range(x.shape[0]):
        bits = 0
        for c in range(3):
            if x[i, c] < all_lo[c]:
                bits |= 1 << (2 * c)
            elif x[i, c] > all_hi[c]:
                bits |= 2 << (2 * c)
        side[i] = bits
    corners = np.empty((4, 3))
    t_lo = np.empty(3)
    t_hi = np.empty(3)
    for t in range(tets.shape[0]):
        if side[tets[t, 0]] & side[tets[t, 1]] & side[tets[t, 2]] & side[tets[t, 3]]:
            continue
        for c in range(3):
            t_lo[c] = np.inf
            t_hi[c] = -np.inf
        for v in range(4):
            for c in range(3):
                value = x[tets[t, v], c]
                corners[v, c] = value
                t_lo[c] = min(t_lo[c], value)
                t_hi[c] = max(t_hi[c], value)
        # the tet's bounding sphere (centre c, radius R): a capsule farther than R + r from c misses it
        c0 = 0.25 * (corners[0, 0] + corners[1, 0] + corners[2, 0] + corners[3, 0])
        c1 = 0.25 * (corners[0, 1] + corners[1, 1] + corners[2, 1] + corners[3, 1])
        c2 = 0.25 * (corners[0, 2] + corners[1, 2] + corners[2, 2] + corners[3, 2])
        R2 = 0.0
        for v in range(4):
            d0, d1, d2 = corners[v, 0] - c0, corners[v, 1] - c1, corners[v, 2] - c2
            R2 = max(R2, d0 * d0 + d1 * d1 + d2 * d2)
        R = np.sqrt(R2)
        for k in range(k_count):
            if (t_hi[0] < lo[k, 0] or t_lo[0] > hi[k, 0] or t_hi[1] < lo[k, 1] or t_lo[1] > hi[k, 1]
                    or t_hi[2] < lo[k, 2] or t_lo[2] > hi[k, 2]):
                continue
            e0, e1, e2 = seg_b[k, 0] - seg_a[k, 0], seg_b[k, 1] - seg_a[k, 1], seg_b[k, 2] - seg_a[k, 2]
            p0, p1, p2 = c0 - seg_a[k, 0], c1 - seg_a[k, 1], c2 - seg_a[k, 2]
            len2 = e0 * e0 + e1 * e1 + e2 * e2
            s = min(max((p0 * e0 + p1 * e1 + p2 * e2) / len2, 0.0), 1.0) if len2 > 0.0 else 0.0
            q0, q1, q2 = p0 - s * e0, p1 - s * e1, p2 - s * e2
            reach = R + radius[k]
            if q0 * q0 + q1 * q1 + q2 * q2 > reach * reach * (1.0 + 1e-12):  # rounding margin: never a false miss
                continue
            tet = ((corners[0, 0], corners[0, 1], corners[0, 2]), (corners[1, 0], corners[1, 1], corners[1, 2]),
                   (corners[2, 0], corners[2, 1], corners[2, 2]), (corners[3, 0], corners[3, 1], corners[3, 2]))
            if capsule_meets_tet((seg_a[k, 0], seg_a[k, 1], seg_a[k, 2]), (seg_b[k, 0], seg_b[k, 1], seg_b[k, 2]),
                                 radius[k], tet):
                hit[t] = True
                break
