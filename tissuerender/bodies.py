"""From scene objects to simulation models and render surfaces.

A *body* is a tet mesh (procedural or from a file) with a :class:`sim.model.Model` built from its
material preset, fixed regions, prescribed displacements (either held in every component or in some only:
``tissuerender.scene.bc_schema``) and surface tractions, and a render surface
embedded in its tets by barycentric coordinates so it follows the deformation. A *static surface* is
a triangle mesh loaded from a file and rendered with its own vertex normals.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import materials
from sim.errors import MeshError
from sim.mesh import io, procedural, select
from sim.mesh.embed import deform, embed_points
from sim.mesh.surface import boundary_surface, subdivide, taubin_smooth
from sim.mesh.types import Embedding, SurfaceMesh, TetMesh
from sim.model import Model, PrescribedDisplacement
from sim.painting import Stroke, apply_painting
from tissuerender.errors import SceneError
from tissuerender.scene import Scene
from tissuerender.scene.schema import ObjectSpec, Region
from tissuerender.scene.shapes import DEFAULT_SCALE, ORGAN_SHAPES, procedural_extent


def build_tet_mesh(obj: ObjectSpec, scene: Scene) -> TetMesh:
    """The body's rest tet mesh, translated to ``obj.position``."""
    if obj.mesh is not None and Path(obj.mesh).suffix.lower() in io.SURFACE_SUFFIXES:
        # A closed surface: voxelised into tets (trimesh) with the boundary snapped back onto it.
        surface = io.read_surface(scene.resolve(obj.mesh))
        extent = surface.points.max(axis=0) - surface.points.min(axis=0)
        h = obj.cell_size if obj.cell_size is not None else float(extent.min()) / 8.0
        mesh = io.tetrahedralize_surface(surface, h)
    elif obj.mesh is not None:
        mesh = io.read_tet_mesh(scene.resolve(obj.mesh))
    else:
        extent, h = procedural_extent(obj)
        cells = tuple(max(1, math.ceil(e / h)) for e in extent)
        if obj.shape in ("box", "beam"):
            mesh = procedural.box(size=extent, cells=cells)
        elif obj.shape == "cube":
            mesh = procedural.cube(side=extent[0], n_cells=cells[0])
        elif obj.shape == "cylinder":
            mesh = procedural.cylinder(length=extent[2], radius=extent[0] / 2.0, h=h)
        elif obj.shape == "slab":
            mesh = procedural.slab(size=extent, h=h)
        else:
            scale = obj.scale if obj.scale is not None else DEFAULT_SCALE[obj.shape]
            mesh = getattr(procedural, obj.shape)(scale=scale, h=h)
    return TetMesh(mesh.points + np.asarray(obj.position), mesh.tets, source=mesh.source)


def region_nodes(points: np.ndarray, region: Region) -> np.ndarray:
    """Indices of the nodes in a region: a bounding-box side (``x_min`` ...) or an explicit box."""
    if region.side is not None:
        axis = "xyz".index(region.side[0])
        return select.nodes_on_side(points, axis, region.side[2:])
    return select.nodes_in_box(points, np.asarray(region.box_min), np.asarray(region.box_max))


def _traction_forces(mesh: TetMesh, surface: SurfaceMesh, nodes: np.ndarray, traction) -> np.ndarray:
    """Nodal forces [N] of a constant traction [Pa] over boundary faces whose three nodes are in ``nodes``."""
    in_region = np.zeros(mesh.n_points, dtype=bool)
    in_region[nodes] = True
    tri_nodes = surface.vertex_map[surface.triangles]  # (k, 3) tet-mesh node ids
    faces = tri_nodes[in_region[tri_nodes].all(axis=1)]
    p = mesh.points
    area = 0.5 * np.linalg.norm(np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]]), axis=1)
    f = np.zeros((mesh.n_points, 3))
    share = area[:, None] * np.asarray(traction, dtype=np.float64)[None, :] / 3.0
    for k in range(3):
        np.add.at(f, faces[:, k], share)
    return f


