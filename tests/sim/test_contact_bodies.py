"""Contact between bodies, with static triangle surfaces and mesh tools (issue 21 item 4; ``sim.contact_bodies``,
``sim.contact_mesh``, xpbd)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.contact import ContactPlane
from sim.contact_bodies import MeshProbe, SurfaceContact, add_body_contact, merge_models
from sim.integrators import make_integrator
from sim.mesh import io, procedural, select
from sim.mesh.surface import boundary_faces
from sim.model import Model, PrescribedDisplacement, State

G = 9.81


def _run(model, settings, steps, dt):
    integrator = make_integrator("xpbd", model, settings)
    state = State.at_rest(model)
    for _ in range(steps):
        state = integrator.step(state, dt)
    return integrator, state


def _block(size, origin, gravity=True, E=1e5):
    mesh = procedural.box(size, (2, 2, 2), origin=origin)
    return Model.from_mesh(mesh, E=E, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -G if gravity else 0.0]))


def _segment_distance(p, a, b):
    s = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(p - (a + s * (b - a)))


def _triangle_distance(p, a, b, c):
    """Distance from p to triangle abc: to its plane where the foot falls inside, else to its nearest edge."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    height = (p - a) @ n
    u, v = np.linalg.lstsq(np.column_stack([b - a, c - a]), p - height * n - a, rcond=None)[0]
    if u >= 0.0 and v >= 0.0 and u + v <= 1.0:
        return abs(height)
    return min(_segment_distance(p, a, b), _segment_distance(p, b, c), _segment_distance(p, c, a))


def _depth_inside(points, X, tets):
    """Independent of the contact code: for each point inside a tet of the body (barycentrics all > 0), its
    distance to the body's boundary (brute force over every boundary triangle); else 0."""
    faces = boundary_faces(tets)
    depth = np.zeros(len(points))
    for k, p in enumerate(points):
        for tet in tets:
            T = np.column_stack([X[tet[1]] - X[tet[0]], X[tet[2]] - X[tet[0]], X[tet[3]] - X[tet[0]]])
            lam = np.linalg.solve(T, p - X[tet[0]])
            if lam.min() > 0.0 and lam.sum() < 1.0:
                depth[k] = min(_triangle_distance(p, *X[f]) for f in faces)
                break
    return depth


def test_a_block_resting_on_another_is_carried_with_its_weight_and_does_not_sink_in():
    """A 6 cm block (0.216 kg) rests off-centre on a 10 cm block on a floor. The lower block carries the upper's weight
    through the contact (force on the upper block from the lower: its weight, upwards) and the floor carries both;
    XPBD's contact corrections conserve momentum, so at rest both equal the weights up to the remaining motion
    (measured after 0.4 s: contact +1.4e-3, floor +1.5e-3 relative, still settling)."""
    lower = _block((0.1, 0.1, 0.1), (0.0, 0.0, 0.0))
    lower.contact_planes = [ContactPlane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])]
    upper = _block((0.06, 0.06, 0.06), (0.033, 0.027, 0.1))
    group = merge_models([lower, upper])
    add_body_contact(group, 0, 1, friction=0.0, pair=0)
    integrator, state = _run(group.model, {"substeps": 10, "iterations": 8, "damping": 10.0}, 40, 0.01)
    w_lower, w_upper = lower.mass.sum() * G, upper.mass.sum() * G
    force = integrator.contact_loads[0]  # on the second body (upper) from the first (lower)
    assert force[2] == pytest.approx(w_upper, rel=0.01)
    assert np.abs(force[:2]).max() < 0.01 * w_upper
    assert integrator.plane_loads[0, 2] == pytest.approx(-(w_lower + w_upper), rel=0.01)
    x_lower, x_upper = (s.x for s in group.split_state(state))
    # each sweep ends with the contact projections (the lower's nodes against the upper's surface, then the reverse),
    # so a node stays inside only by rounding or by what the later direction moved the other surface: measured
    # 1e-17 m both ways; the tolerance, 1 um, is 1e-5 of the block
    assert _depth_inside(x_upper, x_lower, lower.tets).max() < 1e-6
    assert _depth_inside(x_lower, x_upper, upper.tets).max() < 1e-6
    # it rests on the lower block's top, which its own and the upper's weight press down ~1 mm (E = 1e5 Pa)
    assert 0.097 < x_upper[:, 2].min() < 0.1


