"""All triangle-surface contacts of a model (``Model.contacts``, ``sim.contact_bodies.SurfaceContact``) as one flat
set for XPBD: a broad phase once per substep, a narrow phase per Gauss-Seidel sweep over the small candidate lists it
found, friction once after the sweeps. The constraint, the inside test and the friction are ``sim.contact_mesh``'s
(module docstring there: Bærentzen & Aanæs 2005, Macklin et al. 2016 eq. 18).

**Broad phase** (:func:`broad_phase`, one call per substep for every contact). A body's surface gets its triangles'
boxes grown by ``reach`` at the predicted positions and its face normals; a static surface has both from its
construction and its grid (``SurfaceContactState``). A tested node is *visited* by the substep's sweeps when a
triangle lies within ``reach`` of it now (the nearest one is its hint, tried first in every sweep), as before: a node
farther off would have to be moved more than ``reach`` by one substep's corrections to reach the surface. Each
visited node gets the list of triangles whose grown box lies within ``reach`` of it now (ascending triangle order):
by the same bound on a substep's motion, every triangle within ``reach`` of it during the sweeps is in the list.
Edge and angle-weighted vertex normals are computed only for the listed triangles (the vertex sums in ascending face
order, as a whole-surface pass adds them).

**Narrow phase** (:func:`project_entries`, every sweep): per visited node, the hint and then its list, each triangle
skipped when its box is farther than the best so far, the closest point and the inside test on the nearest within
``reach``. The visited nodes, their hints and the triangles tried in the order they are tried give what one grid
lookup per node and sweep gave (``sim.contact_mesh.project_nodes``: the triangles of the node's cell), so the steps
are the same bit for bit (tests/sim/test_contact_set.py) at a fraction of the cost (docs/interaction.md).

Vertices: ids below ``n_nodes`` are the model's nodes (positions ``x``, inverse masses ``w``); ids from ``n_nodes``
on are the static surfaces' points (``static_x``, inverse mass 0).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from sim.contact_broad import broad_phase, cell_clearance, corners, feature_normals, nearest_triangle
from sim.contact_mesh import GRID_CELLS, build_grid, closest_on_triangle_xyz
from sim.wrench import add_wrench


@njit(cache=True)
def _most_moved(x, x_start, nodes):
    """The largest displacement of ``nodes`` since the broad phase."""
    most = 0.0
    for v in nodes:
        most = max(most, (x[v, 0] - x_start[v, 0]) ** 2 + (x[v, 1] - x_start[v, 1]) ** 2
                   + (x[v, 2] - x_start[v, 2]) ** 2)
    return np.sqrt(most)


@njit(cache=True)
def project_entries(x, w, x_start, static_x, n_nodes, entry_node, entry_contact, entry_hint, entry_start, candidates,
                    entry_second, surface_nodes, all_triangles, c_tri_start, tri_v, tri_adj, tri_lv, lv_start, lv_face,
                    normals_at, substep, face_n, edge_n, corner_n, lv_n, lv_at, lo, hi, c_reach, c_motion, entry_closed,
                    clear_x, clear_d, clear_m, c_sign, c_pair, lam_n, contact_tri, contact_bary, contact_n, loads):
    """One Gauss-Seidel pass of the contact constraint over the visited nodes (``sim.contact_mesh.project_nodes``'
    update: both sides moved by their inverse masses); per entry the summed normal impulse, the triangle,
    barycentrics and normal of its last correction; ``c_sign[c]`` times the impulse and its moment about the origin
    added to ``loads[c_pair[c]]``. A node searches its candidate list while it has moved less than ``c_motion[c]``
    since the broad phase (``x_start``), else all of its contact's triangles (``all_triangles``: 0, 1, ...). Returns
    the number of corrections. A body surface's edge and vertex normals are computed for a triangle when it is
    first nearest to a node in the substep (``normals_at[t]``: the last ``substep`` they were; a vertex's in ``lv_n``,
    of substep ``lv_at``, shared by its triangles). A node found outside a
    surface closed around it (``entry_closed[e]``: a closed surface, or no listed triangle at a border of an open one,
    where the pseudonormal test's sign is the side) at distance ``clear_d[e]`` at ``clear_x[e]`` (its listed vertices
    then moved ``clear_m[e]`` since the broad phase) stays outside while its motion since and its listed vertices'
    cannot close that distance (it would have to cross the surface): it is not searched (the same result: an outside
    node is left alone). ``clear_d[e] = 0``: no such bound."""
    moved = 0
    g = np.empty(3)
    # the largest motion since the broad phase of a body surface's vertex (of ``surface_nodes``), a bound of any
    # listed vertices' (-1: not found yet); raised by every correction of this pass
    surface = -1.0
    for e in range(entry_node.size):
        i, c = entry_node[e], entry_contact[e]
        for d in range(3):
            g[d] = x[i, d]
        motion2 = (g[0] - x_start[i, 0]) ** 2 + (g[1] - x_start[i, 1]) ** 2 + (g[2] - x_start[i, 2]) ** 2
        listed = motion2 < c_motion[c] * c_motion[c]
        if listed:
            static = tri_v[entry_hint[e], 0] >= n_nodes  # a static surface does not move
            if not static and surface < 0.0:
                surface = _most_moved(x, x_start, surface_nodes)
            moved_surface = 0.0 if static else surface
            if clear_d[e] > 0.0:
                node = np.sqrt((g[0] - clear_x[e, 0]) ** 2 + (g[1] - clear_x[e, 1]) ** 2 + (g[2] - clear_x[e, 2]) ** 2)
                if node + moved_surface + clear_m[e] < clear_d[e]:
                    continue
            # the hint is still the nearest listed triangle within reach, without searching the list, when its
            # distance now plus the node's motion and the listed vertices' since the broad phase is under
            # entry_second, the distance there to the nearest other triangle: each other listed triangle is then
            # farther, and the search would return the hint with the same closest point. The margins (1e-9 reach,
            # 1e-6 of reach**2) are far above the rounding of these sums (a few ulps of the coordinates) and keep
            # clear of ties and of the search's box and plane skips. Written out here: a call passing arrays costs
            # more than the test (docs/interaction.md, "The narrow phase's cost").
            t, h, reach = -1, entry_hint[e], c_reach[c]
            if entry_second[e] > 0.0:
                ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, h)
                d2, e0, e1, e2, feature = closest_on_triangle_xyz(g[0], g[1], g[2], ax, ay, az, bx, by, bz, cx, cy,
                                                                  cz)
                if d2 < reach * reach * (1.0 - 1e-6):
                    if np.sqrt(d2) + np.sqrt(motion2) + moved_surface + 1e-9 * reach < entry_second[e]:
                        t, f, b0, b1, b2 = h, feature, e0, e1, e2
            if t < 0:
                t, f, b0, b1, b2, _ = nearest_triangle(g, x, static_x, n_nodes, tri_v, face_n, lo, hi, c_reach[c],
                                                       entry_hint[e], candidates, entry_start[e], entry_start[e + 1])
        else:
            t, f, b0, b1, b2, _ = nearest_triangle(g, x, static_x, n_nodes, tri_v, face_n, lo, hi, c_reach[c],
                                                   entry_hint[e], all_triangles, c_tri_start[c], c_tri_start[c + 1])
        clear_d[e] = 0.0
        if t < 0:
            if listed and entry_closed[e]:  # no listed triangle within reach
                clear_d[e], clear_m[e] = c_reach[c] * (1.0 - 1e-9), moved_surface
                clear_x[e, 0], clear_x[e, 1], clear_x[e, 2] = g[0], g[1], g[2]
            continue
        va, vb, vc = tri_v[t, 0], tri_v[t, 1], tri_v[t, 2]
        if va < n_nodes and normals_at[t] != substep:  # a body surface's, at the broad phase's positions
            feature_normals(x_start, t, tri_v, tri_adj, tri_lv, lv_start, lv_face, face_n, edge_n, corner_n, lv_n,
                            lv_at, substep)
            normals_at[t] = substep
        ax, ay, az, bx, by, bz, cx, cy, cz = corners(x, static_x, n_nodes, tri_v, t)
        qx = b0 * ax + b1 * bx + b2 * cx
        qy = b0 * ay + b1 * by + b2 * cy
        qz = b0 * az + b1 * bz + b2 * cz
        dx, dy, dz = g[0] - qx, g[1] - qy, g[2] - qz
        if f < 3:
            Nx, Ny, Nz = corner_n[t, f, 0], corner_n[t, f, 1], corner_n[t, f, 2]
        elif f < 6:
            Nx, Ny, Nz = edge_n[t, f - 3, 0], edge_n[t, f - 3, 1], edge_n[t, f - 3, 2]
        else:
            Nx, Ny, Nz = face_n[t, 0], face_n[t, 1], face_n[t, 2]
        if dx * Nx + dy * Ny + dz * Nz >= 0.0:
            if listed and entry_closed[e]:  # outside at that distance (a little less: rounding)
                clear_d[e], clear_m[e] = np.sqrt(dx * dx + dy * dy + dz * dz) * (1.0 - 1e-9), moved_surface
                clear_x[e, 0], clear_x[e, 1], clear_x[e, 2] = g[0], g[1], g[2]
            continue
        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
        if dist > 1e-300:  # n: from the node to the surface point (outward)
            nx, ny, nz = -dx / dist, -dy / dist, -dz / dist
        else:
            nx, ny, nz = Nx, Ny, Nz
        wa = w[va] if va < n_nodes else 0.0
        wb = w[vb] if vb < n_nodes else 0.0
        wc = w[vc] if vc < n_nodes else 0.0
        w_sum = w[i] + b0 * b0 * wa + b1 * b1 * wb + b2 * b2 * wc
        if w_sum == 0.0:
            continue
        dlam = dist / w_sum
        jx, jy, jz = dlam * nx, dlam * ny, dlam * nz
        x[i, 0] += w[i] * jx
        x[i, 1] += w[i] * jy
        x[i, 2] += w[i] * jz
        for v, bk, wk in ((va, b0, wa), (vb, b1, wb), (vc, b2, wc)):
            if v < n_nodes:
                x[v, 0] -= bk * wk * jx
                x[v, 1] -= bk * wk * jy
                x[v, 2] -= bk * wk * jz
        lam_n[e] += dlam
        contact_tri[e] = t
        contact_bary[e, 0], contact_bary[e, 1], contact_bary[e, 2] = b0, b1, b2
        contact_n[e, 0], contact_n[e, 1], contact_n[e, 2] = nx, ny, nz
        sign, load = c_sign[c], loads[c_pair[c]]
        rx, ry, rz = x[i, 0], x[i, 1], x[i, 2]
        add_wrench(load, sign, jx, jy, jz, rx, ry, rz)
        moved += 1
        if surface >= 0.0:  # the bound stays one: the corrected node and triangle corners moved
            for v in (i, va, vb, vc):
                if v < n_nodes:
                    surface = max(surface, np.sqrt((x[v, 0] - x_start[v, 0]) ** 2 + (x[v, 1] - x_start[v, 1]) ** 2
                                                   + (x[v, 2] - x_start[v, 2]) ** 2))
    return moved


@njit(cache=True)
def friction_entries(x, x_prev, w, n_nodes, entry_node, entry_contact, tri_v, c_mu, c_sign, c_pair, lam_n,
                     contact_tri, contact_bary, contact_n, loads):
    """Coulomb friction (``sim.contact_mesh``'s module docstring) on the visited nodes with a normal impulse this
    substep, for the contacts with ``c_mu > 0``; a static surface does not move."""
    du = np.empty(3)
    for e in range(entry_node.size):
        c = entry_contact[e]
        if lam_n[e] <= 0.0 or c_mu[c] == 0.0:
            continue
        i, t = entry_node[e], contact_tri[e]
        ws = 0.0
        for d in range(3):
            du[d] = x[i, d] - x_prev[i, d]
        for k in range(3):
            v = tri_v[t, k]
            bk = contact_bary[e, k]
            if v < n_nodes:
                for d in range(3):
                    du[d] -= bk * (x[v, d] - x_prev[v, d])
                ws += bk * bk * w[v]
            else:
                ws += bk * bk * 0.0
        w_sum = w[i] + ws
        if w_sum == 0.0:
            continue
        un = du[0] * contact_n[e, 0] + du[1] * contact_n[e, 1] + du[2] * contact_n[e, 2]
        tx, ty, tz = du[0] - un * contact_n[e, 0], du[1] - un * contact_n[e, 1], du[2] - un * contact_n[e, 2]
        slip = np.sqrt(tx * tx + ty * ty + tz * tz)
        if slip == 0.0:
            continue
        mu = c_mu[c]
        limit = mu * lam_n[e] * w_sum
        # static: the tangential impulse that stops the relative motion; kinetic: Coulomb's mu lambda_n
        scale = 1.0 / w_sum if slip < limit else mu * lam_n[e] / slip
        jx, jy, jz = scale * tx, scale * ty, scale * tz
        x[i, 0] -= w[i] * jx
        x[i, 1] -= w[i] * jy
        x[i, 2] -= w[i] * jz
        for k in range(3):
            v = tri_v[t, k]
            if v < n_nodes:
                bk = contact_bary[e, k]
                x[v, 0] += bk * w[v] * jx
                x[v, 1] += bk * w[v] * jy
                x[v, 2] += bk * w[v] * jz
        sign, load = c_sign[c], loads[c_pair[c]]
        rx, ry, rz = x[i, 0], x[i, 1], x[i, 2]
        load[0] -= sign * jx
        load[1] -= sign * jy
        load[2] -= sign * jz
        load[3] -= sign * (ry * jz - rz * jy)
        load[4] -= sign * (rz * jx - rx * jz)
        load[5] -= sign * (rx * jy - ry * jx)


def border_triangles(faces, adjacent):
    """Per triangle whether a corner lies on a border edge (an edge with no neighbour: ``adjacent`` -1)."""
    k = np.nonzero(adjacent < 0)
    on_border = np.zeros(int(faces.max()) + 1 if faces.size else 0, np.bool_)
    on_border[faces[k[0], k[1]]] = True
    on_border[faces[k[0], (k[1] + 1) % 3]] = True
    return on_border[faces].any(axis=1)


def own_box_grid(lo, hi, reach):
    """A grid of a static surface's triangles by their own boxes (``lo``, ``hi`` grown by ``reach``, shrunk again
    as the box tests do), cells their mean largest side (at most ``GRID_CELLS`` along the longest extent):
    ``(origin, cell, dims, start, items)``. The triangles within a distance r of a point are among those of the cells
    r around it; each triangle lies in a few cells, where the grid of the grown boxes repeats it in tens (it answers
    which triangles' grown box holds a point: one cell)."""
    own_lo, own_hi = lo + reach, hi - reach
    extent = float((own_hi.max(axis=0) - own_lo.min(axis=0)).max())
    cell = max(float((own_hi - own_lo).max(axis=1).mean()), extent / GRID_CELLS, 1e-9)
    origin, dims, start, items = build_grid(own_lo, own_hi, cell)
    return origin, cell, dims, start, items


class ContactSet:
    """The model's surface contacts (``sim.contact_bodies.SurfaceContactState`` each: a static surface's normals,
    boxes and grid are built there once) as flat arrays over all their triangles; :meth:`begin` at every substep's
    start, :meth:`project` in every sweep, :meth:`friction` after the sweeps. Each contact's state gets views of its
    visited nodes' ``active``, ``lam_n``, ``tri``, ``bary``, ``normal`` for the substep."""

    motion_fraction = 0.125
    skin_fraction = 0.5  # of reach: how far a node moves before its superset is built again
    superset_size = 48  # triangles at most in a node's superset or kept list (more: from the grids, as without)
    slack_fraction = 0.5  # of c_motion: the room a list is built with, so that it can be kept

    def __init__(self, contacts: list, n_nodes: int):
        self.contacts = contacts
        self.n_nodes = n_nodes
        statics = [c for c in contacts if c.static]
        self.static_x = (np.ascontiguousarray(np.concatenate([c.xv for c in statics]), dtype=np.float64) if statics
                         else np.zeros((0, 3)))
        tri_v, tri_adj, tri_lv, lv_faces, face_n, edge_n, corner_n, lo, hi = [], [], [], [], [], [], [], [], []
        g_origin, g_cell, g_dims, g_start, g_items, g_start_off, g_items_off = [], [], [], [], [], [], []
        g_clear = []
        o_frame, o_dims, o_off, o_start, o_items = [], [], [], [], []  # the grids of the triangles' own boxes
        tri_start, static_start, lv_count, start_off, items_off = [0], n_nodes, 0, 0, 0
        own_start_off, own_items_off = 0, 0
        for c in contacts:
            k, t0 = c.faces.shape[0], tri_start[-1]
            tri_adj.append(np.where(c.adjacent >= 0, c.adjacent + t0, -1))
            if c.static:
                tri_v.append(c.faces + static_start)
                static_start += c.xv.shape[0]
                tri_lv.append(np.zeros((k, 3), np.int64))
                face_n.append(c.face_n), edge_n.append(c.edge_n), corner_n.append(c.vert_n[c.faces])
                lo.append(c.lo), hi.append(c.hi)
                g_origin.append(c.origin), g_cell.append(c.cell), g_dims.append(c.dims)
                g_start.append(c.start), g_items.append(c.items)
                # slightly under the true gap: rounding in the box arithmetic (a few ulps of the coordinates)
                g_clear.append(cell_clearance(c.origin, c.cell, c.dims, c.lo, c.hi, c.reach) * (1.0 - 1e-9))
                g_start_off.append(start_off), g_items_off.append(items_off)
                start_off, items_off = start_off + c.start.size, items_off + c.items.size
                origin, cell, dims, start, items = own_box_grid(c.lo, c.hi, c.reach)
                o_frame.append([*origin, cell]), o_dims.append(dims), o_off.append([own_start_off, own_items_off])
                o_start.append(start), o_items.append(items)
                own_start_off, own_items_off = own_start_off + start.size, own_items_off + items.size
            else:
                tri_v.append(c.vmap[c.faces])
                tri_lv.append(c.faces + lv_count)
                # the faces around each surface vertex, ascending (the order a whole-surface pass adds them in)
                corner_vertex = c.faces.ravel()
                order = np.argsort(corner_vertex, kind="stable")
                lv_faces.append(np.bincount(corner_vertex, minlength=c.vmap.size))
                lv_faces.append(order // 3 + t0)
                lv_count += c.vmap.size
                for name, shape in ((face_n, (k, 3)), (edge_n, (k, 3, 3)), (corner_n, (k, 3, 3)), (lo, (k, 3)),
                                    (hi, (k, 3))):
                    name.append(np.zeros(shape))
                g_origin.append(np.zeros(3)), g_cell.append(1.0), g_dims.append(np.zeros(3, np.int64))
                g_start_off.append(start_off), g_items_off.append(items_off)
                o_frame.append([0.0, 0.0, 0.0, 1.0]), o_dims.append(np.zeros(3, np.int64))
                o_off.append([own_start_off, own_items_off])
            tri_start.append(t0 + k)
        cat = lambda parts, shape, dtype=np.float64: (  # noqa: E731
            np.ascontiguousarray(np.concatenate(parts), dtype=dtype) if parts else np.zeros(shape, dtype))
        self.tri_v, self.tri_adj, self.tri_lv = (cat(tri_v, (0, 3), np.int64), cat(tri_adj, (0, 3), np.int64),
                                                 cat(tri_lv, (0, 3), np.int64))
        self.lv_start = np.concatenate([[0], np.cumsum(np.concatenate(lv_faces[0::2]) if lv_faces else [])]
                                       ).astype(np.int64)
        self.lv_face = cat(lv_faces[1::2], (0,), np.int64)
        self.face_n, self.edge_n, self.corner_n = cat(face_n, (0, 3)), cat(edge_n, (0, 3, 3)), cat(corner_n, (0, 3, 3))
        self.lo, self.hi = cat(lo, (0, 3)), cat(hi, (0, 3))
        self.g_origin, self.g_cell = cat([np.reshape(o, (1, 3)) for o in g_origin], (0, 3)), cat([g_cell], (0,))
        self.g_dims = cat([np.reshape(d, (1, 3)) for d in g_dims], (0, 3), np.int64)
        self.g_start, self.g_items = cat(g_start, (0,), np.int64), cat(g_items, (0,), np.int64)
        self.g_clearance = cat(g_clear, (0,))
        self.g_start_off, self.g_items_off = cat([g_start_off], (0,), np.int64), cat([g_items_off], (0,), np.int64)
        self.own_frame = np.array(o_frame, dtype=np.float64).reshape(-1, 4)
        self.own_dims = np.array(o_dims, dtype=np.int64).reshape(-1, 3)
        self.own_off = np.array(o_off, dtype=np.int64).reshape(-1, 2)
        self.own_start, self.own_items = cat(o_start, (0,), np.int64), cat(o_items, (0,), np.int64)
        self.c_tri_start = np.array(tri_start, dtype=np.int64)
        self.nodes = cat([c.spec.nodes for c in contacts], (0,), np.int64)
        self.c_node_start = np.concatenate([[0], np.cumsum([c.spec.nodes.size for c in contacts])]).astype(np.int64)
        self.c_static = np.array([c.static for c in contacts], dtype=np.bool_)
        self.c_reach = np.array([c.reach for c in contacts], dtype=np.float64)
        self.c_sign = np.array([c.spec.sign for c in contacts], dtype=np.float64)
        self.c_pair = np.array([c.spec.pair for c in contacts], dtype=np.int64)
        self.c_mu = np.array([c.spec.friction for c in contacts], dtype=np.float64)
        # a node outside a closed surface cannot get in without crossing it (a body's boundary, a closed static mesh)
        self.c_closed = np.array([not c.static or bool((c.adjacent >= 0).all()) for c in contacts], dtype=np.bool_)
        # an open static surface's triangles at its border (a corner on a border edge): elsewhere it is closed
        # around a node whose listed triangles are none of these (the pseudonormal test's sign is the side there)
        self.tri_border = np.zeros(self.tri_v.shape[0], np.bool_)
        for c, t0 in zip(contacts, self.c_tri_start[:-1]):
            if c.static:
                self.tri_border[t0:t0 + c.faces.shape[0]] = border_triangles(c.faces, c.adjacent)
        # a node moved this far within the sweeps searches all its contact's triangles, else its list (broad_phase):
        # an eighth of reach, above what one substep's corrections usually move a node
        self.c_motion = self.motion_fraction * self.c_reach
        self.all_triangles = np.arange(self.tri_v.shape[0], dtype=np.int64)
        # the body surfaces' vertices (model nodes): what a listed triangle's corners can be
        self.surface_nodes = cat([np.unique(c.vmap) for c in contacts if not c.static], (0,), np.int64)
        self.x_start = np.zeros((n_nodes, 3))
        # per tested node of a static surface its superset of triangles (broad_phase), rebuilt when it has moved
        # c_skin from where it was built
        self.c_skin = self.skin_fraction * self.c_reach
        self.sup_ref = np.zeros((self.nodes.size, 3))
        self.sup_len = np.full(self.nodes.size, -1, np.int64)
        self.sup_items = np.zeros((self.nodes.size, self.superset_size), np.int64)
        # per tested node its last list, hint's runner-up bound, where (keep_ref) and at which drift of the surface
        # they were found (broad_phase keeps them while they hold); c_drift: per contact the sum over substeps of its
        # surface vertices' largest displacement between broad phases (0 for a static surface), a bound of any
        # vertex's motion between two of them
        self.c_slack = self.slack_fraction * self.c_motion
        self.c_drift = np.zeros(len(contacts))
        self.keep_ref, self.keep_drift = np.zeros((self.nodes.size, 3)), np.zeros(self.nodes.size)
        self.keep_cref, self.keep_cdrift = np.zeros((self.nodes.size, 3)), np.zeros(self.nodes.size)  # keep_second's
        self.keep_second, self.keep_radius = np.zeros(self.nodes.size), np.zeros(self.nodes.size)
        self.keep_len = np.full(self.nodes.size, -1, np.int64)
        self.keep_items = np.zeros((self.nodes.size, self.superset_size), np.int64)
        self.keep_closed = np.zeros(self.nodes.size, np.bool_)
        self.c_vertices = [np.unique(c.vmap) if not c.static else None for c in contacts]
        self.node_ref, self.node_clear = np.zeros((self.nodes.size, 3)), np.zeros(self.nodes.size)
        self.node_drift = np.zeros(self.nodes.size)  # the surface's drift (c_drift) when node_clear was found
        self.last_hint = np.full(self.nodes.size, -1, np.int64)
        self.normals_at = np.full(self.tri_v.shape[0], -1, np.int64)  # feature normals: the substep they are of
        self.lv_n = np.zeros((lv_count, 3))  # a body surface vertex's normal, of substep lv_at
        self.lv_at = np.full(lv_count, -1, np.int64)
        self.substep = 0
        self.begin(None)

    def begin(self, x: np.ndarray | None) -> None:
        """At a substep's start (after the prediction): the visited nodes, their hints and candidate triangles at
        ``x`` (:func:`broad_phase`); multipliers reset. ``None``: none visited."""
        if x is None or not self.contacts:
            empty = np.zeros(0, np.int64)
            self.entry_node, self.entry_contact, self.entry_hint, self.candidates = empty, empty, empty, empty
            self.entry_second, self.entry_closed = np.zeros(0), np.zeros(0, np.bool_)
            self.entry_start = np.zeros(1, np.int64)
            gap, at = np.zeros(0), np.zeros((0, 3))
        else:
            for k, vertices in enumerate(self.c_vertices):  # x_start: the last broad phase's positions
                if vertices is not None and self.substep:  # (nothing is kept before the first)
                    self.c_drift[k] += _most_moved(x, self.x_start, vertices)
            self.x_start[:] = x
            self.substep += 1
            (self.entry_node, self.entry_contact, self.entry_hint, self.entry_start, self.candidates,
             self.entry_second, self.entry_closed, gap) = broad_phase(
                x, self.static_x, self.n_nodes, self.c_static, self.c_reach, self.c_motion, self.c_node_start,
                self.nodes, self.c_tri_start, self.tri_v, self.g_origin, self.g_cell, self.g_dims, self.g_start_off,
                self.g_items_off, self.g_start, self.g_items, self.g_clearance, self.own_frame, self.own_dims,
                self.own_off, self.own_start, self.own_items, self.c_skin, self.sup_ref, self.sup_len,
                self.sup_items, self.c_closed, self.tri_border, self.c_slack, self.c_drift, self.keep_ref,
                self.keep_drift, self.keep_cref, self.keep_cdrift, self.keep_second, self.keep_radius, self.keep_len,
                self.keep_items, self.keep_closed,
                self.node_ref, self.node_clear, self.node_drift, self.last_hint,
                self.face_n, self.edge_n, self.corner_n, self.lo, self.hi)
            at = x[self.entry_node]  # where each node's gap was found
        e = self.entry_node.size
        self.lam_n, self.tri = np.zeros(e), np.zeros(e, dtype=np.int64)
        self.bary, self.normal = np.zeros((e, 3)), np.zeros((e, 3))
        # a node outside a static surface is left alone from the first sweep (broad_phase's entry_gap)
        self.clear_x, self.clear_d, self.clear_m = at, gap, np.zeros(e)
        bounds = np.searchsorted(self.entry_contact, np.arange(len(self.contacts) + 1))
        for k, c in enumerate(self.contacts):
            part = slice(bounds[k], bounds[k + 1])
            c.active = self.entry_node[part]
            c.lam_n, c.tri, c.bary, c.normal = self.lam_n[part], self.tri[part], self.bary[part], self.normal[part]

    def arrays(self) -> tuple:
        """The narrow phase's arguments after ``x, w`` (:func:`project_entries`, up to ``loads``)."""
        return (self.x_start, self.static_x, self.n_nodes, self.entry_node, self.entry_contact, self.entry_hint,
                self.entry_start, self.candidates, self.entry_second, self.surface_nodes, self.all_triangles,
                self.c_tri_start,
                self.tri_v, self.tri_adj, self.tri_lv, self.lv_start, self.lv_face, self.normals_at, self.substep,
                self.face_n, self.edge_n, self.corner_n, self.lv_n, self.lv_at, self.lo, self.hi, self.c_reach,
                self.c_motion, self.entry_closed, self.clear_x, self.clear_d, self.clear_m, self.c_sign, self.c_pair,
                self.lam_n, self.tri, self.bary, self.normal)

    def project(self, x: np.ndarray, w: np.ndarray, loads: np.ndarray) -> int:
        """One pass over the visited nodes; adds the impulses to ``loads`` (pairs, 6) (:func:`project_entries`)."""
        if not self.entry_node.size:
            return 0
        return int(project_entries(x, w, *self.arrays(), loads))

    def friction(self, x: np.ndarray, x_prev: np.ndarray, w: np.ndarray, loads: np.ndarray) -> None:
        if self.entry_node.size:
            friction_entries(x, x_prev, w, self.n_nodes, self.entry_node, self.entry_contact, self.tri_v, self.c_mu,
                             self.c_sign, self.c_pair, self.lam_n, self.tri, self.bary, self.normal, loads)
