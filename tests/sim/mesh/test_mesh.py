"""Meshes: procedural shapes, boundary surfaces, embedding, quality, and file input with clear errors."""
from __future__ import annotations

import meshio
import numpy as np
import pytest

from sim.errors import MeshError
from sim.mesh import embed, io, procedural, quality, select, surface
from sim.mesh.types import TetMesh

SHAPES = {
    "beam": lambda: procedural.beam(),
    "cube": lambda: procedural.cube(2.0, 6),
    "cylinder": lambda: procedural.cylinder(2.0, 0.5, 0.125),
    "slab": lambda: procedural.slab((0.2, 0.2, 0.03), 0.01),
    "liver": lambda: procedural.liver(0.15, 0.02),
    "kidney": lambda: procedural.kidney(0.11, 0.012),
}


@pytest.mark.parametrize("name", SHAPES)
def test_procedural_shapes_have_no_inverted_tets_and_a_closed_outward_surface(name):
    mesh = SHAPES[name]()
    report = quality.quality_report(mesh)
    assert report.inverted == 0 and report.min_volume_ratio > 0.02
    surf = surface.boundary_surface(mesh)
    edges = np.sort(np.concatenate([surf.triangles[:, [0, 1]], surf.triangles[:, [1, 2]],
                                    surf.triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed 2-manifold
    p = surf.points[surf.triangles]
    terms = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))
    enclosed = terms.sum() / 6.0  # divergence theorem
    # signed sums: each side's error <= (count + 10 flops per term) u sum|terms| (Higham 4.2)
    u = 2.0**-53
    bound = (terms.size + 10) * u * np.abs(terms).sum() / 6.0 + (mesh.n_tets + 10) * u * report.total_volume
    assert abs(enclosed - report.total_volume) <= bound


def test_beam_sizes_of_the_throughput_benchmark():
    assert procedural.box((2, 0.2, 0.2), (40, 4, 4)).n_tets == 3840
    assert procedural.box((2, 0.2, 0.2), (80, 8, 8)).n_tets == 30720


def test_cylinder_and_cube_volumes_within_2_percent():
    cyl = procedural.cylinder(2.0, 0.5, 0.125)
    assert quality.quality_report(cyl).total_volume == pytest.approx(np.pi * 0.25 * 2.0, rel=0.02)
    assert quality.quality_report(procedural.cube(2.0, 4)).total_volume == pytest.approx(8.0, rel=0.02)


def test_quality_of_a_regular_tet():
    pts = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    r = quality.quality_report(TetMesh(pts, procedural.orient(pts, np.array([[0, 1, 2, 3]]))))
    # cos from normals (~20 roundings), arccos' slope 1.06 at 1/3, 57.3 deg / rad: 20 u x 61 = 1.4e-13 deg
    assert r.min_dihedral_deg == pytest.approx(np.degrees(np.arccos(1 / 3)), abs=1e-9)
    assert r.max_dihedral_deg == pytest.approx(70.528779, abs=1e-5)  # the literal's six decimals: 5e-7
    assert r.min_volume_ratio == pytest.approx(1.0, abs=1e-12)  # a ratio of two equal ~10-flop volumes: 20 u


def test_embedding_round_trip_rest_and_affine():
    mesh = procedural.liver(0.15, 0.025)
    fine = surface.subdivide(surface.boundary_surface(mesh), 2)
    emb = embed.embed_points(mesh, fine.points)
    # barycentric solve (3 x 3, ~30 roundings, times the tets' condition <= ~1e2) and a 4-term reconstruction of
    # coordinates <= 0.15 m: 34 u x 1e2 x 0.15 = 6e-14 m
    assert np.abs(embed.deform(emb, mesh.tets, mesh.points) - fine.points).max() < 1e-12
    A = np.array([[1.1, 0.2, 0.0], [0.0, 0.9, 0.1], [0.05, 0.0, 1.2]])
    b = np.array([0.3, -0.2, 0.1])
    moved = embed.deform(emb, mesh.tets, mesh.points @ A.T + b)
    assert np.abs(moved - (fine.points @ A.T + b)).max() < 1e-12
    assert np.allclose(emb.bary.sum(axis=1), 1.0) and emb.bary.min() > -1e-9
    assert emb.extra["outside_distance"].max() < 1e-12


def test_subdivision_quadruples_triangles_and_stays_on_the_surface():
    surf = surface.boundary_surface(procedural.cube(1.0, 2))
    fine = surface.subdivide(surf, 1)
    assert fine.triangles.shape[0] == 4 * surf.triangles.shape[0]
    on_face = np.isclose(fine.points, 0.0) | np.isclose(fine.points, 1.0)
    assert np.all(on_face.any(axis=1))


def test_node_selection():
    mesh = procedural.box((1.0, 1.0, 1.0), (2, 2, 2))
    top = select.nodes_on_side(mesh.points, 2, "max")
    assert top.size == 9 and np.allclose(mesh.points[top, 2], 1.0)
    inner = select.nodes_in_box(mesh.points, [0.4, 0.4, 0.4], [0.6, 0.6, 0.6])
    assert inner.size == 1 and np.allclose(mesh.points[inner[0]], 0.5)


def test_tet_mesh_files_round_trip(tmp_path):
    mesh = procedural.cube(1.0, 2)
    for ext in ("vtu", "msh", "vtk", "mesh"):
        path = tmp_path / f"cube.{ext}"
        meshio.write(path, meshio.Mesh(mesh.points, [("tetra", mesh.tets)]), **({"file_format": "gmsh22"} if ext == "msh" else {}))
        back = io.read_tet_mesh(path)
        assert back.n_tets == mesh.n_tets and np.allclose(back.points, mesh.points)


def _write(tmp_path, points, tets, name="bad.vtu"):
    path = tmp_path / name
    meshio.write(path, meshio.Mesh(np.asarray(points, dtype=float), [("tetra", np.asarray(tets))]))
    return path


UNIT = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]


