"""Contact of tissue nodes with triangle surfaces (issue 21 item 4): a static mesh, a rigid tool given by a closed
mesh, or another body's boundary surface, with Coulomb friction, for XPBD.

Inside test: a node ``p`` whose closest point ``q`` on the surface (over the triangles near it, found in a uniform
grid of the triangles' boxes grown by ``reach``) lies on a feature with angle-weighted pseudonormal ``N`` is inside
when ``(p - q) . N < 0`` (Bærentzen & Aanæs 2005: exact for a closed, consistently wound surface; for an open sheet
it means "behind it"). Only nodes within ``reach`` of the surface are seen, so ``reach`` bounds the depth a node
can be found at (a closed tool mesh: half its box's smallest side, then every point inside is seen).

Constraint of a node inside, with ``q = sum_k b_k v_k`` (barycentrics ``b``) and ``n = (q - p) / |q - p|``:
``C = n . (p - q) = -|q - p| >= 0``; its XPBD update with zero compliance (Macklin et al. 2016, eq. 18)
``dlambda = |q - p| / (w_p + sum_k b_k^2 w_k)``, ``p += w_p dlambda n``, ``v_k -= b_k w_k dlambda n``: the node and
the surface point meet, each side moved by its inverse mass (a static surface has ``w_k = 0``). Momentum is
conserved: the impulse on the node, ``dlambda n`` (``m_p dp``), is minus the surface's.

Friction after the sweeps (as ``sim.contact.PlaneState``): the node's tangential motion relative to the surface
point over the substep, ``dx_t``, against the normal impulse ``lambda_n`` summed over the sweeps: static if
``|dx_t| < mu lambda_n w`` (``w = w_p + sum b_k^2 w_k``; the tangential impulse ``dx_t / w`` stops it), else kinetic
(the impulse ``mu lambda_n``, Coulomb's ``mu N h``), shared between node and surface by inverse masses.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from sim.wrench import add_wrench


GRID_CELLS = 32  # at most this many grid cells along the grid's longest side


@njit(cache=True)
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@njit(cache=True)
def _closest_barycentrics(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of triangle abc to p (Ericson 2005 §5.1.5): ``(b0, b1, b2, feature)``, the point's barycentrics
    and its feature: 0-2 the vertex k, 3-5 the edge from vertex k - 3 to the next, 6 the face."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1, d2 = _dot(abx, aby, abz, apx, apy, apz), _dot(acx, acy, acz, apx, apy, apz)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0, 0
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3, d4 = _dot(abx, aby, abz, bpx, bpy, bpz), _dot(acx, acy, acz, bpx, bpy, bpz)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0, 1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        s = d1 / (d1 - d3)
        return 1.0 - s, s, 0.0, 3
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5, d6 = _dot(abx, aby, abz, cpx, cpy, cpz), _dot(acx, acy, acz, cpx, cpy, cpz)
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0, 2
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        s = d2 / (d2 - d6)
        return 1.0 - s, 0.0, s, 5
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - s, s, 4
    denom = 1.0 / (va + vb + vc)
    v, w = vb * denom, vc * denom
    return 1.0 - v - w, v, w, 6


@njit(cache=True)
def closest_on_triangle_xyz(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """The closest point of triangle abc to p from their coordinates: ``(d2, b0, b1, b2, feature)``, the squared
    distance to it, its barycentrics and feature (:func:`_closest_barycentrics`). Scalars only: the contact searches
    call it for every triangle they test, and a call passing arrays costs several times its arithmetic
    (docs/interaction.md, "The narrow phase's cost")."""
    b0, b1, b2, feature = _closest_barycentrics(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
    rx = px - (b0 * ax + b1 * bx + b2 * cx)
    ry = py - (b0 * ay + b1 * by + b2 * cy)
    rz = pz - (b0 * az + b1 * bz + b2 * cz)
    return rx * rx + ry * ry + rz * rz, b0, b1, b2, feature


@njit(cache=True)
def closest_on_triangle(p, a, b, c):
    """:func:`closest_on_triangle_xyz`'s barycentrics and feature for (3,) arrays."""
    return _closest_barycentrics(p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2])


@njit(cache=True)
def closest_with_distance2(p, a, b, c):
    """:func:`closest_on_triangle_xyz` for (3,) arrays."""
    return closest_on_triangle_xyz(p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2])


