"""Boundary surfaces of tet meshes, vertex normals, UVs and subdivision of render surfaces."""
from __future__ import annotations

import numpy as np

from sim.mesh.types import SurfaceMesh, TetMesh

# Faces of a positively oriented tet (0,1,2,3), ordered counter-clockwise seen from outside.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """Faces used by exactly one tet, outward oriented, as tet-mesh node ids (k, 3)."""
    faces = tets[:, TET_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (the cross products summed per vertex, then normalised)."""
    p = points[triangles]
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # length = 2 * area
    n = np.zeros_like(points)
    for k in range(3):
        np.add.at(n, triangles[:, k], face_n)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0.0, length, 1.0)


def box_uv(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """UVs in metres by box projection: each vertex is projected along the axis its normal is closest
    to (top faces get (x, y), side faces (y, z) or (x, z)), so procedural textures keep their physical
    size on every face without the poles of a cylindrical unwrap. Seams sit where the dominant axis
    changes."""
    axis = np.argmax(np.abs(normals), axis=1)
    uv = np.empty((points.shape[0], 2))
    for a, (i, j) in enumerate(((1, 2), (0, 2), (0, 1))):
        sel = axis == a
        uv[sel] = points[sel][:, [i, j]]
    return uv


def boundary_surface(mesh: TetMesh) -> SurfaceMesh:
    """The closed outer surface of a tet mesh, with normals, box-projected UVs in metres (``box_uv``)
    and ``vertex_map`` into the mesh nodes."""
    faces = boundary_faces(mesh.tets)
    used, local = np.unique(faces, return_inverse=True)
    triangles = local.reshape(-1, 3)
    points = mesh.points[used]
    normals = vertex_normals(points, triangles)
    return SurfaceMesh(points, triangles, normals=normals, uv=box_uv(points, normals),
                       source=mesh.source, vertex_map=used.astype(np.int64))


def weld(surface: SurfaceMesh) -> SurfaceMesh:
    """Vertices with equal position (and equal normal and UV, where given) merged into one, so a triangle
    soup (an STL file has no shared vertices) becomes a connected surface; triangles keep their order."""
    key = [surface.points] + [a for a in (surface.normals, surface.uv) if a is not None]
    _, first, inverse = np.unique(np.concatenate(key, axis=1), axis=0, return_index=True, return_inverse=True)
    if first.size == surface.points.shape[0]:
        return surface
    order = np.argsort(first)  # unique rows in the file order of their first occurrence
    rank = np.empty(first.size, dtype=np.int64)
    rank[order] = np.arange(first.size)
    keep = first[order]
    triangles = rank[inverse.ravel()][surface.triangles]
    pick = lambda a: None if a is None else a[keep]  # noqa: E731
    return SurfaceMesh(surface.points[keep], triangles, pick(surface.normals), pick(surface.uv), source=surface.source)


def orient_outward(surface: SurfaceMesh) -> SurfaceMesh:
    """The surface with every triangle's winding reversed when the enclosed signed volume is negative (the
    file listed its triangles clockwise seen from outside), so geometric normals point out."""
    p = surface.points[surface.triangles]
    if np.einsum("ij,ij->", np.cross(p[:, 0], p[:, 1]), p[:, 2]) >= 0.0:
        return surface
    return SurfaceMesh(surface.points, surface.triangles[:, [0, 2, 1]], surface.normals, surface.uv,
                       source=surface.source)


def subdivide(surface: SurfaceMesh, levels: int = 1) -> SurfaceMesh:
    """Midpoint 4-to-1 subdivision, ``levels`` times (positions, normals and UVs interpolated linearly).

    The finer surface is embedded in the tets by the caller; ``vertex_map`` is dropped.
    """
    points, tris = surface.points, surface.triangles.astype(np.int64)
    normals, uv = surface.normals, surface.uv
    for _ in range(levels):
        edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
        key = np.sort(edges, axis=1)
        unique, inverse = np.unique(key, axis=0, return_inverse=True)
        inverse = inverse.ravel()
        n = points.shape[0]
        mid = n + inverse.reshape(3, -1).T  # (k, 3): midpoint ids of edges 01, 12, 20
        points = np.concatenate([points, 0.5 * (points[unique[:, 0]] + points[unique[:, 1]])])
        if normals is not None:
            normals = np.concatenate([normals, 0.5 * (normals[unique[:, 0]] + normals[unique[:, 1]])])
            normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        if uv is not None:
            uv = np.concatenate([uv, 0.5 * (uv[unique[:, 0]] + uv[unique[:, 1]])])
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        m01, m12, m20 = mid[:, 0], mid[:, 1], mid[:, 2]
        tris = np.concatenate([np.stack([a, m01, m20], 1), np.stack([m01, b, m12], 1),
                               np.stack([m20, m12, c], 1), np.stack([m01, m12, m20], 1)])
    return SurfaceMesh(points, tris, normals=normals, uv=uv, source=surface.source)


def taubin_smooth(surface: SurfaceMesh, iterations: int = 10, lam: float = 0.5, mu: float = -0.53) -> SurfaceMesh:
    """Taubin lambda/mu smoothing (Taubin 1995): alternating shrink and inflate umbrella steps remove
    the voxel staircase of SDF meshes without shrinking the shape. Normals are recomputed."""
    from scipy.sparse import coo_matrix  # the umbrella operator as a sparse matrix: one product per step

    tris = surface.triangles
    n = surface.points.shape[0]
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    degree = np.bincount(edges.ravel(), minlength=n).astype(np.float64)
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    umbrella = coo_matrix((1.0 / np.maximum(degree, 1.0)[rows], (rows, cols)), shape=(n, n)).tocsr()
    p = surface.points.copy()
    for _ in range(iterations):
        for factor in (lam, mu):
            p = p + factor * (umbrella @ p - p)
    return SurfaceMesh(p, tris, normals=vertex_normals(p, tris), uv=surface.uv, source=surface.source)
