"""The broad phase of ``sim.contact_set`` (triangle-surface contact for XPBD, issue 21): once per substep, the nodes a
substep's sweeps visit, each with its nearest triangle (the hint) and the short list of triangles it can be nearest to
during the sweeps; a body surface's normals and boxes at the substep's start. See ``sim.contact_set``'s docstring for
the rule, ``sim.contact_mesh`` for the constraint and the pseudonormals (Bærentzen & Aanæs 2005).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from sim.contact_mesh import build_grid, closest_on_triangle_xyz, corner_angle_xyz


@njit(cache=True)
def corners(x, static_x, n_nodes, tri_v, t):
    """Triangle t's corners as nine coordinates ``ax, ay, az, bx, ..., cz`` (scalars, for
    ``sim.contact_mesh.closest_on_triangle_xyz``: passing (3,) arrays between the helpers cost about four times the
    searches' arithmetic; docs/interaction.md, "The narrow phase's cost")."""
    ia, ib, ic = tri_v[t, 0], tri_v[t, 1], tri_v[t, 2]
    if ia >= n_nodes:  # a static surface's triangle: all three corners are its points
        ia, ib, ic = ia - n_nodes, ib - n_nodes, ic - n_nodes
        return (static_x[ia, 0], static_x[ia, 1], static_x[ia, 2], static_x[ib, 0], static_x[ib, 1], static_x[ib, 2],
                static_x[ic, 0], static_x[ic, 1], static_x[ic, 2])
    return x[ia, 0], x[ia, 1], x[ia, 2], x[ib, 0], x[ib, 1], x[ib, 2], x[ic, 0], x[ic, 1], x[ic, 2]


@njit(cache=True)
def _face_normals_and_boxes(x, tri_v, t0, t1, reach, face_n, lo, hi):
    """Unit normals and boxes grown by ``reach`` of a body surface's triangles ``t0:t1`` (``sim.contact_mesh``'s
    ``unit_face_normal`` and ``triangle_boxes``, the same arithmetic, written out: one call per surface)."""
    for t in range(t0, t1):
        a, b, c = tri_v[t, 0], tri_v[t, 1], tri_v[t, 2]
        e1x, e1y, e1z = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        e2x, e2y, e2z = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        scale = 1.0 / length if length > 0.0 else 0.0
        face_n[t, 0], face_n[t, 1], face_n[t, 2] = nx * scale, ny * scale, nz * scale
        for d in range(3):
            pa, pb, pc = x[a, d], x[b, d], x[c, d]
            lo[t, d] = min(pa, pb, pc) - reach
            hi[t, d] = max(pa, pb, pc) + reach


@njit(cache=True)
def nearest_triangle(g, x, static_x, n_nodes, tri_v, face_n, lo, hi, reach, first, cand, c0, c1, runner_up=0.0):
    """The nearest triangle within ``reach`` of point g over ``first`` (-1: none) then ``cand[c0:c1]``, skipping a
    triangle whose box (the grown box shrunk by ``reach``) or plane is farther than the best so far: ``(t, feature,
    b0, b1, b2, second2)``, t = -1 for none (``sim.contact_mesh.project_nodes``' search). With ``runner_up`` > 0
    [m], ``second2`` bounds from below the squared distance to the nearest triangle
    other than t: it is that distance when under t's plus ``runner_up`` (and ``reach``), else at least that (a
    triangle as near as t makes it t's); the skipping then compares with it, which leaves t the same. Without,
    ``second2`` is ``reach**2``."""
    best, best_t, best_f = reach * reach, -1, 0
    second = reach * reach
    bound = second  # what a triangle farther than is skipped: the best, or the runner-up's cap
    b0 = b1 = b2 = 0.0
    gx, gy, gz = g[0], g[1], g[2]
    for s in range(c0 - (1 if first >= 0 else 0), c1):
        t = cand[s] if s >= c0 else first
        if face_n[t, 0] == 0.0 and face_n[t, 1] == 0.0 and face_n[t, 2] == 0.0:
            continue
        r0 = max(lo[t, 0] + reach - gx, gx - (hi[t, 0] - reach), 0.0)
        r1 = max(lo[t, 1] + reach - gy, gy - (hi[t, 1] - reach), 0.0)
        r2 = max(lo[t, 2] + reach - gz, gz - (hi[t, 2] - reach), 0.0)
        box2 = r0 * r0 + r1 * r1 + r2 * r2
        if box2 > bound:
            continue
        ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, t)
        # the distance to the triangle's plane bounds the distance to it from below (a node resting on a surface lies
        # in the boxes of most triangles around it, not near their planes); pruned only beyond rounding (1e-9
        # relative, far above the few ulps the two computations differ by), so ties are searched as before
        nx = (by - ay) * (cz - az) - (bz - az) * (cy - ay)
        ny = (bz - az) * (cx - ax) - (bx - ax) * (cz - az)
        nz = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        height = nx * (gx - ax) + ny * (gy - ay) + nz * (gz - az)
        plane2 = height * height
        normal2 = nx * nx + ny * ny + nz * nz
        if plane2 > bound * (1.0 + 1e-9) * normal2:
            continue
        d2, e0, e1, e2, feature = closest_on_triangle_xyz(gx, gy, gz, ax, ay, az, bx, by, bz, cx, cy, cz)
        if t == best_t:  # the first triangle tried again in the list: the same distance
            continue
        # the nearest as without the runner-up: a triangle the best's box or plane test skips cannot become it
        if d2 <= best and box2 <= best and plane2 <= best * (1.0 + 1e-9) * normal2:
            if runner_up > 0.0:
                second = best
            best, best_t, best_f, b0, b1, b2 = d2, t, feature, e0, e1, e2
        elif runner_up > 0.0 and d2 < second:
            second = d2
        bound = min(second, (np.sqrt(best) + runner_up) ** 2) if runner_up > 0.0 else best
    return best_t, best_f, b0, b1, b2, min(second, bound) if runner_up > 0.0 else second


