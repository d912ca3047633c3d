"""Organic patterns per tissue: lobules (Voronoi cells on a jittered hexagonal lattice), vessel trees grown by
space colonisation, mucosal folds, fibres; each returns the fields a layer bake needs (``value`` for the
palette and roughness, ``vessels`` mask, ``height``), tiling on the unit square, deterministic from the seed.

- Lobules: liver lobules are hexagonal prisms ~1–2 mm across with a central vein and portal tracts at the
  corners (Ross & Pawlina, Histology, ch. 18); under Glisson's capsule they read as a polygonal mosaic.
  Fat lobules are larger, rounder cells separated by thin septa carrying small vessels. Cell centres sit on
  a jittered hexagonal lattice of ``cells`` x ``cells`` (rows even, so it tiles); F1 / F2 are the distances
  to the nearest and second-nearest centre, ``F2 - F1`` small on the septa (Worley 1996).
- Vessel trees: space colonisation (Runions, Lane & Prusinkiewicz 2007): ``attractors`` seeded points; each
  grows the nearest tree node within ``influence``; a node with attractors grows one step along their mean
  direction; attractors within ``kill`` of a node are removed. Radii follow Murray's law
  ``r_parent^3 = sum r_child^3`` from a leaf radius (Murray 1926), so they decrease along every path from the
  root. Distances are periodic (minimum image) so the trees cross the tile's edges seamlessly.
- Folds: the colon's semilunar folds and the small bowel's plicae circulares as a smooth periodic ridge
  profile along v, its phase bent by a low-frequency field.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from materials.textures import Level, Quadtree, quadtree


@njit(cache=True)
def _voronoi(size, cx, cy, rows, cols, f1, f2, cell_id):
    """F1, F2 and the nearest cell of every pixel of a periodic jittered lattice (``cx``, ``cy``: (rows, cols)
    centres in [0, 1)); each pixel checks the 5 x 5 lattice neighbourhood of its own lattice cell."""
    for j in range(size):
        y = (j + 0.5) / size
        for i in range(size):
            x = (i + 0.5) / size
            r0 = int(y * rows)
            c0 = int(x * cols)
            b1, b2, best = 1e9, 1e9, -1
            for dr in range(-2, 3):
                rr = (r0 + dr) % rows
                for dc in range(-2, 3):
                    cc = (c0 + dc) % cols
                    dx = (x - cx[rr, cc] + 0.5) % 1.0 - 0.5
                    dy = (y - cy[rr, cc] + 0.5) % 1.0 - 0.5
                    d = np.sqrt(dx * dx + dy * dy)
                    if d < b1:
                        b2 = b1
                        b1 = d
                        best = rr * cols + cc
                    elif d < b2:
                        b2 = d
            f1[j, i] = b1
            f2[j, i] = b2
            cell_id[j, i] = best


def lobules(size: int, cells: int, jitter: float, seed: int):
    """(F1, F2, cell id) (size, size) of ``cells`` x ``cells`` hexagonal-ish cells (``cells`` even) in a tile,
    distances in tile widths."""
    if cells < 2 or cells % 2:
        raise ValueError(f"lobules: cells must be an even number >= 2 (the lattice tiles), found {cells}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x10B]))
    rows = cols = cells
    j, i = np.mgrid[0:rows, 0:cols]
    shift = 0.5 * (j % 2)  # odd rows shifted by half a cell: a hexagonal lattice
    cx = ((i + 0.5 + shift + jitter * (rng.random((rows, cols)) - 0.5)) / cols) % 1.0
    cy = ((j + 0.5 + jitter * (rng.random((rows, cols)) - 0.5)) / rows) % 1.0
    f1, f2 = np.empty((size, size)), np.empty((size, size))
    cell_id = np.empty((size, size), np.int64)
    _voronoi(size, cx, cy, rows, cols, f1, f2, cell_id)
    return f1, f2, cell_id


@dataclass(frozen=True)
class VesselTree:
    """Tree nodes ``points`` (n, 2) (unwrapped; the tile is their positions modulo 1), ``parent`` (n,) (-1 at
    each root), ``radius`` (n,) in tile widths and ``generation`` (n,): the number of branch points between
    the node and its root."""

    points: np.ndarray
    parent: np.ndarray
    radius: np.ndarray
    generation: np.ndarray

    def children(self) -> list[list[int]]:
        out: list[list[int]] = [[] for _ in range(len(self.parent))]
        for k, p in enumerate(self.parent):
            if p >= 0:
                out[p].append(k)
        return out

    def branch_points(self) -> int:
        return sum(len(c) >= 2 for c in self.children())


def grow_tree(seed: int, roots: int = 1, attractors: int = 250, step: float = 0.015, influence: float = 0.15,
              kill: float = 0.03, leaf_radius: float = 0.0012, max_nodes: int = 3000) -> VesselTree:
    """A vessel tree by space colonisation (see the module's docstring), deterministic from ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7EE]))
    targets = rng.random((attractors, 2))
    nodes = [p for p in rng.random((roots, 2))]
    parent = [-1] * roots
    alive = np.ones(attractors, bool)
    # each attractor's nearest node and distance, updated with the new nodes only (periodic distances)
    d0 = np.linalg.norm((targets[:, None, :] - np.asarray(nodes)[None] + 0.5) % 1.0 - 0.5, axis=2)
    nearest, best = np.argmin(d0, axis=1), d0.min(axis=1)
    n_children = np.zeros(roots, np.int64)
    while alive.any() and len(nodes) < max_nodes:
        act = np.flatnonzero(alive)
        close = act[best[act] < influence]
        if close.size == 0:  # nothing within reach: the nearest attractor pulls its nearest node
            close = act[[int(np.argmin(best[act]))]]
        pts = np.asarray(nodes)
        first = len(nodes)
        grown = np.unique(nearest[close])
        for node in grown:
            pull = (targets[close[nearest[close] == node]] - pts[node] + 0.5) % 1.0 - 0.5
            direction = (pull / np.maximum(np.linalg.norm(pull, axis=1, keepdims=True), 1e-12)).sum(axis=0)
            length = np.linalg.norm(direction)
            if length < 1e-9:
                continue
            nodes.append(pts[node] + step * direction / length)
            parent.append(int(node))
        if len(nodes) == first:
            break
        # a node grows at most two children (a bifurcation); its attractors then look for other nodes
        children = np.bincount(np.asarray(parent[first:]), minlength=len(nodes))
        n_children[:first] += children[:first]
        n_children = np.concatenate([n_children, np.zeros(len(nodes) - first, np.int64)])
        full = grown[n_children[grown] >= 2]
        if full.size:
            redo = np.flatnonzero(np.isin(nearest, full))
            pts = np.asarray(nodes)
            d = np.linalg.norm((targets[redo][:, None, :] - pts[None] + 0.5) % 1.0 - 0.5, axis=2)
            d[:, np.flatnonzero(n_children >= 2)] = np.inf
            nearest[redo], best[redo] = np.argmin(d, axis=1), d.min(axis=1)
        new = np.asarray(nodes[first:])
        d = np.linalg.norm((targets[:, None, :] - new[None] + 0.5) % 1.0 - 0.5, axis=2)
        k = np.argmin(d, axis=1)
        dmin = d[np.arange(attractors), k]
        better = dmin < best
        nearest[better], best[better] = first + k[better], dmin[better]
        alive &= best >= kill
    parent_arr = np.asarray(parent, np.int64)
    n = parent_arr.size
    has_child = np.zeros(n, bool)
    has_child[parent_arr[parent_arr >= 0]] = True
    cube = np.where(has_child, 0.0, leaf_radius ** 3)
    for k in range(n - 1, -1, -1):  # children always come after their parent: one reverse sweep
        if parent_arr[k] >= 0:
            cube[parent_arr[k]] += cube[k]
    radius = np.cbrt(cube)  # Murray's law
    n_children = np.bincount(parent_arr[parent_arr >= 0], minlength=n)
    generation = np.zeros(n, np.int64)
    for k in range(n):
        p = parent_arr[k]
        if p >= 0:
            generation[k] = generation[p] + (1 if n_children[p] >= 2 else 0)
    return VesselTree(points=np.asarray(nodes), parent=parent_arr, radius=radius, generation=generation)


@njit(cache=True)
def _rasterise_segments(size, ax, ay, bx, by, ra, rb, out):
    """Max-blend capsules (segment a -> b, radius ra ... rb linearly) into ``out`` (size, size), periodic;
    coverage 1 inside the radius, falling to 0 over one pixel (anti-aliased edge)."""
    px = 1.0 / size
    for s in range(ax.shape[0]):
        r = max(ra[s], rb[s]) + px
        x0 = min(ax[s], bx[s]) - r
        x1 = max(ax[s], bx[s]) + r
        y0 = min(ay[s], by[s]) - r
        y1 = max(ay[s], by[s]) + r
        ex, ey = bx[s] - ax[s], by[s] - ay[s]
        e2 = max(ex * ex + ey * ey, 1e-30)
        for jj in range(int(np.floor(y0 * size)), int(np.ceil(y1 * size)) + 1):
            y = (jj + 0.5) / size
            for ii in range(int(np.floor(x0 * size)), int(np.ceil(x1 * size)) + 1):
                x = (ii + 0.5) / size
                t = min(max(((x - ax[s]) * ex + (y - ay[s]) * ey) / e2, 0.0), 1.0)
                dx, dy = x - ax[s] - t * ex, y - ay[s] - t * ey
                d = np.sqrt(dx * dx + dy * dy)
                rad = ra[s] + t * (rb[s] - ra[s])
                c = min(max((rad + 0.5 * px - d) / px, 0.0), 1.0)
                if c > 0.0:
                    j, i = jj % size, ii % size
                    if c > out[j, i]:
                        out[j, i] = c


def rasterise_tree(tree: VesselTree, size: int) -> np.ndarray:
    """(size, size) coverage in [0, 1] of the tree's segments (capsules of the nodes' radii), tiling."""
    child = np.flatnonzero(tree.parent >= 0)
    par = tree.parent[child]
    out = np.zeros((size, size))
    if child.size:
        a, b = tree.points[par], tree.points[child]
        _rasterise_segments(size, a[:, 0].copy(), a[:, 1].copy(), b[:, 0].copy(), b[:, 1].copy(),
                            tree.radius[par].copy(), tree.radius[child].copy(), out)
    return out


def vessel_mask(size: int, seed: int, density: float, roots: int = 2, attractors: int = 300,
                leaf_radius: float = 0.0012) -> np.ndarray:
    """A vessel-tree coverage mask scaled by ``density`` (0: none), clipped to [0, 1]."""
    if density <= 0.0:
        return np.zeros((size, size))
    tree = grow_tree(seed, roots=roots, attractors=attractors, leaf_radius=leaf_radius)
    return np.clip(rasterise_tree(tree, size) * min(density, 1.0), 0.0, 1.0)


FIBRES = Quadtree(levels=tuple(Level(opacity=0.5, aspect=10.0, size_jitter=0.5, rotation=0.3, value=(0.3, 0.9))
                               for _ in range(5)), start_level=2, background=0.55, softness=0.8)
MOTTLE = Quadtree(levels=tuple(Level(opacity=0.45, value=(0.3, 0.8), blend=b)
                               for b in ("normal", "overlay", "normal", "multiply", "screen", "normal")))


@dataclass
class Pattern:
    value: np.ndarray  # (size, size) in [0, 1]: palette position (0 deep colour ... 1 surface colour) and roughness
    vessels: np.ndarray  # (size, size) in [0, 1]
    height: np.ndarray  # (size, size) in [0, 1]


def _smooth(x):
    return x * x * (3.0 - 2.0 * x)


def _liver(size, seed, density):
    f1, f2, _ = lobules(size, 16, 0.5, seed)
    edge = _smooth(np.clip((f2 - f1) * 16 / 0.25, 0.0, 1.0))  # 0 on the septa, 1 inside a lobule
    centre = _smooth(np.clip(f1 * 16 / 0.12, 0.0, 1.0))  # 0 at the central vein
    mottle = quadtree(size, MOTTLE, seed)
    value = np.clip(0.25 + 0.55 * edge * centre + 0.2 * mottle, 0.0, 1.0)
    vessels = vessel_mask(size, seed + 1, density, roots=2, attractors=250)
    return Pattern(value, vessels, 0.6 * value + 0.4 * vessels)


def _fat(size, seed, density):
    f1, f2, _ = lobules(size, 6, 0.8, seed)
    inside = _smooth(np.clip((f2 - f1) * 6 / 0.18, 0.0, 1.0))
    dome = 1.0 - np.clip(f1 * 6 / 0.8, 0.0, 1.0) ** 2  # lobules bulge
    value = np.clip(0.2 + 0.7 * inside + 0.1 * quadtree(size, MOTTLE, seed), 0.0, 1.0)
    vessels = vessel_mask(size, seed + 1, density, roots=3, attractors=200, leaf_radius=0.0008)
    return Pattern(value, vessels * (1.0 - 0.9 * inside), 0.5 * dome * inside + 0.2 * value)  # vessels in the septa


def _fibrous(size, seed, density, vessel_roots=1):
    fibres = quadtree(size, FIBRES, seed)
    vessels = vessel_mask(size, seed + 1, density, roots=vessel_roots, attractors=150, leaf_radius=0.0009)
    return Pattern(np.clip(0.15 + 0.85 * fibres, 0.0, 1.0), vessels, 0.7 * fibres + 0.3 * vessels)


def _folds(size, seed, density, count):
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    bend = quadtree(size, Quadtree(levels=tuple(Level(opacity=0.5, value=(0.0, 1.0)) for _ in range(3)),
                                   start_level=1), seed + 7)
    phase = count * (y + 0.08 * (bend - 0.5) + 0.03 * np.sin(2 * np.pi * x))
    ridge = 0.5 + 0.5 * np.cos(2 * np.pi * phase)
    ridge = ridge ** 3  # narrow crests, broad valleys
    mottle = quadtree(size, MOTTLE, seed)
    vessels = vessel_mask(size, seed + 1, density, roots=2, attractors=300)
    value = np.clip(0.3 + 0.4 * mottle + 0.3 * ridge, 0.0, 1.0)
    return Pattern(value, vessels * (1.0 - 0.6 * ridge), np.clip(0.7 * ridge + 0.3 * mottle, 0.0, 1.0))


def _smooth_serosa(size, seed, density):
    mottle = quadtree(size, MOTTLE, seed)
    vessels = vessel_mask(size, seed + 1, density, roots=2, attractors=220)
    return Pattern(np.clip(0.2 + 0.8 * mottle, 0.0, 1.0), vessels, 0.5 * mottle + 0.5 * vessels)


def _vessel_wall(size, seed, density):
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    stripes = 0.5 + 0.5 * np.sin(2 * np.pi * (12 * x + 0.1 * quadtree(size, MOTTLE, seed)))
    vessels = vessel_mask(size, seed + 1, density, roots=1, attractors=120, leaf_radius=0.0006)
    return Pattern(np.clip(0.3 + 0.5 * stripes, 0.0, 1.0), vessels, 0.6 * stripes + 0.4 * vessels)


PATTERNS = {
    "liver_lobules": _liver,
    "fat_lobules": _fat,
    "capsule": lambda size, seed, density: _fibrous(size, seed, density, vessel_roots=2),
    "fibres": _fibrous,
    "colon_folds": lambda size, seed, density: _folds(size, seed, density, 3),
    "bowel_folds": lambda size, seed, density: _folds(size, seed, density, 8),
    "serosa": _smooth_serosa,
    "vessel_wall": _vessel_wall,
}


def pattern(name: str, size: int, seed: int, vessel_density: float) -> Pattern:
    """The pattern ``name`` (one of :data:`PATTERNS`) at ``size`` pixels."""
    try:
        make = PATTERNS[name]
    except KeyError:
        raise ValueError(f"unknown texture pattern {name!r}; expected one of {', '.join(PATTERNS)}") from None
    return make(size, seed, vessel_density)
