"""Users' mesh files (issue 19 item 2): gmsh 1 ($NOD/$ELM) and VTK POLYDATA (.vtk, .vtp) read with the expected
counts and coordinates; ``scale`` scales a mesh body before ``position``; a closed surface file's own triangles
are the render surface, embedded in the tets voxelised from it. Test meshes are made here, none downloaded."""
from __future__ import annotations

import numpy as np
import pytest
import pyvista

from sim.errors import MeshError
from sim.mesh import io
from sim.mesh.formats import read_gmsh1
from sim.mesh.quality import neighbour_normal_angles
from tissuerender import load_scene
from tissuerender.bodies import build_body
from tissuerender.errors import SceneError

# node labels out of order and with gaps, as gmsh 1 allows; two tets, one triangle, one line, one point
GMSH1_TETS = """$NOD
6
10 0 0 0
2 0.1 0 0
7 0 0.1 0
3 0 0 0.1
5 0.1 0.1 0.1
99 1 1 1
$ENDNOD
$ELM
5
1 15 0 0 1 99
2 1 0 0 2 10 2
3 4 1 1 4 10 2 7 3
4 4 1 1 4 2 7 3 5
5 2 1 1 3 10 2 7
$ENDELM
"""


def _octahedron_gmsh1(radius: float) -> str:
    nodes = [(1, radius, 0, 0), (2, -radius, 0, 0), (3, 0, radius, 0), (4, 0, -radius, 0), (5, 0, 0, radius),
             (6, 0, 0, -radius)]
    faces = [(1, 3, 5), (3, 2, 5), (2, 4, 5), (4, 1, 5), (3, 1, 6), (2, 3, 6), (4, 2, 6), (1, 4, 6)]
    lines = ["$NOD", str(len(nodes))] + [" ".join(map(str, n)) for n in nodes] + ["$ENDNOD", "$ELM", str(len(faces))]
    lines += [f"{k + 1} 2 1 1 3 {a} {b} {c}" for k, (a, b, c) in enumerate(faces)] + ["$ENDELM", ""]
    return "\n".join(lines)


def _ellipsoid(radii=(0.06, 0.04, 0.03), resolution=48) -> pyvista.PolyData:
    sphere = pyvista.Sphere(radius=1.0, theta_resolution=resolution, phi_resolution=resolution)
    sphere.points = np.asarray(sphere.points, dtype=np.float64) * np.asarray(radii)
    return sphere.triangulate()


def test_gmsh1_nodes_and_elements_are_read_with_their_labels(tmp_path):
    path = tmp_path / "two.msh"
    path.write_text(GMSH1_TETS)
    nodes, tets, triangles = read_gmsh1(path)
    assert nodes.shape == (6, 3) and tets.shape == (2, 4) and triangles.shape == (1, 3)
    # label 10 is the first node (row 0), label 5 the fifth: the labels map to rows in $NOD order
    assert tets.tolist() == [[0, 1, 2, 3], [1, 2, 3, 4]] and triangles.tolist() == [[0, 1, 2]]
    assert nodes[4].tolist() == [0.1, 0.1, 0.1] and nodes[5].tolist() == [1.0, 1.0, 1.0]
    mesh = io.read_tet_mesh(path)  # the unused node 99 (only a point element) is dropped
    assert (mesh.n_points, mesh.n_tets) == (5, 2) and mesh.repairs["unreferenced_removed"] == 1
    assert not io.is_surface_file(path)


def test_gmsh1_errors_name_the_line(tmp_path):
    path = tmp_path / "bad.msh"
    path.write_text(GMSH1_TETS.replace("4 4 1 1 4 2 7 3 5", "4 4 1 1 4 2 7 3 8"))
    with pytest.raises(MeshError, match=r"bad\.msh: line 15: element names node 8, which \$NOD does not list"):
        read_gmsh1(path)
    path.write_text(GMSH1_TETS.replace("$ENDNOD", "$END"))
    with pytest.raises(MeshError, match=r"line 9: expected \$ENDNOD, found '\$END'"):
        read_gmsh1(path)


def test_gmsh1_triangles_are_a_surface_and_vtk_polydata_reads_like_pyvista(tmp_path):
    msh = tmp_path / "octahedron.msh"
    msh.write_text(_octahedron_gmsh1(0.05))
    assert io.is_surface_file(msh)
    surface = io.read_surface(msh)
    assert surface.points.shape == (6, 3) and surface.triangles.shape == (8, 3)
    assert surface.points[4].tolist() == [0.0, 0.0, 0.05]
    ellipsoid = _ellipsoid()
    for name in ("e.vtk", "e.vtp"):
        ellipsoid.save(tmp_path / name, binary=name.endswith(".vtp"))
        assert io.is_surface_file(tmp_path / name)
        surface = io.read_surface(tmp_path / name)
        assert surface.triangles.shape == (ellipsoid.n_cells, 3) and surface.points.shape == (ellipsoid.n_points, 3)
        # binary files hold the points exactly; VTK's legacy ASCII writer keeps 11 significant digits
        np.testing.assert_allclose(surface.points, np.asarray(ellipsoid.points), rtol=1e-10 if name == "e.vtk" else 0,
                                   atol=0)
        np.testing.assert_array_equal(surface.triangles, ellipsoid.regular_faces)


def _mesh_scene(scene_dict, write_scene, mesh, **extra):
    data = {**scene_dict, "objects": [dict(scene_dict["objects"][0])]}
    obj = data["objects"][0]
    for key in ("shape", "size", "cell_size", "fixed"):
        obj.pop(key, None)
    obj.update(mesh=mesh, **extra)
    return load_scene(write_scene(data, f"scene_{extra.get('scale', 1)}.toml"))