@njit(cache=True)
def outside_gap(g, x, static_x, n_nodes, tri_v, t, b0, b1, b2, feature, face_n, edge_n, corner_n):
    """The distance from g to the point of triangle t at barycentrics b0, b1, b2 (its nearest, on ``feature``), a
    little under it (rounding), when g lies on the outer side of the feature's pseudonormal (the narrow phase's inside
    test, ``sim.contact_set.project_entries``); 0 when inside."""
    ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, t)
    dx = g[0] - (b0 * ax + b1 * bx + b2 * cx)
    dy = g[1] - (b0 * ay + b1 * by + b2 * cy)
    dz = g[2] - (b0 * az + b1 * bz + b2 * cz)
    if feature < 3:
        side = dx * corner_n[t, feature, 0] + dy * corner_n[t, feature, 1] + dz * corner_n[t, feature, 2]
    elif feature < 6:
        side = dx * edge_n[t, feature - 3, 0] + dy * edge_n[t, feature - 3, 1] + dz * edge_n[t, feature - 3, 2]
    else:
        side = dx * face_n[t, 0] + dy * face_n[t, 1] + dz * face_n[t, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz) * (1.0 - 1e-9) if side >= 0.0 else 0.0


@njit(cache=True)
def _grown(buf):
    """``buf`` in a buffer twice as long (the caller writes on)."""
    grown = np.empty(2 * buf.size + 16, buf.dtype)
    grown[:buf.size] = buf
    return grown


@njit(cache=True)
def _append(buf, n, value):
    if n == buf.size:
        buf = _grown(buf)
    buf[n] = value
    return buf


@njit(cache=True)
def _box_gap(g, lo, hi, t, reach):
    """Distance from g to triangle t's own box (its box grown by ``reach``, shrunk again)."""
    box2 = 0.0
    for d in range(3):
        r = max(lo[t, d] + reach - g[d], g[d] - (hi[t, d] - reach), 0.0)
        box2 += r * r
    return np.sqrt(box2)


@njit(cache=True)
def cell_clearance(origin, cell, dims, lo, hi, reach):
    """Per cell of a static surface's grid (``sim.contact_mesh.build_grid`` over boxes ``lo``-``hi`` grown by
    ``reach``): the distance from the cell to the nearest triangle's own box, a lower bound of any of its points'
    distance to the surface (a node in a cell farther than ``reach`` has no triangle within reach)."""
    clearance = np.full(dims[0] * dims[1] * dims[2] + 1, np.inf)
    for i in range(dims[0]):
        for j in range(dims[1]):
            for k in range(dims[2]):
                cell_lo = (origin[0] + i * cell, origin[1] + j * cell, origin[2] + k * cell)
                best = np.inf
                for t in range(lo.shape[0]):
                    gap2 = 0.0
                    for d in range(3):
                        r = max(lo[t, d] + reach - (cell_lo[d] + cell), cell_lo[d] - (hi[t, d] - reach), 0.0)
                        gap2 += r * r
                    best = min(best, gap2)
                clearance[(i * dims[1] + j) * dims[2] + k] = np.sqrt(best)
    return clearance


