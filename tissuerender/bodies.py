"""From scene objects to simulation models and render surfaces.

A *body* is a tet mesh (procedural or from a file) with a :class:`sim.model.Model` built from its
material preset, fixed regions, prescribed displacements (either held in every component or in some only:
``tissuerender.scene.bc_schema``) and surface tractions, and a render surface embedded in its tets by
barycentric coordinates so it follows the deformation. The render surface of an organ shape is a smooth
contour of its SDF, that of a closed surface file the file's own triangles (the tets only approximate
them), otherwise the tets' boundary. A *static surface* is
a triangle mesh loaded from a file and rendered with its own vertex normals.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import materials
from sim.errors import MeshError
from sim.mesh import io, procedural, select
from sim.mesh.contour import smooth_surface
from sim.mesh.embed import check_embedding, deform, embed_points
from sim.mesh.surface import boundary_surface, box_uv, orient_outward, subdivide, vertex_normals, weld
from sim.mesh.types import Embedding, SurfaceMesh, TetMesh
from sim.model import Model, PrescribedDisplacement
from sim.painting import Stroke, apply_painting
from tissuerender.errors import SceneError
from tissuerender.scene import Scene
from tissuerender.scene.schema import ObjectSpec, Region
from tissuerender.scene.shapes import DEFAULT_SCALE, ORGAN_SHAPES, organ_render_pitch, procedural_extent


def _scaled(obj: ObjectSpec) -> float:
    return obj.scale if obj.scale is not None else 1.0


def read_mesh_body(obj: ObjectSpec, scene: Scene) -> tuple[TetMesh, SurfaceMesh | None]:
    """A mesh-file body's rest tets and, for a closed surface file, that surface (the render surface), both
    scaled by ``obj.scale`` about the file's origin and then translated to ``obj.position``."""
    path = scene.resolve(obj.mesh)
    offset = np.asarray(obj.position, dtype=np.float64)
    if not io.is_surface_file(path):
        mesh = io.read_tet_mesh(path)
        return TetMesh(mesh.points * _scaled(obj) + offset, mesh.tets, source=mesh.source, repairs=mesh.repairs), None
    surface = orient_outward(weld(io.read_surface(path)))
    surface = SurfaceMesh(surface.points * _scaled(obj) + offset, surface.triangles, surface.normals, surface.uv,
                          source=surface.source)
    # A closed surface: voxelised into tets (trimesh) with the boundary snapped back onto it.
    extent = surface.points.max(axis=0) - surface.points.min(axis=0)
    h = obj.cell_size if obj.cell_size is not None else float(extent.min()) / 8.0
    return io.tetrahedralize_surface(surface, h), surface


def build_tet_mesh(obj: ObjectSpec, scene: Scene) -> TetMesh:
    """The body's rest tet mesh, scaled (mesh files) and translated to ``obj.position``."""
    if obj.mesh is not None:
        return read_mesh_body(obj, scene)[0]
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


def organ_surface(obj: ObjectSpec) -> SurfaceMesh:
    """The smooth render surface of an organ shape: its SDF contoured at ``organ_render_pitch`` and smoothed
    (:func:`sim.mesh.contour.smooth_surface`), translated to ``obj.position``."""
    scale = obj.scale if obj.scale is not None else DEFAULT_SCALE[obj.shape]
    sdf, lo, hi = getattr(procedural, f"{obj.shape}_sdf")(scale)
    surface = smooth_surface(sdf, lo, hi, organ_render_pitch(obj), source=f"procedural:{obj.shape}")
    return SurfaceMesh(surface.points + np.asarray(obj.position), surface.triangles, surface.normals, surface.uv,
                       source=surface.source)


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
    """The body's tets, model and render surface: an organ shape's smooth contour of its SDF, a closed surface
    file's own triangles, or else the tets' boundary; subdivided ``render_subdivision`` times (organs: folded
    into the contour's resolution instead) and embedded in the tets (``check_embedding``)."""
    try:
        if obj.mesh is not None:
            mesh, surface = read_mesh_body(obj, scene)
        else:
            mesh, surface = build_tet_mesh(obj, scene), None
        if obj.shape in ORGAN_SHAPES:
            surface = organ_surface(obj)
    except MeshError as e:
        raise SceneError(scene.path, f"objects[{index}]", str(e)) from None
    boundary = boundary_surface(mesh)
    model = build_model(obj, index, mesh, scene, boundary)
    if surface is None:
        surface = boundary
    elif surface.uv is None or surface.normals is None:
        normals = surface.normals if surface.normals is not None else vertex_normals(surface.points, surface.triangles)
        surface = SurfaceMesh(surface.points, surface.triangles, normals,
                              surface.uv if surface.uv is not None else box_uv(surface.points, normals),
                              source=surface.source)
    if obj.render_subdivision and obj.shape not in ORGAN_SHAPES:
        surface = subdivide(surface, obj.render_subdivision)
    embedding = embed_points(mesh, surface.points)
    try:
        check_embedding(embedding, mesh, surface)
    except MeshError as e:
        raise SceneError(scene.path, f"objects[{index}]", str(e)) from None
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
