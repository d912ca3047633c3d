"""The contact broad phase and the fused sweeps (issue 21, "Performance"; ``sim.contact_set``, ``sim.contact_broad``,
``sim.integrators.xpbd.sweeps``) change the cost, not the result: a stack of two blocks on a floor, with friction,
a capsule tool pushing into the top and a grasp, and a block settling on a folded static sheet, step bit for bit the
same with the candidate lists (and the hint kept without a search while it is provably nearest) as with every
triangle searched in every sweep, and with one compiled call per substep as with the per-sweep Python loop."""
import numpy as np

from sim.contact import ContactPlane, Grasp
from sim.contact_bodies import add_body_contact, add_static_contact, merge_models
from sim.contact_broad import _static_clearance, nearest_triangle
from sim.contact_bodies import SurfaceContact, SurfaceContactState
from sim.contact_mesh import closest_on_triangle
from sim.contact_set import ContactSet
from sim.integrators import make_integrator
from sim.integrators.xpbd import sweeps
from sim.mesh import procedural
from sim.model import Model, State
from sim.probe import Probe


def _stack():
    blocks = []
    for size, origin in (((0.1, 0.1, 0.04), (0.0, 0.0, 0.0)), ((0.06, 0.06, 0.03), (0.021, 0.017, 0.041))):
        mesh = procedural.box(size, (3, 3, 2), origin=origin)
        blocks.append(Model.from_mesh(mesh, E=1e5, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -9.81])))
    blocks[0].contact_planes = [ContactPlane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], friction=0.5)]
    group = merge_models(blocks)
    add_body_contact(group, 0, 1, friction=0.4, pair=0)
    model = group.model
    # a capsule pressing the upper block's top down and sideways, grasping what it touches from 0.1 s
    model.probes = [Probe("capsule", 0.008, [0.0, 0.2], [[0.05, 0.05, 0.08], [0.055, 0.05, 0.076]],
                          axis=[1.0, 0.0, 0.0], length=0.03)]
    model.grasps = [Grasp(probe=0, t_close=0.1, t_release=1.0, radius=0.02)]
    return model


def _steps(model, steps=12, dt=0.02):
    integrator = make_integrator("xpbd", model, {"substeps": 5, "iterations": 5, "damping": 5.0})
    state, loads = State.at_rest(model), []
    for _ in range(steps):
        state = integrator.step(state, dt)
        loads.append(np.concatenate([integrator.tool_loads.ravel(), integrator.plane_loads.ravel(),
                                     integrator.contact_loads.ravel()]))
    return integrator, state, np.array(loads)


def test_candidate_lists_and_the_fused_sweeps_step_bit_for_bit_as_full_searches_in_python_sweeps():
    model = _stack()
    # more steps than one begin_step computes the tool's poses for: the look-ahead rolls over
    steps = sweeps.FusedSweeps.LOOKAHEAD + 4
    fused, state, loads = _steps(model, steps=steps)
    assert fused.fused is not None  # the fused path ran
    # real work in every part: the tool pushed, the grasp held nodes, the blocks pressed each other and the floor
    assert np.abs(loads[-1, 0:3]).max() > 0.1 and fused.grasps[0].nodes.size > 0
    assert loads[-1, 8] < -1.0 and np.abs(loads[-1, 12:15]).max() > 0.1
    covers, fraction = sweeps.FusedSweeps.covers, ContactSet.motion_fraction
    try:
        sweeps.FusedSweeps.covers = staticmethod(lambda xpbd, probes: False)  # the per-sweep Python loop
        ContactSet.motion_fraction = 0.0  # no node is ever still enough: every sweep searches every triangle
        loop, state_ref, loads_ref = _steps(model, steps=steps)
    finally:
        sweeps.FusedSweeps.covers, ContactSet.motion_fraction = covers, fraction
    assert loop.fused is None
    assert np.array_equal(state.x, state_ref.x) and np.array_equal(state.v, state_ref.v)
    assert np.array_equal(loads, loads_ref)


def _sheet(n=9, half=0.12, fold=0.01):
    """An open triangulated sheet folded along x (ridges and valleys: nodes rest on faces, edges and vertices)."""
    u = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(u, u, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), fold * np.sin(40.0 * gx.ravel()) + 0.004 * gy.ravel()], axis=1)
    k = np.arange((n - 1) * n).reshape(n - 1, n)[:, :n - 1].ravel()
    faces = np.concatenate([np.stack([k, k + n, k + n + 1], 1), np.stack([k, k + n + 1, k + 1], 1)])
    return points, faces