def test_inverted_tets_are_flipped_and_counted(tmp_path):
    mesh = io.read_tet_mesh(_write(tmp_path, UNIT, [[0, 2, 1, 3], [1, 2, 3, 4]]))
    assert mesh.repairs["flipped"] >= 1
    assert quality.quality_report(mesh).inverted == 0


@pytest.mark.parametrize("case,points,tets,needle", [
    ("zero volume", [[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 1], [1, 1, 1]], [[0, 1, 2, 3], [1, 4, 3, 0]], "zero volume"),
    ("nan", [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, float("nan")]], [[0, 1, 2, 3]], "non-finite"),
])
def test_broken_tet_meshes_are_rejected(tmp_path, case, points, tets, needle):
    path = _write(tmp_path, points, tets)
    with pytest.raises(MeshError, match=needle) as info:
        io.read_tet_mesh(path)
    assert "bad.vtu" in str(info.value)


def test_index_out_of_range_is_rejected():
    with pytest.raises(MeshError, match="references node"):
        io.clean_tets(np.array(UNIT, dtype=float), np.array([[0, 1, 2, 9]]), "x.vtu")


@pytest.mark.parametrize("content,needle", [(None, "not found"), (b"", "empty"), (b"\x00\xff\x13garbage" * 50, "cannot read")])
def test_unusable_files_are_rejected_with_the_path(tmp_path, content, needle):
    path = tmp_path / "organ.vtu"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(MeshError, match=needle) as info:
        io.read_tet_mesh(path)
    assert "organ.vtu" in str(info.value)


def test_file_without_tets_is_rejected(tmp_path):
    path = tmp_path / "tri.vtu"
    meshio.write(path, meshio.Mesh(np.eye(3), [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(MeshError, match="no tetrahedra"):
        io.read_tet_mesh(path)


def test_surface_files_keep_their_own_normals(tmp_path):
    obj = tmp_path / "tri.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0.6 0 0.8\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1/1 2/2/1 3/3/1\n")
    s = io.read_surface(obj)
    assert np.allclose(s.normals, [[0.6, 0.0, 0.8]] * 3)  # computed normals would be (0, 0, 1)
    assert np.allclose(s.uv, [[0, 0], [1, 0], [0, 1]])
    ply = io.read_surface("scenes/assets/backdrop.ply")
    computed = surface.vertex_normals(ply.points, ply.triangles)
    assert np.abs(ply.normals[0] - [np.sin(0.6), 0.0, np.cos(0.6)]).max() < 1e-5
    assert np.abs(ply.normals - computed).max() > 1e-3  # the file's analytic normals, not recomputed ones


def test_closed_surface_to_tets():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    from sim.mesh.types import SurfaceMesh

    mesh = io.tetrahedralize_surface(SurfaceMesh(sphere.vertices, sphere.faces), 0.025)
    r = quality.quality_report(mesh)
    assert r.inverted == 0 and r.total_volume == pytest.approx(sphere.volume, rel=0.1)
    open_surface = SurfaceMesh(sphere.vertices, sphere.faces[:-3], source="holey.stl")
    with pytest.raises(MeshError, match="not closed"):
        io.tetrahedralize_surface(open_surface, 0.025)
