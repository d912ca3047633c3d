"""Procedural tetrahedral meshes: boxes split 6 tets per hex cell, and signed-distance shapes
(cylinder, slab, organ-like liver and kidney) voxelised on a grid with boundary vertices snapped
onto the zero level set (Qian ch. 3 builds its organ surfaces by the same SDF voxelisation).

All meshes are conforming and positively oriented (``det[x1-x0, x2-x0, x3-x0] > 0``), in metres.
"""
from __future__ import annotations

import itertools

import numpy as np

from sim.errors import MeshError
from sim.mesh.types import TetMesh

# Freudenthal (Kuhn) split of the unit cube: one tet per permutation of the axes, each a monotone
# path 000 -> 111. Neighbouring cells split their shared faces identically, so the mesh conforms.
_CORNER = {c: i for i, c in enumerate(itertools.product((0, 1), repeat=3))}  # (dx,dy,dz) -> 0..7


def _kuhn_tets() -> np.ndarray:
    tets = []
    for perm in itertools.permutations(range(3)):
        corner = [0, 0, 0]
        path = [tuple(corner)]
        for axis in perm:
            corner[axis] = 1
            path.append(tuple(corner))
        tets.append([_CORNER[c] for c in path])
    return np.array(tets, dtype=np.int64)


KUHN = _kuhn_tets()


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed tet volumes ``det[x1-x0, x2-x0, x3-x0] / 6`` [m^3]."""
    p = points[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def orient(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Tets with vertices 1 and 2 swapped where the signed volume is negative."""
    tets = tets.copy()
    neg = signed_volumes(points, tets) < 0.0
    tets[neg, 1], tets[neg, 2] = tets[neg, 2].copy(), tets[neg, 1].copy()
    return tets