def test_scale_multiplies_a_mesh_body_before_its_position(scene_dict, write_scene, tmp_path):
    (tmp_path / "two.msh").write_text(GMSH1_TETS)
    position = [0.01, 0.02, 0.03]
    scene = _mesh_scene(scene_dict, write_scene, "two.msh", position=position)
    plain = build_body(scene.objects[0], 0, scene)
    scene = _mesh_scene(scene_dict, write_scene, "two.msh", scale=2.5, position=position)
    scaled = build_body(scene.objects[0], 0, scene)
    # x -> 2.5 x + position, each one rounding: exact to a few ulps of 0.25 m
    np.testing.assert_allclose(scaled.mesh.points, 2.5 * (plain.mesh.points - position) + position, rtol=0, atol=1e-16)
    extent = lambda p: p.max(axis=0) - p.min(axis=0)  # noqa: E731
    np.testing.assert_allclose(extent(scaled.mesh.points), 2.5 * extent(plain.mesh.points), rtol=1e-15)


def test_a_users_closed_surface_is_the_render_surface_embedded_in_its_tets(scene_dict, write_scene, tmp_path):
    ellipsoid = _ellipsoid()
    ellipsoid.save(tmp_path / "organ.vtp")
    position = np.array([0.1, 0.0, 0.05])
    bodies = {}
    for scale in (1.0, 2.0):
        scene = _mesh_scene(scene_dict, write_scene, "organ.vtp", scale=scale, position=position.tolist(),
                            cell_size=0.01 * scale)
        bodies[scale] = body = build_body(scene.objects[0], 0, scene)
        # the file's own triangles, one for one, at scale * x + position (one multiply and one add: 2 ulps)
        assert body.surface.triangles.shape[0] == ellipsoid.n_cells
        np.testing.assert_array_equal(body.surface.triangles, ellipsoid.regular_faces)
        np.testing.assert_allclose(body.surface.points, np.asarray(ellipsoid.points) * scale + position, rtol=0,
                                   atol=4e-17 * scale)
        # embedded: the rest tets reproduce the surface (barycentric solve, about 1e-15 relative)
        np.testing.assert_allclose(body.surface_points(body.mesh.points), body.surface.points, rtol=0, atol=1e-12)
        angles = neighbour_normal_angles(body.surface.points, body.surface.triangles)
        assert np.percentile(angles, 99) < 10.0
    extent = lambda p: p.max(axis=0) - p.min(axis=0)  # noqa: E731
    np.testing.assert_allclose(extent(bodies[2.0].surface.points), 2.0 * extent(bodies[1.0].surface.points), rtol=1e-14)
    # the tets are voxelised at cell_size = 0.01 scale: their box scales by the factor to the snapping's accuracy
    np.testing.assert_allclose(extent(bodies[2.0].mesh.points), 2.0 * extent(bodies[1.0].mesh.points), rtol=0.05)


def test_a_surface_thinner_than_the_cells_is_refused_naming_the_cell_size(scene_dict, write_scene, tmp_path):
    """A needle 2 cm thick voxelised at 1 cm: its tips get no tets, and extrapolating the tets' motion 1.5 cm out
    would more than double it; the body is refused with what to change (1 cm thick at 3 mm cells: accepted)."""
    _ellipsoid((0.1, 0.01, 0.01), resolution=40).save(tmp_path / "needle.vtp")
    scene = _mesh_scene(scene_dict, write_scene, "needle.vtp", cell_size=0.01)
    with pytest.raises(SceneError, match=r"objects\[0\].*needle\.vtp: the render surface leaves the tet mesh by "
                                         r"0\.01\d+ m .* use a smaller cell_size"):
        build_body(scene.objects[0], 0, scene)
    scene = _mesh_scene(scene_dict, write_scene, "needle.vtp", cell_size=0.003, scale=1.0)
    assert build_body(scene.objects[0], 0, scene).embedding.extra["outside_distance"].max() < 0.003


def test_an_stl_triangle_soup_is_welded_and_turned_outward(tmp_path):
    """STL stores three vertices per triangle: welded, the icosphere's 1,280 triangles share its 642 vertices
    (else each would be shaded flat); listed clockwise, they are flipped so normals point out."""
    import trimesh

    from sim.mesh.surface import orient_outward, weld

    sphere = trimesh.creation.icosphere(3, 0.05)
    inward = trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1], process=False)
    (tmp_path / "inward.stl").write_bytes(inward.export(file_type="stl"))
    read = io.read_surface(tmp_path / "inward.stl")
    assert read.points.shape == (3 * 1280, 3)
    surface = orient_outward(weld(read))
    assert surface.points.shape == (642, 3) and surface.triangles.shape == (1280, 3)
    p = surface.points[surface.triangles]
    assert np.einsum("ij,ij->", np.cross(p[:, 0], p[:, 1]), p[:, 2]) / 6 > 0.95 * 4 / 3 * np.pi * 0.05**3


def test_an_unreadable_vtk_surface_is_one_mesh_error_and_vtk_prints_nothing(tmp_path, capfd):
    (tmp_path / "garbage.vtp").write_bytes(bytes(range(256)) * 2)
    (tmp_path / "short.vtk").write_text("# vtk DataFile Version 2.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0\n")
    for name in ("garbage.vtp", "short.vtk"):
        with pytest.raises(MeshError, match=rf"{name}: cannot read the VTK surface"):
            io.read_surface(tmp_path / name)
    assert capfd.readouterr().err == ""