def test_two_bodies_pushed_together_do_not_interpenetrate_and_push_each_other_equally():
    """No gravity; block a clamped at x = 0, block b (a 2 mm gap away) driven 1 cm into it by its right face. Every
    node of each body stays outside the other (to 1 um; measured 0) and the force on b from a pushes it back along +x
    (measured 2.49 N, sideways 0.2 % of it)."""
    a = _block((0.1, 0.1, 0.1), (0.0, 0.0, 0.0), gravity=False, E=1e4)
    a.fixed[select.nodes_on_side(a.X, 0, "min")] = True
    b = _block((0.1, 0.06, 0.06), (0.102, 0.02, 0.02), gravity=False, E=1e4)
    right = select.nodes_on_side(b.X, 0, "max")
    b.prescribed.append(PrescribedDisplacement(right, np.array([-0.012, 0.0, 0.0]), 0.0, 0.2))
    group = merge_models([a, b])
    add_body_contact(group, 0, 1, friction=0.0, pair=0)
    integrator, state = _run(group.model, {"substeps": 10, "iterations": 8, "damping": 10.0}, 30, 0.01)
    x_a, x_b = (s.x for s in group.split_state(state))
    assert x_b[:, 0].min() < 0.1  # b pressed a's face in (else the check below is vacuous)
    assert _depth_inside(x_b, x_a, a.tets).max() < 1e-6
    assert _depth_inside(x_a, x_b, b.tets).max() < 1e-6
    force = integrator.contact_loads[0]
    assert force[0] > 0.01  # on b, from a: away from a
    assert np.abs(force[1:3]).max() < 0.05 * force[0]


def _incline_mesh(rot):
    """A static 1 m square of two triangles through the origin, in the plane rotated by ``rot`` (normal rot[:, 2])."""
    square = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]]) @ rot.T
    return square, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("friction", [0.6, 0.2])
def test_a_block_on_a_tilted_static_mesh_sticks_or_slides_as_coulomb_says(friction):
    """tan 20 deg = 0.364: mu = 0.6 sticks (the mesh carries the whole weight), mu = 0.2 slides with its centre of
    mass at g (sin - mu cos) (the same as the plane test, tests/sim/test_contact_plane.py)."""
    theta = np.radians(20.0)
    rot = np.array([[np.cos(theta), 0.0, np.sin(theta)], [0.0, 1.0, 0.0], [-np.sin(theta), 0.0, np.cos(theta)]])
    mesh = procedural.box((0.1, 0.1, 0.1), (2, 2, 2))
    mesh.points = mesh.points @ rot.T
    model = Model.from_mesh(mesh, E=1e6, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -G]))
    points, faces = _incline_mesh(rot)
    model.contacts = [SurfaceContact(np.arange(model.n_nodes), faces, points, friction=friction)]
    weight = model.mass.sum() * G
    if friction > np.tan(theta):
        integrator, state = _run(model, {"substeps": 10, "iterations": 8, "damping": 10.0}, 30, 0.01)
        # sticking: only the elastic shear moves it along the plane (~1e-4 m; sliding would be 5 cm)
        assert np.abs((state.x - model.X) @ rot[:, 0]).max() < 3e-4
        np.testing.assert_allclose(integrator.contact_loads[0, :3], [0.0, 0.0, -weight], atol=0.01 * weight)
    else:
        T = 0.4
        integrator, state = _run(model, {"substeps": 10, "iterations": 8}, 40, 0.01)
        mass = model.mass[:, None]
        v = (state.v * mass).sum(axis=0) / mass.sum()
        expected = G * (np.sin(theta) - friction * np.cos(theta)) * T
        assert v @ rot[:, 0] == pytest.approx(expected, rel=0.01)
        assert abs(v @ rot[:, 2]) < 0.01 * expected
    assert ((state.x @ rot[:, 2]).min()) > -1e-9  # never below the mesh