def _grid(lo, cells, h):
    """Grid node positions ``(nx+1)(ny+1)(nz+1) x 3`` and the 8 corner node ids of every cell."""
    nx, ny, nz = cells
    axes = [lo[a] + h[a] * np.arange(cells[a] + 1) for a in range(3)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    base = (i * (ny + 1) + j) * (nz + 1) + k
    corners = np.empty((base.size, 8), dtype=np.int64)
    for (dx, dy, dz), c in _CORNER.items():
        corners[:, c] = (base + (dx * (ny + 1) + dy) * (nz + 1) + dz).ravel()
    return points, corners


def _compact(points: np.ndarray, tets: np.ndarray):
    used = np.unique(tets)
    remap = np.full(points.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return points[used], remap[tets]


def box(size=(1.0, 1.0, 1.0), cells=(4, 4, 4), origin=(0.0, 0.0, 0.0), source: str | None = None) -> TetMesh:
    """A box ``[origin, origin + size]`` of ``nx*ny*nz`` hex cells, 6 tets each.

    >>> box((2.0, 0.2, 0.2), (40, 4, 4)).n_tets
    3840
    """
    size = np.asarray(size, dtype=np.float64)
    cells = tuple(int(c) for c in cells)
    if size.shape != (3,) or np.any(~np.isfinite(size)) or np.any(size <= 0):
        raise MeshError(f"procedural:box: size must be three positive lengths, found {size.tolist()}")
    if len(cells) != 3 or min(cells) < 1:
        raise MeshError(f"procedural:box: cells must be three integers >= 1, found {list(cells)}")
    points, corners = _grid(np.asarray(origin, dtype=np.float64), cells, size / np.asarray(cells))
    tets = corners[:, KUHN].reshape(-1, 4)
    return TetMesh(points, orient(points, tets), source=source or "procedural:box")


def beam(size=(2.0, 0.2, 0.2), cells=(40, 4, 4)) -> TetMesh:
    """The benchmark beam (Zhang 5.3.1 proportions): 2 m x 0.2 m x 0.2 m, x along its length."""
    return box(size, cells, source="procedural:beam")


def cube(side: float = 2.0, n_cells: int = 8) -> TetMesh:
    """A cube ``[0, side]^3`` with ``n_cells`` cells per edge."""
    return box((side, side, side), (n_cells,) * 3, source="procedural:cube")


def _gradient(sdf, p: np.ndarray, eps: float) -> np.ndarray:
    g = np.empty_like(p)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        g[:, a] = (sdf(p + d) - sdf(p - d)) / (2.0 * eps)
    return g


def from_sdf(sdf, bounds_lo, bounds_hi, h: float, source: str = "procedural:sdf", snap: bool = True) -> TetMesh:
    """Tet mesh of ``{p : sdf(p) < 0}`` (``sdf`` maps (k,3) points to (k,) distances, negative inside).

    Grid cells of size ``h`` are split into 6 tets; tets whose centroid lies inside are kept. Boundary
    vertices are then moved onto the zero level set along the SDF gradient (``p - sdf(p) grad``),
    in up to four halving attempts per vertex so that no incident tet falls below 10 % of its grid
    volume (no inversion, no flattening).
    """
    lo = np.asarray(bounds_lo, dtype=np.float64) - h
    hi = np.asarray(bounds_hi, dtype=np.float64) + h
    if not np.isfinite(h) or h <= 0:
        raise MeshError(f"{source}: cell size h must be positive, found {h}")
    cells = np.maximum(1, np.ceil((hi - lo) / h).astype(int))
    if np.prod(cells.astype(float)) * 6 > 3e6:
        raise MeshError(f"{source}: cell size {h} m gives {int(np.prod(cells.astype(float)) * 6)} tets; at most 3e6")
    points, corners = _grid(lo, cells, np.full(3, h))
    cell_tets = corners[:, KUHN]  # (cells, 6, 4)
    keep = (sdf(points[cell_tets.reshape(-1, 4)].mean(axis=1)) < 0.0).reshape(-1, 6)
    keep = _make_manifold(cell_tets, keep, corners)
    tets = cell_tets[keep]
    if tets.size == 0:
        raise MeshError(f"{source}: the shape is empty at cell size {h} m; use a smaller cell size")
    points, tets = _compact(points, tets)
    tets = orient(points, tets)
    if snap:
        points = _snap_boundary(points, tets, sdf, h)
    return TetMesh(points, tets, source=source)


def _nonmanifold_edges(tets: np.ndarray) -> np.ndarray:
    """Boundary edges shared by other than two boundary faces (two parts touching along an edge)."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bf = faces[counts[inverse.ravel()] == 1]
    edges = np.sort(np.concatenate([bf[:, [0, 1]], bf[:, [1, 2]], bf[:, [2, 0]]]), axis=1)
    uniq, ecount = np.unique(edges, axis=0, return_counts=True)
    return uniq[ecount != 2]


def _make_manifold(cell_tets, keep, corners, rounds: int = 8):
    """Fill every grid cell around a non-manifold boundary edge until the boundary is a closed
    2-manifold (centroid selection can leave parts touching along an edge only)."""
    for _ in range(rounds):
        bad = _nonmanifold_edges(cell_tets[keep])
        if bad.size == 0:
            break
        for a, b in bad:
            cells = np.flatnonzero((corners == a).any(axis=1) & (corners == b).any(axis=1))
            keep[cells] = True
    return keep


def boundary_nodes(tets: np.ndarray, n: int) -> np.ndarray:
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    mask = np.zeros(n, dtype=bool)
    mask[faces[counts[inverse.ravel()] == 1].ravel()] = True
    return np.flatnonzero(mask)


def _snap_boundary(points, tets, sdf, h):
    nodes = boundary_nodes(tets, points.shape[0])
    rest_volume = signed_volumes(points, tets)
    g = _gradient(sdf, points[nodes], 1e-4 * h)
    g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
    move = -sdf(points[nodes])[:, None] * g
    move_len = np.linalg.norm(move, axis=1)
    move[move_len > h] *= (h / move_len[move_len > h])[:, None]
    snapped = points.copy()
    factor = np.ones(nodes.size)
    for _ in range(5):
        snapped[nodes] = points[nodes] + factor[:, None] * move
        bad_tets = signed_volumes(snapped, tets) < 0.1 * rest_volume
        if not bad_tets.any():
            break
        bad_nodes = np.zeros(points.shape[0], dtype=bool)
        bad_nodes[tets[bad_tets].ravel()] = True
        factor[bad_nodes[nodes]] *= 0.5
    else:
        bad_nodes = np.zeros(points.shape[0], dtype=bool)
        bad_nodes[tets[signed_volumes(snapped, tets) < 0.1 * rest_volume].ravel()] = True
        snapped[bad_nodes] = points[bad_nodes]
    return snapped


def _ellipsoid(p, centre, radii):
    """Approximate SDF of an ellipsoid (exact on the axes; scaled by the smallest radius)."""
    q = (p - np.asarray(centre)) / np.asarray(radii)
    return (np.linalg.norm(q, axis=1) - 1.0) * min(radii)


def _smooth_union(a, b, k):
    """Polynomial smooth minimum (Quilez): blends two SDFs over a width ``k``."""
    hmix = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - hmix) + a * hmix - k * hmix * (1 - hmix)


def cylinder(length: float = 2.0, radius: float = 0.5, h: float | None = None) -> TetMesh:
    """A solid cylinder along z, base at ``z = 0`` centred on the axis (Zhang §5.3.2: 2 m x 0.5 m)."""
    if not (np.isfinite(length) and np.isfinite(radius)) or length <= 0 or radius <= 0:
        raise MeshError(f"procedural:cylinder: length and radius must be positive, found {length}, {radius}")
    h = radius / 4.0 if h is None else h

    def sdf(p):
        radial = np.hypot(p[:, 0], p[:, 1]) - radius
        axial = np.maximum(-p[:, 2], p[:, 2] - length)
        return np.maximum(radial, axial)

    return from_sdf(sdf, (-radius, -radius, 0.0), (radius, radius, length), h, source="procedural:cylinder")


def slab(size=(0.2, 0.2, 0.03), h: float | None = None) -> TetMesh:
    """A flat tissue slab ``[0, size]``, bottom at z = 0 (a box with cells of about ``h``)."""
    size = np.asarray(size, dtype=np.float64)
    h = float(size.min()) / 3.0 if h is None else h
    if not np.isfinite(h) or h <= 0:
        raise MeshError(f"procedural:slab: cell size must be positive, found {h}")
    cells = np.maximum(1, np.round(size / h)).astype(int)
    return box(size, cells, source="procedural:slab")


def _smooth_max(a, b, k):
    """Smooth maximum (a rounded intersection of width ``k``), the mirror of :func:`_smooth_union`."""
    return -_smooth_union(-a, -b, k)


def _smooth_subtract(a, b, k):
    """``a`` with ``b`` carved out, rounded over a width ``k`` (the mirror of :func:`_smooth_union`)."""
    return _smooth_max(a, -b, k)


def liver_sdf(scale: float):
    """A liver seen from the front (-y), +z up, flat posterior-inferior base on z = 0 with a rounded rim: a thick
    right lobe (+x) with a domed upper face, a thinner left lobe tapering to the left, joined smoothly; the upper
    face slopes down to a thin anterior-inferior edge, notched between the lobes (the ligamentum teres, x = -0.2 s)."""
    s = scale

    def sdf(p):
        right = _ellipsoid(p, (0.3 * s, 0.05 * s, 0.3 * s), (0.7 * s, 0.55 * s, 0.4 * s))
        left = _ellipsoid(p, (-0.5 * s, 0.1 * s, 0.18 * s), (0.6 * s, 0.38 * s, 0.2 * s))
        lobes = _smooth_union(right, left, 0.15 * s)
        # a plane rising from z = 0.06 s at y = -0.5 s with slope 0.9 (42 degrees): the thin front edge
        slope = ((p[:, 2] - 0.06 * s) - 0.9 * (p[:, 1] + 0.5 * s)) / np.hypot(1.0, 0.9)
        liver = _smooth_max(lobes, slope, 0.2 * s)
        notch = np.hypot(p[:, 0] + 0.18 * s, p[:, 1] + 0.42 * s) - 0.18 * s  # a vertical cylinder at the front
        return _smooth_max(_smooth_subtract(liver, notch, 0.1 * s), -p[:, 2], 0.1 * s)

    return sdf, (-1.1 * s, -0.55 * s, 0.0), (1.0 * s, 0.6 * s, 0.7 * s)


def kidney_sdf(scale: float):
    """A bean: an ellipsoid with a smooth indentation (the hilum) on its +y side, resting on z = 0 (rounded rim)."""
    s = scale

    def sdf(p):
        body = _ellipsoid(p, (0.0, 0.0, 0.2 * s), (0.5 * s, 0.3 * s, 0.24 * s))
        hilum = np.linalg.norm(p - np.array([0.0, 0.38 * s, 0.2 * s]), axis=1) - 0.2 * s
        k = 0.15 * s
        hmix = np.clip(0.5 - 0.5 * (body + hilum) / k, 0.0, 1.0)
        carved = body * (1 - hmix) + (-hilum) * hmix + k * hmix * (1 - hmix)  # smooth subtraction
        return _smooth_max(carved, -p[:, 2], 0.1 * s)

    return sdf, (-0.5 * s, -0.3 * s, 0.0), (0.5 * s, 0.3 * s, 0.44 * s)


def _round_cone(p, a, b, ra, rb):
    """Exact SDF of the round cone between a sphere of radius ``ra`` at ``a`` and one of ``rb`` at ``b``, with the
    cone tangent to both (Quilez, "distance functions": sdRoundCone)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ba = b - a
    l2 = float(ba @ ba)
    rr = ra - rb
    a2 = l2 - rr * rr
    pa = p - a
    y = pa @ ba
    z = y - l2
    x2 = np.einsum("ij,ij->i", pa * l2 - y[:, None] * ba, pa * l2 - y[:, None] * ba)
    y2, z2 = y * y * l2, z * z * l2
    k = np.sign(rr) * rr * rr * x2
    side = (np.sqrt(x2 * a2 / l2) + y * rr) / l2 - ra  # distance to the cone's side
    at_b = np.sqrt(x2 + z2) / l2 - rb
    at_a = np.sqrt(x2 + y2) / l2 - ra
    return np.where(np.sign(z) * a2 * z2 > k, at_b, np.where(np.sign(y) * a2 * y2 < k, at_a, side))


def gallbladder_sdf(scale: float):
    """A gallbladder in the liver's frame (front -y, right lobe +x, +z up) resting on z = 0: a pear-shaped sac whose
    round fundus (radius 0.42 scale) points forward and to the right, past the liver's inferior edge, tapering
    through the body to the neck (radius 0.2 scale) at the back left, which bends up and further left towards the
    porta hepatis (Hartmann's pouch, radius 0.12 scale), the long axis 30 degrees off y as in the fossa; flattened
    to 3/4 of its width in height, as a sac lying in the liver's fossa is. About ``1.7 scale`` long; every curvature
    radius is at least 0.1 scale (see ``organ_render_pitch``)."""
    s = scale
    zc, squash = 0.29 * s, 0.75

    def sdf(p):
        q = p.copy()
        q[:, 2] = zc + (p[:, 2] - zc) / squash  # flattened in z: distances shrink by at most ``squash``
        fundus_body = _round_cone(q, (0.23 * s, -0.42 * s, zc), (-0.17 * s, 0.27 * s, zc), 0.42 * s, 0.2 * s)
        neck = _round_cone(q, (-0.17 * s, 0.27 * s, zc), (-0.47 * s, 0.52 * s, zc + 0.15 * s), 0.2 * s, 0.12 * s)
        sac = _smooth_union(fundus_body, neck, 0.1 * s) * squash
        return _smooth_max(sac, -p[:, 2], 0.1 * s)

    return sdf, (-0.65 * s, -0.95 * s, 0.0), (0.7 * s, 0.7 * s, 0.65 * s)


def liver(scale: float = 0.15, h: float | None = None) -> TetMesh:
    """An organ-like liver lobe pair of about ``2 scale`` x ``1.1 scale`` x ``0.7 scale`` [m]."""
    sdf, lo, hi = liver_sdf(scale)
    return from_sdf(sdf, lo, hi, scale / 6.0 if h is None else h, source="procedural:liver")


def kidney(scale: float = 0.11, h: float | None = None) -> TetMesh:
    """A kidney-like bean of about ``scale`` x ``0.6 scale`` x ``0.44 scale`` [m]."""
    sdf, lo, hi = kidney_sdf(scale)
    return from_sdf(sdf, lo, hi, scale / 8.0 if h is None else h, source="procedural:kidney")


def gallbladder(scale: float = 0.05, h: float | None = None) -> TetMesh:
    """A pear-shaped gallbladder about ``1.7 scale`` long, ``0.85 scale`` wide and ``0.6 scale`` high [m]."""
    sdf, lo, hi = gallbladder_sdf(scale)
    return from_sdf(sdf, lo, hi, scale / 6.0 if h is None else h, source="procedural:gallbladder")


SHAPES = {"box": box, "beam": beam, "cube": cube, "cylinder": cylinder, "slab": slab, "liver": liver,
          "kidney": kidney, "gallbladder": gallbladder}


def make(shape: str, **params) -> TetMesh:
    """Build a procedural shape by name (see ``SHAPES``); ``MeshError`` for unknown shapes or parameters."""
    if shape not in SHAPES:
        raise MeshError(f"procedural:{shape}: unknown shape; expected one of {', '.join(SHAPES)}")
    try:
        return SHAPES[shape](**params)
    except TypeError as e:
        raise MeshError(f"procedural:{shape}: bad parameters {sorted(params)}: {e}") from None