def test_a_block_settling_on_a_static_sheet_steps_bit_for_bit_as_full_searches():
    points, faces = _sheet()
    mesh = procedural.box((0.08, 0.06, 0.03), (4, 3, 2), origin=(-0.04, -0.03, 0.012))
    model = Model.from_mesh(mesh, E=2e4, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    add_static_contact(model, np.arange(model.n_nodes), points, faces, friction=0.3, pair=0, reach=0.02)
    fused, state, loads = _steps(model, steps=20)
    assert fused.fused is not None
    # it has settled onto the folds: the block presses the sheet down with about its weight, several nodes in contact
    weight = float(model.mass.sum()) * 9.81
    assert abs(loads[-1, -4] + weight) < 0.1 * weight and np.count_nonzero(fused.contacts[0].lam_n) >= 4
    fraction = ContactSet.motion_fraction
    covers = sweeps.FusedSweeps.covers
    try:
        sweeps.FusedSweeps.covers = staticmethod(lambda xpbd, probes: False)
        ContactSet.motion_fraction = 0.0
        loop, state_ref, loads_ref = _steps(model, steps=20)
    finally:
        sweeps.FusedSweeps.covers, ContactSet.motion_fraction = covers, fraction
    assert np.array_equal(state.x, state_ref.x) and np.array_equal(state.v, state_ref.v)
    assert np.array_equal(loads, loads_ref)


def test_the_runner_up_is_the_second_nearest_triangle_capped_at_reach():
    """``nearest_triangle(..., runner_up=1.0)`` (a cap far beyond the sheet): the same nearest triangle as without,
    and the squared distance to the nearest other triangle (brute force) or reach**2 when none is nearer; a point on a shared edge or vertex has
    its runner-up as near as its nearest."""
    points, faces = _sheet(n=6)
    state = SurfaceContactState(SurfaceContact(np.zeros(0), faces, points, reach=0.03), np.zeros((0, 3)))
    cs = ContactSet([state], 0)
    reach = state.reach
    everything = np.arange(faces.shape[0], dtype=np.int64)
    rng = np.random.default_rng(3)
    queries = list(rng.uniform([-0.13, -0.13, -0.04], [0.13, 0.13, 0.04], (300, 3))) + [points[14], points[15] * 0.5 + points[21] * 0.5]
    ties = 0
    for g in queries:
        d2 = np.array([np.sum((g - sum(b * points[f[j]] for j, b in enumerate(closest_on_triangle(g, *points[f])[:3])))
                              ** 2) for f in faces])
        t, f, b0, b1, b2, second2 = nearest_triangle(g, np.zeros((0, 3)), cs.static_x, 0, cs.tri_v, cs.face_n, cs.lo,
                                                     cs.hi, reach, -1, everything, 0, everything.size, 1.0)
        plain = nearest_triangle(g, np.zeros((0, 3)), cs.static_x, 0, cs.tri_v, cs.face_n, cs.lo, cs.hi, reach, -1,
                                 everything, 0, everything.size)
        assert plain[:5] == (t, f, b0, b1, b2) and plain[5] == reach * reach
        order = np.argsort(d2, kind="stable")
        if d2[order[0]] > reach * reach:
            assert t == -1 and second2 == reach * reach
            continue
        assert abs(d2[t] - d2[order[0]]) <= 1e-15
        expected = min(np.delete(d2, t).min(), reach * reach)
        # both are the same few-flop sums over the same coordinates: equal to rounding (1e-16 m^2 at 0.1 m)
        assert abs(second2 - expected) <= 1e-15
        ties += second2 - d2[t] <= 1e-15
    assert ties >= 2  # the vertex and the edge midpoint


def test_a_static_surface_clearance_is_its_distance_capped_at_two_reach():
    """A node skipped by the static broad phase is farther than reach from the surface: the clearance it is given is
    the brute-force distance to the surface (or 2 reach when farther), less its 1e-9 relative safety margin."""
    rng = np.random.default_rng(7)
    u = np.linspace(-0.2, 0.2, 6)
    gx, gy = np.meshgrid(u, u, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), 0.02 * np.sin(9.0 * gx.ravel())], axis=1)
    k = np.arange(5 * 6).reshape(5, 6)[:, :5].ravel()
    faces = np.concatenate([np.stack([k, k + 6, k + 7], 1), np.stack([k, k + 7, k + 1], 1)])
    state = SurfaceContactState(SurfaceContact(np.zeros(0), faces, points), np.zeros((0, 3)))
    cs = ContactSet([state], 0)
    seen = np.full(faces.shape[0], -1, np.int64)
    checked = 0
    for q, g in enumerate(rng.uniform([-0.25, -0.25, -0.1], [0.25, 0.25, 0.15], (200, 3))):
        brute = min(np.linalg.norm(g - sum(b * points[f[j]] for j, b in enumerate(closest_on_triangle(
            g, *points[f])[:3]))) for f in faces)
        clear = _static_clearance(g, np.zeros((0, 3)), cs.static_x, 0, cs.tri_v, cs.lo, cs.hi, state.reach, 0,
                                  cs.g_origin[0], cs.g_cell[0], cs.g_dims[0], cs.g_start_off[0], cs.g_items_off[0],
                                  cs.g_start, cs.g_items, seen, -2 - q)
        expected = min(brute, 2.0 * state.reach)
        # 1e-9 relative margin, and the distance's own rounding: a few ulps of 0.1 m coordinates (1e-15 m)
        assert expected * (1.0 - 1e-9) - 1e-14 <= clear <= expected * (1.0 - 1e-9) + 1e-14
        checked += brute < 2.0 * state.reach
    assert checked > 50  # most points near enough for a true distance, not the cap