CUBE_OBJ = """# a closed cube of side 0.2 m centred on the origin, outward wound
v -0.1 -0.1 -0.1
v 0.1 -0.1 -0.1
v 0.1 0.1 -0.1
v -0.1 0.1 -0.1
v -0.1 -0.1 0.1
v 0.1 -0.1 0.1
v 0.1 0.1 0.1
v -0.1 0.1 0.1
f 1 3 2
f 1 4 3
f 5 6 7
f 5 7 8
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
"""


def _cube_tool(tmp_path, times, positions):
    path = tmp_path / "cube.obj"
    path.write_text(CUBE_OBJ)
    surface = io.read_surface(path)
    return MeshProbe(surface.points, surface.triangles, times, positions)


def test_a_cube_mesh_tool_carries_a_block_resting_on_it_and_keeps_every_node_out(tmp_path):
    """A 1 kg block rests on a cube tool (its top face at z = 0); rollers on the block's top hold x and y only, so
    the tool carries the whole weight: the tissue presses it down with -9.81 N (as the sphere in
    tests/test_tool_forces.py; measured 1e-5). Then the cube, moved 5 mm up into a clamped block, leaves no node
    inside it."""
    mesh = procedural.box((0.1, 0.1, 0.1), (2, 2, 2))
    model = Model.from_mesh(mesh, E=1e5, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -G]))
    top = select.nodes_on_side(mesh.points, 2, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.zeros(3), held=np.eye(3)[:2]))
    model.probes = [_cube_tool(tmp_path, [0.0], [[0.05, 0.05, -0.1]])]
    integrator, state = _run(model, {"substeps": 10, "iterations": 4, "damping": 10.0}, 40, 0.01)
    weight = model.mass.sum() * G
    assert integrator.tool_loads[0, 2] == pytest.approx(-weight, rel=0.01)
    assert np.abs(integrator.tool_loads[0, :2]).max() < 1e-3 * weight

    model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0)
    model.fixed[top] = True
    centre = [0.04, 0.05, -0.1]  # off the block's centre line: its top face's edge at x = 0.14 cuts into the side
    model.probes = [_cube_tool(tmp_path, [0.0, 0.1], [centre, [0.04, 0.05, -0.095]])]
    integrator, state = _run(model, {"substeps": 10, "iterations": 8, "damping": 10.0}, 15, 0.01)
    local = np.abs(state.x - np.array([0.04, 0.05, -0.095]))
    inside = (local < 0.1).all(axis=1)
    depth = np.where(inside, (0.1 - local).min(axis=1), 0.0)
    # the tool's projection runs after the tets in every sweep, so the nodes end on its surface up to rounding
    # (coordinates ~0.1 m, a few operations: 1e-15; 1e-12 allows for the grid's rounding)
    assert depth.max() < 1e-12
    assert (state.x[:, 2] < -1e-3).sum() == 0 and state.x[:, 2].min() == pytest.approx(0.005, abs=1e-9)
    assert integrator.tool_loads[0, 2] < 0.0  # the tissue pushes the tool back down


SQUARE_OBJ = """# a static 1 m square at z = 0, its winding's normal +z
v -0.5 -0.5 0
v 0.5 -0.5 0
v 0.5 0.5 0
v -0.5 0.5 0
f 1 2 3
f 1 3 4
"""


def _contact_scene(scene_dict, tmp_path, integrator="xpbd"):
    """The minimal scene's 10x10x4 cm block, unfixed, on a static square (a wall's OBJ) at z = 0 (friction 0.5), a
    6x6x2 cm lid of the same material resting on it, damped."""
    (tmp_path / "wall.obj").write_text(SQUARE_OBJ)
    block = scene_dict["objects"][0]
    del block["fixed"]
    lid = {"name": "lid", "kind": "body", "shape": "box", "size": [0.06, 0.06, 0.02], "cell_size": 0.02,
           "material": "liver", "position": [0.02, 0.02, 0.04]}
    wall = {"name": "wall", "kind": "surface", "mesh": "wall.obj", "material": "fascia"}
    scene_dict["objects"] += [lid, wall]
    scene_dict["contacts"] = [{"bodies": ["block", "wall"], "friction": 0.5}, {"bodies": ["block", "lid"]}]
    scene_dict["simulation"] = {"integrator": integrator, "dt": 1 / 48}
    if integrator == "xpbd":
        scene_dict["simulation"] |= {"substeps": 10, "iterations": 4, "xpbd": {"damping": 20.0}}
    return scene_dict