@njit(cache=True)
def _static_clearance(g, x, static_x, n_nodes, tri_v, lo, hi, reach, t0, origin, cell, dims, start_off, items_off,
                      g_start, g_items, seen, stamp):
    """The distance from g to a static surface, at most ``2 reach`` (the triangles from the grid cells within that of
    g, skipped when their box is farther than the nearest so far), a little under it (rounding)."""
    limit = 2.0 * reach
    best = limit * limit
    lo_cell, hi_cell = np.empty(3, np.int64), np.empty(3, np.int64)
    for d in range(3):
        lo_cell[d] = max(int(np.floor((g[d] - limit - origin[d]) / cell)), 0)
        hi_cell[d] = min(int(np.floor((g[d] + limit - origin[d]) / cell)), dims[d] - 1)
    for ci in range(lo_cell[0], hi_cell[0] + 1):
        for cj in range(lo_cell[1], hi_cell[1] + 1):
            for ck in range(lo_cell[2], hi_cell[2] + 1):
                cell_id = start_off + (ci * dims[1] + cj) * dims[2] + ck
                for s in range(g_start[cell_id], g_start[cell_id + 1]):
                    t = t0 + g_items[items_off + s]
                    if seen[t] == stamp or _box_gap(g, lo, hi, t, reach) ** 2 > best:
                        continue
                    seen[t] = stamp
                    ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, t)
                    best = min(best, closest_on_triangle_xyz(g[0], g[1], g[2], ax, ay, az, bx, by, bz, cx, cy, cz)[0])
    return np.sqrt(best) * (1.0 - 1e-9)


@njit(cache=True)
def _listed_clearance(g, x, static_x, n_nodes, tri_v, lo, hi, reach, cand, c0, c1, limit):
    """The distance from g to the nearest of ``cand[c0:c1]``, at most ``limit`` (the distance beyond which the
    others lie), a little under it (rounding): :func:`_static_clearance` over a node's superset."""
    best = limit * limit
    for s in range(c0, c1):
        t = cand[s]
        if _box_gap(g, lo, hi, t, reach) ** 2 > best:
            continue
        ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, t)
        best = min(best, closest_on_triangle_xyz(g[0], g[1], g[2], ax, ay, az, bx, by, bz, cx, cy, cz)[0])
    return np.sqrt(best) * (1.0 - 1e-9)


@njit(cache=True)
def feature_normals(x, t, tri_v, tri_adj, tri_lv, lv_start, lv_face, face_n, edge_n, corner_n, lv_n, lv_at, stamp):
    """Triangle t's edge normals (its and its neighbour's face normals summed) and angle-weighted vertex normals at
    its corners (over the faces around each, ascending: the sums of ``sim.contact_mesh.pseudonormals``, the same
    arithmetic) at positions ``x``; ``tri_lv``: a corner's surface vertex, ``lv_face[lv_start[v]:lv_start[v + 1]]``
    the faces around it. A vertex normal is computed once per ``stamp`` (``lv_n[v]``, found at ``lv_at[v]``) and
    shared by the triangles around it (each would sum the same faces in the same order)."""
    for k in range(3):
        f = tri_adj[t, k]
        for d in range(3):
            edge_n[t, k, d] = face_n[t, d] + face_n[f, d] if f >= 0 else face_n[t, d]
        length = np.sqrt(edge_n[t, k, 0] ** 2 + edge_n[t, k, 1] ** 2 + edge_n[t, k, 2] ** 2)
        if length > 0.0:
            for d in range(3):
                edge_n[t, k, d] /= length
        v = tri_lv[t, k]
        if lv_at[v] != stamp:
            nx = ny = nz = 0.0
            for s in range(lv_start[v], lv_start[v + 1]):
                f = lv_face[s]
                corner = 0
                while tri_lv[f, corner] != v:
                    corner += 1
                v0, v1, v2 = tri_v[f, corner], tri_v[f, (corner + 1) % 3], tri_v[f, (corner + 2) % 3]
                angle = corner_angle_xyz(x[v1, 0] - x[v0, 0], x[v1, 1] - x[v0, 1], x[v1, 2] - x[v0, 2],
                                         x[v2, 0] - x[v0, 0], x[v2, 1] - x[v0, 1], x[v2, 2] - x[v0, 2])
                if angle >= 0.0:
                    nx += angle * face_n[f, 0]
                    ny += angle * face_n[f, 1]
                    nz += angle * face_n[f, 2]
            length = np.sqrt(nx * nx + ny * ny + nz * nz)
            if length > 0.0:
                nx, ny, nz = nx / length, ny / length, nz / length
            lv_n[v, 0], lv_n[v, 1], lv_n[v, 2] = nx, ny, nz
            lv_at[v] = stamp
        corner_n[t, k, 0], corner_n[t, k, 1], corner_n[t, k, 2] = lv_n[v, 0], lv_n[v, 1], lv_n[v, 2]