def test_border_triangles_are_those_with_a_corner_on_an_open_edge():
    """An open 6 x 6 sheet: the 18 triangles of its inner 3 x 3 cells have no corner on its rim, all others do; a
    closed box surface has none."""
    from sim.contact_mesh import face_adjacency
    from sim.contact_set import border_triangles
    from sim.mesh.surface import boundary_faces
    points, faces = _sheet(n=6)
    border = border_triangles(faces, face_adjacency(faces))
    rim = (np.abs(points[:, :2]) > 0.119).any(axis=1)
    assert np.array_equal(border, rim[faces].any(axis=1)) and np.count_nonzero(~border) == 18
    box = boundary_faces(procedural.box((0.1, 0.1, 0.1), (2, 2, 2)).tets)
    assert not border_triangles(box, face_adjacency(box)).any()


def _triangle_distances(g, corners):
    return np.array([np.linalg.norm(g - sum(b * tri[j] for j, b in enumerate(closest_on_triangle(g, *tri)[:3])))
                     for tri in corners])


def test_every_node_within_reach_is_visited_with_its_nearest_triangle_as_hint():
    """The broad phase keeps lists, hints and clearances across substeps (``sim.contact_broad``): at the last
    substep of each of 12 steps of the stack (blocks pressing each other, the tool pushing and dragging) and of a block
    on the folded sheet, every tested node within reach of its contact's surface (brute force over all its triangles)
    is visited, with a hint as near as the nearest triangle, and no visited node is farther than reach."""
    points, faces = _sheet()
    mesh = procedural.box((0.08, 0.06, 0.03), (4, 3, 2), origin=(-0.04, -0.03, 0.012))
    block = Model.from_mesh(mesh, E=2e4, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    add_static_contact(block, np.arange(block.n_nodes), points, faces, friction=0.3, pair=0, reach=0.02)
    checked = 0
    for model in (_stack(), block):
        integrator = make_integrator("xpbd", model, {"substeps": 5, "iterations": 5, "damping": 5.0})
        cs, state = integrator.contact_set, State.at_rest(model)
        for _ in range(12):
            state = integrator.step(state, 0.02)
            x = cs.x_start  # the positions of the last broad phase
            corners = np.concatenate([x, cs.static_x])[cs.tri_v]
            for c in range(len(cs.contacts)):
                tris = corners[cs.c_tri_start[c]:cs.c_tri_start[c + 1]]
                visited = cs.entry_contact == c
                hints = dict(zip(cs.entry_node[visited], cs.entry_hint[visited]))
                for i in cs.nodes[cs.c_node_start[c]:cs.c_node_start[c + 1]]:
                    d = _triangle_distances(x[i], tris)
                    reach = cs.c_reach[c]
                    if d.min() < reach * (1.0 - 1e-9):
                        assert i in hints
                        hinted = d[hints[i] - cs.c_tri_start[c]]
                        assert hinted <= d.min() + 1e-12  # the nearest (or one as near), to rounding
                        checked += 1
                    elif i in hints:
                        assert d.min() <= reach * (1.0 + 1e-9)
    assert checked > 200
