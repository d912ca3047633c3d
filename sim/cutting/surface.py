"""The render surfaces of a cut body: the boundary of its remaining tets, in two parts drawn with two materials.

Once a body has been cut, its render surface is the boundary of the tets that remain (``CutTopology.surface``):
the faces on the original boundary (drawn with the body's material) and the faces the cut exposed (drawn with its
``cut_material``). Each part has its own vertices (the tet nodes it uses), so vertex normals do not smooth across
the crease where a cut face meets the original surface; together the two parts are closed and edge-manifold. Their
vertices are tet nodes, embedded with one barycentric weight 1 at that node, so ``sim.mesh.embed.deform`` gives
the nodes' positions exactly. UVs are box-projected from the rest positions, in metres (``box_uv``), so a textured
preset keeps its scale on the cut.
"""
from __future__ import annotations

import numpy as np

from sim.cutting.topology import CutTopology
from sim.mesh.surface import box_uv, vertex_normals
from sim.mesh.types import Embedding, SurfaceMesh, TetMesh


def node_surface(faces: np.ndarray, X: np.ndarray, source: str) -> SurfaceMesh:
    """Triangles ``faces`` (k, 3) of tet-node ids as a surface of their own vertices at the rest positions ``X``,
    with ``vertex_map`` back to the nodes, vertex normals and box-projected UVs."""
    used, local = np.unique(faces, return_inverse=True)
    triangles = local.reshape(-1, 3)
    points = X[used]
    normals = vertex_normals(points, triangles)
    return SurfaceMesh(points, triangles, normals=normals, uv=box_uv(points, normals), source=source,
                       vertex_map=used.astype(np.int64))


def node_embedding(nodes: np.ndarray, tets: np.ndarray) -> Embedding:
    """Each of ``nodes`` embedded in the first of ``tets`` (m, 4) that holds it, weight 1 at its corner."""
    held, first = np.unique(np.asarray(tets).ravel(), return_index=True)  # first position of each node
    position = first[np.searchsorted(held, nodes)]
    bary = np.zeros((nodes.size, 4))
    bary[np.arange(nodes.size), position % 4] = 1.0
    return Embedding((position // 4).astype(np.int32), bary, extra={"outside_distance": np.zeros(nodes.size)})


def cut_surfaces(topology: CutTopology, X: np.ndarray, source: str) -> tuple[TetMesh, SurfaceMesh, Embedding, SurfaceMesh]:
    """The remaining tets as a mesh, the original part of their boundary with its embedding, and the cut faces
    (module docstring)."""
    original, cut = topology.surface()
    mesh = TetMesh(X, topology.tets[topology.alive], source=source)
    surface = node_surface(original, X, source)
    return mesh, surface, node_embedding(surface.vertex_map, mesh.tets), node_surface(cut, X, f"{source} (cut)")