@njit(cache=True)
def _gather_own(g, radius, reach, t0, lo, hi, frame, dims, start_off, items_off, own_start, own_items, seen, stamp,
                out, n0):
    """Appends to ``out`` from ``n0`` the triangles (``t0`` + local id) of a static surface whose own box is within
    ``radius`` of g, from the cells of its own-box grid (``sim.contact_set.own_box_grid``: origin ``frame[:3]``, cell
    ``frame[3]``, ``dims``) radius around it, each once (``seen[t] == stamp``), ascending: ``(out, n)``."""
    lo_cell, hi_cell = np.empty(3, np.int64), np.empty(3, np.int64)
    cell = frame[3]
    for d in range(3):
        lo_cell[d] = max(int(np.floor((g[d] - radius - frame[d]) / cell)), 0)
        hi_cell[d] = min(int(np.floor((g[d] + radius - frame[d]) / cell)), dims[d] - 1)
    n = n0
    for ci in range(lo_cell[0], hi_cell[0] + 1):
        for cj in range(lo_cell[1], hi_cell[1] + 1):
            for ck in range(lo_cell[2], hi_cell[2] + 1):
                cell_id = start_off + (ci * dims[1] + cj) * dims[2] + ck
                for s in range(own_start[cell_id], own_start[cell_id + 1]):
                    t = t0 + own_items[items_off + s]
                    if seen[t] == stamp:
                        continue
                    seen[t] = stamp
                    r0 = max(lo[t, 0] + reach - g[0], g[0] - (hi[t, 0] - reach), 0.0)
                    r1 = max(lo[t, 1] + reach - g[1], g[1] - (hi[t, 1] - reach), 0.0)
                    r2 = max(lo[t, 2] + reach - g[2], g[2] - (hi[t, 2] - reach), 0.0)
                    if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) <= radius:  # _box_gap, written out
                        if n == out.size:
                            out = _grown(out)
                        out[n] = t
                        n += 1
    out[n0:n].sort()
    return out, n


