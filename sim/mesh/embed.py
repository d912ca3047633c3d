"""Points embedded in a tet mesh by barycentric coordinates (a finer render surface following the
deformation of the simulation mesh)."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from sim.mesh.types import Embedding, TetMesh


def barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (p, 4) of points (p, 3) in tets given by their corners (p, 4, 3)."""
    T = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 0]], axis=2)
    rhs = (points - corners[:, 0])[..., None]
    lam = np.linalg.solve(T, rhs)[..., 0]
    return np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)


def embed_points(mesh: TetMesh, points: np.ndarray, candidates: int = 16) -> Embedding:
    """Containing tet and barycentric weights of each point.

    The ``candidates`` tets with the nearest centroids are tested; the one whose smallest barycentric
    coordinate is largest wins. Points slightly outside the mesh (a smoothed render surface) keep that
    tet's barycentrics, some negative: the point moves with the tet's affine map.
    ``extra["outside_distance"]`` records each point's distance to the tet [m] (0 inside).
    """
    points = np.asarray(points, dtype=np.float64)
    centroids = mesh.points[mesh.tets].mean(axis=1)
    k = min(candidates, mesh.n_tets)
    _, cand = cKDTree(centroids).query(points, k=k)
    cand = cand.reshape(points.shape[0], k)
    best_tet = np.empty(points.shape[0], dtype=np.int32)
    best_bary = np.empty((points.shape[0], 4))
    best_score = np.full(points.shape[0], -np.inf)
    for j in range(k):
        tet = cand[:, j]
        bary = barycentric(points, mesh.points[mesh.tets[tet]])
        score = bary.min(axis=1)
        better = score > best_score
        best_tet[better], best_bary[better], best_score[better] = tet[better], bary[better], score[better]
    # Points outside every candidate keep the (slightly negative) barycentrics of the best tet: an
    # affine extrapolation that still follows the deformation. Their distance to the mesh is recorded.
    outside = best_score < -1e-9
    clamped = np.clip(best_bary, 0.0, None)
    clamped /= clamped.sum(axis=1, keepdims=True)
    emb = Embedding(best_tet, best_bary)
    nearest = np.einsum("pk,pkd->pd", clamped, mesh.points[mesh.tets[best_tet]])
    emb.extra["outside_distance"] = np.where(outside, np.linalg.norm(nearest - points, axis=1), 0.0)
    return emb


def deform(embedding: Embedding, tets: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Embedded point positions for node positions ``x``: ``sum_k bary_k x[tet_k]``."""
    corners = x[tets[embedding.tet_index]]  # (p, 4, 3)
    return np.einsum("pk,pkd->pd", embedding.bary, corners)


def check_embedding(embedding: Embedding, mesh: TetMesh, surface) -> None:
    """Refuse a render surface that leaves the tets by more than the mean tet edge.

    Surface points outside the tet mesh (a smooth surface bulges past the chords of the snapped tet boundary by
    about edge^2 / (8 radius)) are not moved: they keep the affine extrapolation of their nearest tet (negative
    barycentrics), so the rest surface is exactly the given one and follows the deformation of the tets next to
    it. Farther out, the extrapolation would amplify the tet's deformation; that means a part of the surface
    thinner than the cells got no tets, and a smaller cell size is needed.
    """
    edges = mesh.points[mesh.tets[:, [1, 2, 3]]] - mesh.points[mesh.tets[:, [0]]]
    limit = float(np.linalg.norm(edges, axis=2).mean())
    distance = embedding.extra["outside_distance"]
    worst = int(np.argmax(distance))
    if distance[worst] > limit:
        from sim.errors import MeshError

        raise MeshError(f"{surface.source}: the render surface leaves the tet mesh by {distance[worst]:.3g} m at "
                        f"{np.round(surface.points[worst], 4).tolist()} (at most the mean tet edge, {limit:.3g} m); "
                        f"a part thinner than the cells got no tets: use a smaller cell_size")