@njit(cache=True)
def unit_face_normal(xv, a, b, c):
    """The unit normal (right-handed in a, b, c) of the triangle of rows a, b, c of ``xv``; zero when degenerate."""
    e1x, e1y, e1z = xv[b, 0] - xv[a, 0], xv[b, 1] - xv[a, 1], xv[b, 2] - xv[a, 2]
    e2x, e2y, e2z = xv[c, 0] - xv[a, 0], xv[c, 1] - xv[a, 1], xv[c, 2] - xv[a, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    scale = 1.0 / length if length > 0.0 else 0.0
    return nx * scale, ny * scale, nz * scale


@njit(cache=True)
def corner_angle_xyz(ux, uy, uz, wx, wy, wz):
    """The angle between the edges u and w leaving a triangle's corner (the vertex normals' weight); -1 when
    degenerate. Scalars: see :func:`closest_on_triangle_xyz`."""
    lu, lw = np.sqrt(_dot(ux, uy, uz, ux, uy, uz)), np.sqrt(_dot(wx, wy, wz, wx, wy, wz))
    if lu > 0.0 and lw > 0.0:
        return np.arccos(min(1.0, max(-1.0, _dot(ux, uy, uz, wx, wy, wz) / (lu * lw))))
    return -1.0


@njit(cache=True)
def corner_angle(xv, v0, v1, v2):
    """The angle at row v0 of the triangle (v0, v1, v2) of ``xv`` (:func:`corner_angle_xyz`)."""
    return corner_angle_xyz(xv[v1, 0] - xv[v0, 0], xv[v1, 1] - xv[v0, 1], xv[v1, 2] - xv[v0, 2],
                            xv[v2, 0] - xv[v0, 0], xv[v2, 1] - xv[v0, 1], xv[v2, 2] - xv[v0, 2])


@njit(cache=True)
def pseudonormals(xv, vmap, faces, adjacent, face_n, edge_n, vert_n):
    """Unit face normals, edge normals (the two faces' sum; a border edge: its face's) and angle-weighted vertex
    normals (Bærentzen & Aanæs 2005) of the surface with vertex k at ``xv[vmap[k]]``, written in place."""
    vert_n[:] = 0.0
    for f in range(faces.shape[0]):
        a, b, c = vmap[faces[f, 0]], vmap[faces[f, 1]], vmap[faces[f, 2]]
        face_n[f, 0], face_n[f, 1], face_n[f, 2] = unit_face_normal(xv, a, b, c)
        for k in range(3):
            angle = corner_angle(xv, vmap[faces[f, k]], vmap[faces[f, (k + 1) % 3]], vmap[faces[f, (k + 2) % 3]])
            if angle >= 0.0:
                for d in range(3):
                    vert_n[faces[f, k], d] += angle * face_n[f, d]
    for f in range(faces.shape[0]):
        for k in range(3):
            g = adjacent[f, k]
            for d in range(3):
                edge_n[f, k, d] = face_n[f, d] + face_n[g, d] if g >= 0 else face_n[f, d]
            length = np.sqrt(_dot(edge_n[f, k, 0], edge_n[f, k, 1], edge_n[f, k, 2],
                                  edge_n[f, k, 0], edge_n[f, k, 1], edge_n[f, k, 2]))
            if length > 0.0:
                for d in range(3):
                    edge_n[f, k, d] /= length
    for v in range(vert_n.shape[0]):
        length = np.sqrt(_dot(vert_n[v, 0], vert_n[v, 1], vert_n[v, 2], vert_n[v, 0], vert_n[v, 1], vert_n[v, 2]))
        if length > 0.0:
            for d in range(3):
                vert_n[v, d] /= length


@njit(cache=True)
def triangle_boxes(xv, vmap, faces, reach, cells):
    """The triangles' boxes grown by ``reach`` (``lo``, ``hi``: (k, 3)) and a grid cell: their mean largest side, at
    least the boxes' whole extent over ``cells``."""
    k = faces.shape[0]
    lo, hi = np.empty((k, 3)), np.empty((k, 3))
    total_lo, total_hi = np.full(3, np.inf), np.full(3, -np.inf)
    mean_side = 0.0
    for f in range(k):
        side = 0.0
        for d in range(3):
            a, b, c = xv[vmap[faces[f, 0]], d], xv[vmap[faces[f, 1]], d], xv[vmap[faces[f, 2]], d]
            lo[f, d] = min(a, b, c) - reach
            hi[f, d] = max(a, b, c) + reach
            side = max(side, hi[f, d] - lo[f, d])
            total_lo[d] = min(total_lo[d], lo[f, d])
            total_hi[d] = max(total_hi[d], hi[f, d])
        mean_side += side / k
    return lo, hi, max(mean_side, (total_hi - total_lo).max() / cells)


@njit(cache=True)
def build_grid(lo, hi, cell):
    """A uniform grid over boxes ``lo``-``hi`` (k, 3) with cubic cells of side ``cell``: ``(origin, dims, start,
    items)``, the boxes overlapping cell c being ``items[start[c]:start[c + 1]]``."""
    origin = np.empty(3)
    dims = np.empty(3, np.int64)
    for a in range(3):
        origin[a] = lo[:, a].min()
        dims[a] = int((hi[:, a].max() - origin[a]) / cell) + 1
    count = np.zeros(dims[0] * dims[1] * dims[2] + 1, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for c in range(1, count.size):
                count[c] += count[c - 1]
            items = np.empty(count[-1], np.int64)
            cursor = count[:-1].copy()
        for t in range(lo.shape[0]):
            i0 = min(int((lo[t, 0] - origin[0]) / cell), dims[0] - 1)
            j0 = min(int((lo[t, 1] - origin[1]) / cell), dims[1] - 1)
            k0 = min(int((lo[t, 2] - origin[2]) / cell), dims[2] - 1)
            i1 = min(int((hi[t, 0] - origin[0]) / cell), dims[0] - 1)
            j1 = min(int((hi[t, 1] - origin[1]) / cell), dims[1] - 1)
            k1 = min(int((hi[t, 2] - origin[2]) / cell), dims[2] - 1)
            for i in range(i0, i1 + 1):
                for j in range(j0, j1 + 1):
                    for k in range(k0, k1 + 1):
                        c = (i * dims[1] + j) * dims[2] + k
                        if pass_ == 0:
                            count[c + 1] += 1
                        else:
                            items[cursor[c]] = t
                            cursor[c] += 1
    return origin, dims, count, items


@njit(cache=True)
def project_nodes(x, w, nodes, xv, vmap, wv, shift, faces, face_n, edge_n, vert_n, lo, hi, origin, cell, dims,
                  start, items, reach, lam_n, contact_tri, contact_bary, contact_n, load, centre, sign, hint):
    """One Gauss-Seidel pass of the contact constraint (module docstring) over ``nodes`` of ``x``: surface vertex k
    at ``xv[vmap[k]] + shift`` (inverse mass ``wv[vmap[k]]``); grid (``build_grid``) of the triangle boxes
    ``lo``-``hi`` (grown by ``reach``) in the surface's frame (``p - shift``). Records per node (index into
    ``nodes``) the summed normal impulse, the triangle, barycentrics and normal of its last correction; adds
    ``sign`` times the impulse on the nodes and its moment about ``centre`` to ``load`` (6,). Returns the number of
    corrections. ``hint`` (empty, or a triangle per node, -1 for none): tried first, so the nearest-box pruning drops
    the others at once when the node is still nearest to it. A model's contacts take ``sim.contact_set`` (a broad phase
    per substep), a mesh tool this grid search."""
    moved = 0
    g = np.empty(3)
    for q in range(nodes.shape[0]):
        i = nodes[q]
        for d in range(3):
            g[d] = x[i, d] - shift[d]
        cx = int(np.floor((g[0] - origin[0]) / cell))
        cy = int(np.floor((g[1] - origin[1]) / cell))
        cz = int(np.floor((g[2] - origin[2]) / cell))
        if cx < 0 or cy < 0 or cz < 0 or cx >= dims[0] or cy >= dims[1] or cz >= dims[2]:
            continue
        cell_id = (cx * dims[1] + cy) * dims[2] + cz
        best, best_t, best_f = reach * reach, -1, 0
        b0 = b1 = b2 = 0.0
        first = hint[q] if hint.size else -1
        for s in range(start[cell_id] - (1 if first >= 0 else 0), start[cell_id + 1]):
            t = items[s] if s >= start[cell_id] else first
            # the distance to the triangle's own box (the grown box shrunk by reach) bounds the distance to it from
            # below: a triangle whose box is farther than the best so far cannot be closer
            box2 = 0.0
            for d in range(3):
                r = max(lo[t, d] + reach - g[d], g[d] - (hi[t, d] - reach), 0.0)
                box2 += r * r
            if box2 > best or face_n[t, 0] == 0.0 and face_n[t, 1] == 0.0 and face_n[t, 2] == 0.0:
                continue
            va, vb, vc = vmap[faces[t, 0]], vmap[faces[t, 1]], vmap[faces[t, 2]]  # in the surface's frame
            d2, c0, c1, c2, feature = closest_on_triangle_xyz(g[0], g[1], g[2], xv[va, 0], xv[va, 1], xv[va, 2],
                                                              xv[vb, 0], xv[vb, 1], xv[vb, 2], xv[vc, 0], xv[vc, 1],
                                                              xv[vc, 2])
            if d2 <= best:
                best, best_t, best_f, b0, b1, b2 = d2, t, feature, c0, c1, c2
        if best_t < 0:
            continue
        t = best_t
        va, vb, vc = vmap[faces[t, 0]], vmap[faces[t, 1]], vmap[faces[t, 2]]
        qx = b0 * xv[va, 0] + b1 * xv[vb, 0] + b2 * xv[vc, 0]
        qy = b0 * xv[va, 1] + b1 * xv[vb, 1] + b2 * xv[vc, 1]
        qz = b0 * xv[va, 2] + b1 * xv[vb, 2] + b2 * xv[vc, 2]
        dx, dy, dz = g[0] - qx, g[1] - qy, g[2] - qz
        if best_f < 3:
            Nx, Ny, Nz = vert_n[faces[t, best_f], 0], vert_n[faces[t, best_f], 1], vert_n[faces[t, best_f], 2]
        elif best_f < 6:
            Nx, Ny, Nz = edge_n[t, best_f - 3, 0], edge_n[t, best_f - 3, 1], edge_n[t, best_f - 3, 2]
        else:
            Nx, Ny, Nz = face_n[t, 0], face_n[t, 1], face_n[t, 2]
        if _dot(dx, dy, dz, Nx, Ny, Nz) >= 0.0:
            continue
        dist = np.sqrt(_dot(dx, dy, dz, dx, dy, dz))
        if dist > 1e-300:  # n: from the node to the surface point (outward)
            nx, ny, nz = -dx / dist, -dy / dist, -dz / dist
        else:
            nx, ny, nz = Nx, Ny, Nz
        w_sum = w[i] + b0 * b0 * wv[va] + b1 * b1 * wv[vb] + b2 * b2 * wv[vc]
        if w_sum == 0.0:
            continue
        dlam = dist / w_sum
        jx, jy, jz = dlam * nx, dlam * ny, dlam * nz
        x[i, 0] += w[i] * jx
        x[i, 1] += w[i] * jy
        x[i, 2] += w[i] * jz
        for v, bk in ((va, b0), (vb, b1), (vc, b2)):
            xv[v, 0] -= bk * wv[v] * jx
            xv[v, 1] -= bk * wv[v] * jy
            xv[v, 2] -= bk * wv[v] * jz
        lam_n[q] += dlam
        contact_tri[q] = t
        contact_bary[q, 0], contact_bary[q, 1], contact_bary[q, 2] = b0, b1, b2
        contact_n[q, 0], contact_n[q, 1], contact_n[q, 2] = nx, ny, nz
        rx, ry, rz = x[i, 0] - centre[0], x[i, 1] - centre[1], x[i, 2] - centre[2]
        add_wrench(load, sign, jx, jy, jz, rx, ry, rz)
        moved += 1
    return moved


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """(k, 3): the face across edge j (vertex j to j + 1) of each face, -1 on a border (or a non-manifold edge)."""
    faces = np.asarray(faces, dtype=np.int64)
    k = faces.shape[0]
    edges = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    adjacent = np.full(3 * k, -1, dtype=np.int64)
    sk = key[order]
    same = np.all(sk[1:] == sk[:-1], axis=1)
    # exactly two faces on the edge: pair them (three or more: left as borders)
    single_pair = same & np.r_[True, ~same[:-1]] & np.r_[~same[1:], True]
    first, second = order[:-1][single_pair], order[1:][single_pair]
    adjacent[first], adjacent[second] = second // 3, first // 3
    return adjacent.reshape(k, 3)


def mean_edge_length(points: np.ndarray, faces: np.ndarray) -> float:
    p = points[faces]
    return float(np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2).mean())