@njit(cache=True)
def broad_phase(x, static_x, n_nodes, c_static, c_reach, c_motion, c_node_start, nodes, c_tri_start, tri_v, g_origin,
                g_cell, g_dims, g_start_off, g_items_off, g_start, g_items, g_clearance, own_frame, own_dims, own_off,
                own_start, own_items, c_skin, sup_ref, sup_len, sup_items, c_closed, tri_border, c_slack, c_drift,
                keep_ref, keep_drift, keep_cref, keep_cdrift, keep_second, keep_radius, keep_len, keep_items,
                keep_closed, node_ref, node_clear, node_drift, last_hint, face_n, edge_n, corner_n, lo, hi):
    """The substep's visited nodes (module docstring) of every contact c (its tested ``nodes[c_node_start[c]:
    c_node_start[c + 1]]``, its triangles ``c_tri_start[c]:c_tri_start[c + 1]``). Updates a body surface's
    ``face_n``, ``lo``, ``hi`` (all its triangles; edge and corner normals: :func:`feature_normals`, on demand). A
    static surface's grid: origin, cell, dims, and ``g_start[g_start_off[c]:]``,
    ``g_items[g_items_off[c]:]`` (``sim.contact_mesh.build_grid``, triangle ids local to the surface), ``g_clearance``
    per cell a lower bound of its distance to the surface (:func:`cell_clearance`); the grid of its triangles' own boxes
    (``sim.contact_set.own_box_grid``: ``own_frame[c]`` origin and cell, ``own_dims[c]``, ``own_start`` and
    ``own_items`` from ``own_off[c]``) for the lists and clearances; a static surface's tested node q
    not within reach of it gets in ``node_clear[q]`` its distance to it (at most ``2 reach``) at ``node_ref[q]``: it is
    not tested again before it has moved ``node_clear[q] - reach``; ``last_hint[q]``: its nearest triangle at the last
    broad phase (-1: none). A visited node
    at distance ``d0`` from its nearest triangle lists the triangles whose box is within ``d0 + 4 c_motion[c]`` of it
    (at most ``reach + 2 c_motion[c]``; a body surface's from a grid of the triangles near the tested nodes)
    (with every point moved less than ``c_motion`` since, the nearest then is among them: the node and the hint's
    points each moved less than that). Returns ``(entry_node, entry_contact, entry_hint, entry_start, candidates,
    entry_second, entry_closed, entry_gap)``: per visited node its contact, hint, candidate triangles
    ``candidates[entry_start[e]:entry_start[e + 1]]``, a lower bound of its distance to the nearest triangle other
    than the hint (at most ``reach``; ``nearest_triangle``'s runner-up over the triangles whose grown box holds it,
    which include every listed one within ``reach``), whether the surface is closed around it (``c_closed[c]``, or
    neither the hint nor a listed triangle is ``tri_border``) and, for a static surface closed around it, its distance
    to the surface when it is outside (:func:`outside_gap`; else 0): the narrow phase leaves it alone until it has
    moved that far (``sim.contact_set.project_entries``, ``clear_d``)."""
    n_contacts = c_reach.size
    entry_node = np.empty(nodes.size, np.int64)
    entry_contact = np.empty(nodes.size, np.int64)
    entry_hint = np.empty(nodes.size, np.int64)
    entry_second = np.empty(nodes.size)
    entry_closed = np.empty(nodes.size, np.bool_)
    entry_gap = np.zeros(nodes.size)
    entry_start = np.zeros(nodes.size + 1, np.int64)
    cand = np.empty(256, np.int64)
    near = np.empty(256, np.int64)  # a static surface's triangles in a node's grid cells, or a body's near its nodes
    n_cand, n_entries = 0, 0
    seen = np.full(tri_v.shape[0], -1, np.int64)  # per triangle: the last node that gathered it
    g = np.empty(3)
    lo_cell, hi_cell = np.empty(3, np.int64), np.empty(3, np.int64)
    for c in range(n_contacts):
        t0, t1 = c_tri_start[c], c_tri_start[c + 1]
        reach = c_reach[c]
        q0, q1 = c_node_start[c], c_node_start[c + 1]
        if q0 == q1:
            continue
        if not c_static[c]:
            _face_normals_and_boxes(x, tri_v, t0, t1, reach, face_n, lo, hi)
        # only nodes in the surface's grown box can be within reach of it, and only triangles whose grown box
        # overlaps those nodes' box
        surface_lo, surface_hi = np.full(3, np.inf), np.full(3, -np.inf)
        for t in range(t0, t1):
            for d in range(3):
                surface_lo[d] = min(surface_lo[d], lo[t, d])
                surface_hi[d] = max(surface_hi[d], hi[t, d])
        nodes_lo, nodes_hi = np.full(3, np.inf), np.full(3, -np.inf)
        for q in range(q0, q1):
            for d in range(3):
                nodes_lo[d] = min(nodes_lo[d], max(x[nodes[q], d], surface_lo[d]))
                nodes_hi[d] = max(nodes_hi[d], min(x[nodes[q], d], surface_hi[d]))
        n_body = 0
        grow = 2.0 * c_motion[c] + c_slack[c]  # the largest list radius beyond reach (below)
        if not c_static[c]:  # (boxes grown by grow too: the triangles left out are beyond reach + grow of every node)
            for t in range(t0, t1):
                overlaps = True
                for d in range(3):
                    overlaps = overlaps and lo[t, d] - grow <= nodes_hi[d] and hi[t, d] + grow >= nodes_lo[d]
                if overlaps:
                    near = _append(near, n_body, t)
                    n_body += 1
        if not c_static[c] and n_body == 0:
            continue
        if not c_static[c]:  # a grid of those, their boxes grown by reach + grow (the largest list radius)
            sub_lo, sub_hi = np.empty((n_body, 3)), np.empty((n_body, 3))
            for s in range(n_body):
                for d in range(3):
                    sub_lo[s, d] = lo[near[s], d] - grow
                    sub_hi[s, d] = hi[near[s], d] + grow
            sub_origin, sub_dims, sub_start, sub_items = build_grid(sub_lo, sub_hi, reach + grow)
        for q in range(q0, q1):
            i = nodes[q]
            outside = False
            for d in range(3):
                g[d] = x[i, d]
                outside = outside or g[d] < surface_lo[d] or g[d] > surface_hi[d]
            if outside:
                continue
            moved2 = 0.0
            for d in range(3):
                moved2 += (g[d] - node_ref[q, d]) ** 2
            if node_clear[q] > reach and np.sqrt(moved2) + (c_drift[c] - node_drift[q]) < node_clear[q] - reach:
                continue
            # the last substep's hint, runner-up bound and list kept (keep_*: at keep_ref, the surface's drift then
            # keep_drift) when they still hold: the hint nearer than any other triangle by the node's and the
            # surface's motion since (the search would find it), the list's radius covering the one needed now
            if last_hint[q] >= 0 and keep_len[q] >= 0:
                h = last_hint[q]
                moved = np.sqrt((g[0] - keep_ref[q, 0]) ** 2 + (g[1] - keep_ref[q, 1]) ** 2
                                + (g[2] - keep_ref[q, 2]) ** 2) + (c_drift[c] - keep_drift[q])
                ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, h)
                d2, b0, b1, b2, f = closest_on_triangle_xyz(g[0], g[1], g[2], ax, ay, az, bx, by, bz, cx, cy, cz)
                margin = 1e-9 * reach
                degenerate = face_n[h, 0] == 0.0 and face_n[h, 1] == 0.0 and face_n[h, 2] == 0.0
                radius = min(np.sqrt(d2) + 4.0 * c_motion[c], reach + 2.0 * c_motion[c])
                if not degenerate and d2 < reach * reach * (1.0 - 1e-6) and radius + moved + margin <= keep_radius[q]:
                    node_clear[q] = 0.0
                    while n_cand + keep_len[q] > cand.size:
                        cand = _grown(cand)
                    for s in range(keep_len[q]):
                        cand[n_cand + s] = keep_items[q, s]
                    # the runner-up bound was found at keep_cref (the surface's drift then keep_cdrift)
                    shift = np.sqrt((g[0] - keep_cref[q, 0]) ** 2 + (g[1] - keep_cref[q, 1]) ** 2
                                    + (g[2] - keep_cref[q, 2]) ** 2) + (c_drift[c] - keep_cdrift[q])
                    second = keep_second[q] - shift
                    if not np.sqrt(d2) + shift + margin < keep_second[q]:  # a tie, or nearer: search the list
                        # (it holds every triangle as near as the hint, and those beyond the runner-up's cap)
                        h, f, b0, b1, b2, second2 = nearest_triangle(g, x, static_x, n_nodes, tri_v, face_n, lo, hi,
                                                                     reach, h, cand, n_cand, n_cand + keep_len[q],
                                                                     4.0 * c_motion[c])
                        last_hint[q], second, keep_second[q] = h, np.sqrt(second2), np.sqrt(second2)
                        for d in range(3):
                            keep_cref[q, d] = g[d]
                        keep_cdrift[q] = c_drift[c]
                    entry_node[n_entries], entry_contact[n_entries], entry_hint[n_entries] = i, c, h
                    entry_second[n_entries] = second
                    entry_closed[n_entries] = keep_closed[q]
                    if c_static[c] and keep_closed[q]:  # h is the nearest triangle, at b0, b1, b2 on f
                        entry_gap[n_entries] = outside_gap(g, x, static_x, n_nodes, tri_v, h, b0, b1, b2, f, face_n,
                                                           edge_n, corner_n)
                    n_cand += keep_len[q]
                    n_entries += 1
                    entry_start[n_entries] = n_cand
                    continue
            # the triangles whose grown box holds the node (a static surface: its grid cell's), ascending
            n_near = 0
            far2 = 0.0  # a static surface's: the node's squared distance from where its superset was built
            if c_static[c]:
                cell = g_cell[c]
                cx = int(np.floor((g[0] - g_origin[c, 0]) / cell))
                cy = int(np.floor((g[1] - g_origin[c, 1]) / cell))
                cz = int(np.floor((g[2] - g_origin[c, 2]) / cell))
                if cx < 0 or cy < 0 or cz < 0 or cx >= g_dims[c, 0] or cy >= g_dims[c, 1] or cz >= g_dims[c, 2]:
                    continue
                cell_id = g_start_off[c] + (cx * g_dims[c, 1] + cy) * g_dims[c, 2] + cz
                if g_clearance[cell_id] > reach:  # no triangle within reach of any point of the cell
                    continue
                # the node's superset: the triangles within reach + grow + skin of where it was built, kept while
                # the node is within skin of there (all within reach + grow of it, the largest list, are in it)
                for d in range(3):
                    far2 += (g[d] - sup_ref[q, d]) ** 2
                if sup_len[q] < 0 or far2 > c_skin[c] * c_skin[c]:
                    cand, n_end = _gather_own(g, reach + grow + c_skin[c], reach, t0, lo, hi,
                                              own_frame[c], own_dims[c], own_off[c, 0], own_off[c, 1], own_start,
                                              own_items, seen, -2 - nodes.size - q, cand, n_cand)
                    sup_len[q] = n_end - n_cand if n_end - n_cand <= sup_items.shape[1] else -1
                    for s in range(n_cand, n_end if sup_len[q] >= 0 else n_cand):
                        sup_items[q, s - n_cand] = cand[s]
                    for d in range(3):
                        sup_ref[q, d] = g[d]
                    far2 = 0.0
                if sup_len[q] >= 0:  # the superset holds every triangle within reach: the hint's search over it
                    while n_cand + sup_len[q] > cand.size:
                        cand = _grown(cand)
                    for s in range(sup_len[q]):
                        cand[n_cand + s] = sup_items[q, s]
                    n_near = sup_len[q]
                else:  # too many for its row: the grid cell's, as the grown boxes give them
                    for s in range(g_start[cell_id], g_start[cell_id + 1]):
                        if n_cand + n_near == cand.size:
                            cand = _grown(cand)
                        cand[n_cand + n_near] = t0 + g_items[g_items_off[c] + s]
                        n_near += 1
            else:
                cell = reach + grow
                cx = int(np.floor((g[0] - sub_origin[0]) / cell))
                cy = int(np.floor((g[1] - sub_origin[1]) / cell))
                cz = int(np.floor((g[2] - sub_origin[2]) / cell))
                if cx < 0 or cy < 0 or cz < 0 or cx >= sub_dims[0] or cy >= sub_dims[1] or cz >= sub_dims[2]:
                    continue
                cell_id = (cx * sub_dims[1] + cy) * sub_dims[2] + cz
                pool0, pool1 = sub_start[cell_id], sub_start[cell_id + 1]  # ascending triangles, in sub_items
                for s in range(pool0, pool1):
                    t = near[sub_items[s]]
                    inside = True
                    for d in range(3):
                        inside = inside and lo[t, d] <= g[d] <= hi[t, d]
                    if inside:
                        if n_cand + n_near == cand.size:
                            cand = _grown(cand)
                        cand[n_cand + n_near] = t
                        n_near += 1
            # the node's nearest triangle of the last substep first: the box test then drops most of the others (the
            # result is the same: the last in ascending order among the nearest)
            first = last_hint[q] if last_hint[q] >= 0 else -1
            # the runner-up matters up to the hint's distance plus what the node and the surface can move in the
            # sweeps without a search of all triangles (c_motion each), with room to spare
            hint, f, b0, b1, b2, second2 = nearest_triangle(g, x, static_x, n_nodes, tri_v, face_n, lo, hi, reach,
                                                            first, cand, n_cand, n_cand + n_near, 4.0 * c_motion[c])
            last_hint[q] = hint
            if hint < 0:
                if c_static[c] and sup_len[q] >= 0:  # every triangle off the superset is this far at least
                    limit = min(2.0 * reach, reach + 2.0 * c_motion[c] + c_skin[c] - np.sqrt(far2))
                    node_clear[q] = _listed_clearance(g, x, static_x, n_nodes, tri_v, lo, hi, reach, cand, n_cand,
                                                      n_cand + n_near, limit)
                elif c_static[c]:
                    node_clear[q] = _static_clearance(g, x, static_x, n_nodes, tri_v, lo, hi, reach, t0,
                                                      own_frame[c, :3], own_frame[c, 3], own_dims[c], own_off[c, 0],
                                                      own_off[c, 1], own_start, own_items, seen, -2 - q)
                else:  # a body surface: its pool holds every triangle within reach + grow of the node
                    n_pool = pool1 - pool0
                    while n_cand + n_near + n_pool > cand.size:
                        cand = _grown(cand)
                    for s in range(n_pool):
                        cand[n_cand + n_near + s] = near[sub_items[pool0 + s]]
                    node_clear[q] = _listed_clearance(g, x, static_x, n_nodes, tri_v, lo, hi, reach, cand,
                                                      n_cand + n_near, n_cand + n_near + n_pool,
                                                      min(2.0 * reach, reach + grow))
                for d in range(3):
                    node_ref[q, d] = g[d]
                node_drift[q] = c_drift[c]
                continue
            node_clear[q] = 0.0
            ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, hint)
            rx = g[0] - (b0 * ax + b1 * bx + b2 * cx)
            ry = g[1] - (b0 * ay + b1 * by + b2 * cy)
            rz = g[2] - (b0 * az + b1 * bz + b2 * cz)
            d0 = rx * rx + ry * ry + rz * rz
            # a triangle within reach of the node during the sweeps is within reach + 2 c_motion of it now (and
            # within its distance to the hint plus 4 c_motion); listed with room (c_slack) for the node and the
            # surface to move a little before the list is built again: beyond the cap too, or a node farther than
            # reach - 2 c_motion - c_slack from the surface would need a new list at every substep
            radius = min(np.sqrt(d0) + 4.0 * c_motion[c], reach + 2.0 * c_motion[c]) + c_slack[c]
            # the listed triangles: within radius of the node (a static surface: from the cells radius around it)
            n_list = 0
            if c_static[c]:
                if sup_len[q] >= 0:  # the superset's (ascending) within radius, in place
                    for s in range(n_cand, n_cand + n_near):
                        t = cand[s]
                        r0 = max(lo[t, 0] + reach - g[0], g[0] - (hi[t, 0] - reach), 0.0)
                        r1 = max(lo[t, 1] + reach - g[1], g[1] - (hi[t, 1] - reach), 0.0)
                        r2 = max(lo[t, 2] + reach - g[2], g[2] - (hi[t, 2] - reach), 0.0)
                        if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) <= radius:  # _box_gap, written out
                            cand[n_cand + n_list] = t
                            n_list += 1
                else:
                    cand, n_end = _gather_own(g, radius, reach, t0, lo, hi, own_frame[c], own_dims[c], own_off[c, 0],
                                              own_off[c, 1], own_start, own_items, seen, q, cand, n_cand)
                    n_list = n_end - n_cand
            else:
                for s in range(pool0, pool1):
                    t = near[sub_items[s]]
                    r0 = max(lo[t, 0] + reach - g[0], g[0] - (hi[t, 0] - reach), 0.0)
                    r1 = max(lo[t, 1] + reach - g[1], g[1] - (hi[t, 1] - reach), 0.0)
                    r2 = max(lo[t, 2] + reach - g[2], g[2] - (hi[t, 2] - reach), 0.0)
                    if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) <= radius:  # _box_gap, written out
                        if n_cand + n_list == cand.size:
                            cand = _grown(cand)
                        cand[n_cand + n_list] = t
                        n_list += 1
            entry_node[n_entries], entry_contact[n_entries], entry_hint[n_entries] = i, c, hint
            entry_second[n_entries] = np.sqrt(second2)
            interior = not tri_border[hint]
            for s in range(n_cand, n_cand + n_list):
                interior = interior and not tri_border[cand[s]]
            entry_closed[n_entries] = c_closed[c] or interior
            keep_len[q] = n_list if n_list <= keep_items.shape[1] else -1
            for s in range(n_list if keep_len[q] >= 0 else 0):
                keep_items[q, s] = cand[n_cand + s]
            for d in range(3):
                keep_ref[q, d] = keep_cref[q, d] = g[d]
            keep_drift[q] = keep_cdrift[q] = c_drift[c]
            keep_second[q], keep_radius[q] = np.sqrt(second2), radius
            keep_closed[q] = entry_closed[n_entries]
            if c_static[c] and entry_closed[n_entries]:
                entry_gap[n_entries] = outside_gap(g, x, static_x, n_nodes, tri_v, hint, b0, b1, b2, f, face_n, edge_n,
                                                   corner_n)
            n_cand += n_list
            n_entries += 1
            entry_start[n_entries] = n_cand
    return (entry_node[:n_entries].copy(), entry_contact[:n_entries].copy(), entry_hint[:n_entries].copy(),
            entry_start[:n_entries + 1].copy(), cand[:n_cand].copy(), entry_second[:n_entries].copy(),
            entry_closed[:n_entries].copy(), entry_gap[:n_entries].copy())