def test_a_scene_block_on_a_wall_mesh_carries_a_lid_and_reports_both_contact_forces(scene_dict, write_scene, tmp_path):
    from tissuerender import load_scene
    from tissuerender.plan import make_plan
    from tissuerender.stages import StageRecorder
    from tissuerender.world import ToolForceLog, advance, build_world

    scene = load_scene(write_scene(_contact_scene(scene_dict, tmp_path)))
    recorder = StageRecorder()
    world = build_world(scene, make_plan(scene), recorder)
    assert world.integrators[1] is None  # the lid is stepped with the block, as one model
    for _ in range(12):
        advance(world, scene, recorder)
    block, lid = (b.model.mass.sum() * G for b in world.bodies)
    on_wall, on_lid = world.tool_loads
    # the wall carries both, the block the lid (measured after 0.25 s, damped 20/s: 2e-3 and 3e-3)
    assert on_wall[2] == pytest.approx(-(block + lid), rel=0.01)
    assert on_lid[2] == pytest.approx(lid, rel=0.01)
    assert ToolForceLog(scene).names == ["contact:block:wall", "contact:block:lid"]
    x_block, x_lid = world.states[0].x, world.states[1].x
    assert x_block[:, 2].min() > -1e-9 and x_lid[:, 2].min() > 0.035  # on the wall; on the block (compressed)


@pytest.mark.parametrize("change, key, words", [
    ({"integrator": "explicit"}, "contacts[0]", "not for simulation.integrator = 'explicit'"),
    ({"name": "liver"}, "contacts[0].bodies", "'liver', which is not an object"),
])
def test_a_contact_needs_xpbd_and_named_objects(scene_dict, write_scene, tmp_path, change, key, words):
    from tissuerender import load_scene
    from tissuerender.errors import SceneError

    data = _contact_scene(scene_dict, tmp_path, change.get("integrator", "xpbd"))
    if "name" in change:
        data["contacts"][0]["bodies"][0] = change["name"]
    with pytest.raises(SceneError) as error:
        load_scene(write_scene(data))
    assert key in str(error.value) and words in str(error.value)


def test_a_scene_mesh_tool_pushes_the_block_and_is_drawn_where_it_pushes(scene_dict, write_scene, tmp_path):
    """A cube OBJ tool (0.2 m) lowered 5 mm into the minimal scene's clamped block (top at z = 0.04) over 0.25 s:
    no node inside the cube, the tissue pushes it back up (fz > 0), and the drawn triangles are the file's on the
    tool's path."""
    from tissuerender import load_scene
    from tissuerender.plan import make_plan
    from tissuerender.render_inputs import tool_surface
    from tissuerender.stages import StageRecorder
    from tissuerender.world import advance, build_world

    (tmp_path / "cube.obj").write_text(CUBE_OBJ)
    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1 / 48, "substeps": 10, "iterations": 8}
    scene_dict["tools"] = [{"name": "cube", "kind": "mesh", "mesh": "cube.obj", "keyframes": [
        {"t": 0.0, "position": [0.05, 0.05, 0.14]}, {"t": 0.25, "position": [0.05, 0.05, 0.135]}]}]
    scene = load_scene(write_scene(scene_dict))
    recorder = StageRecorder()
    world = build_world(scene, make_plan(scene), recorder)
    for _ in range(6):
        advance(world, scene, recorder)
    x = world.states[0].x
    assert x[:, 2].max() == pytest.approx(0.035, abs=1e-9)  # the top face pressed to the cube's bottom, not into it
    assert world.tool_loads[0, 2] > 0.0  # the tissue pushes the cube up
    points, triangles, normals = tool_surface(scene.tools[0], 0.25)
    assert triangles.shape == (12, 3) and points.min(axis=0) == pytest.approx([-0.05, -0.05, 0.035])