def build_model(obj: ObjectSpec, index: int, mesh: TetMesh, scene: Scene, boundary: SurfaceMesh) -> Model:
    """A :class:`Model` from the body's material preset (with overrides) and boundary conditions."""
    mech = materials.get_preset(obj.material).mechanics
    over = obj.override
    E = over.E if over and over.E is not None else mech.E
    nu = over.nu if over and over.nu is not None else mech.nu
    density = over.density if over and over.density is not None else mech.density
    params: dict = {}
    if mech.prony:
        params["prony"] = tuple(mech.prony)
    model = Model.from_mesh(
        mesh, E=E, nu=nu, density=density, constitutive=mech.constitutive, fibre=mech.fibre,
        material_params=params, gravity=np.asarray(scene.simulation.gravity, dtype=np.float64),
    )
    key = f"objects[{index}]"
    if obj.paint:
        try:
            apply_painting(model, [Stroke(tuple(p.centre), p.radius, p.amount) for p in obj.paint])
        except ValueError as e:
            raise SceneError(scene.path, f"{key}.paint", f"expected strokes that keep every stiffness positive: {e}") from None
    for j, region in enumerate(obj.fixed):
        nodes = region_nodes(mesh.points, region)
        if nodes.size == 0:
            raise SceneError(scene.path, f"{key}.fixed[{j}]", "expected the region to contain nodes, found none")
        held = region.held_directions()
        if held is None:
            model.fixed[nodes] = True
        else:  # held in some components only: a zero displacement along them (sim.model.PartialTargets)
            model.prescribed.append(PrescribedDisplacement(nodes, np.zeros(3), held=held))
    for j, pres in enumerate(obj.prescribed):
        nodes = region_nodes(mesh.points, pres)
        if nodes.size == 0:
            raise SceneError(scene.path, f"{key}.prescribed[{j}]", "expected the region to contain nodes, found none")
        model.prescribed.append(PrescribedDisplacement(nodes, np.asarray(pres.displacement), pres.t_start, pres.t_end,
                                                       pres.held_directions()))
    if obj.tractions:
        force = np.zeros((mesh.n_points, 3))
        for j, tr in enumerate(obj.tractions):
            f = _traction_forces(mesh, boundary, region_nodes(mesh.points, tr), tr.traction)
            if not np.any(f):
                raise SceneError(scene.path, f"{key}.tractions[{j}]",
                                 "expected the region to contain boundary faces, found none")
            force += f
        model.external_force = force
    return model


@dataclass
class Body:
    """A simulated object: its model and the render surface embedded in its tets."""

    spec: ObjectSpec
    mesh: TetMesh
    model: Model
    surface: SurfaceMesh
    embedding: Embedding

    def surface_points(self, x: np.ndarray) -> np.ndarray:
        return deform(self.embedding, self.mesh.tets, x)


@dataclass
class StaticSurface:
    spec: ObjectSpec
    surface: SurfaceMesh


def build_body(obj: ObjectSpec, index: int, scene: Scene) -> Body:
    try:
        mesh = build_tet_mesh(obj, scene)
    except MeshError as e:
        raise SceneError(scene.path, f"objects[{index}]", str(e)) from None
    boundary = boundary_surface(mesh)
    model = build_model(obj, index, mesh, scene, boundary)
    surface = boundary
    if obj.shape in ORGAN_SHAPES:
        # Organ shapes come from a voxel grid: smooth the staircase away at the tet-mesh scale first,
        # then again lightly after subdivision; the result is embedded in the tets.
        surface = taubin_smooth(surface, iterations=20)
    if obj.render_subdivision:
        surface = subdivide(surface, obj.render_subdivision)
        if obj.shape in ORGAN_SHAPES:
            surface = taubin_smooth(surface, iterations=4)
    embedding = embed_points(mesh, surface.points)
    return Body(obj, mesh, model, surface, embedding)


def build_static_surface(obj: ObjectSpec, index: int, scene: Scene) -> StaticSurface:
    try:
        surface = io.read_surface(scene.resolve(obj.mesh))
    except MeshError as e:
        raise SceneError(scene.path, f"objects[{index}].mesh", str(e)) from None
    scale = obj.scale if obj.scale is not None else 1.0
    surface = SurfaceMesh(surface.points * scale + np.asarray(obj.position), surface.triangles,
                          surface.normals, surface.uv, source=surface.source)
    return StaticSurface(obj, surface)
