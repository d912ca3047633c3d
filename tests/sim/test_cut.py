"""Cutting (issue 21 item 3; sim.cutting, docs/interaction.md "Cutting"): a blade removes the tets it sweeps through,
the model, the XPBD constraints and the render surface follow."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from sim.constitutive import tensor
from sim.contact import Grasp
from sim.cutting import Cut
from sim.cutting.surface import cut_surfaces
from sim.cutting.sweep import capsule_meets_tet
from sim.integrators.xpbd import blocked
from sim.integrators.xpbd.removal import TetRemoval
from sim.integrators.xpbd.solver import XPBD
from sim.mesh import procedural
from sim.model import Model, State, rest_shape
from sim.probe import Probe

LENGTH, SIDE = 0.2, 0.04


def _cut_bar(gravity=(0.0, 0.0, 0.0), steps=8, grasp=False, prony=False):
    """A 20 x 4 x 4 cm bar (10 x 2 x 2 cells, 240 tets) clamped at both ends, cut through at x = 0.101 m by a
    capsule blade (radius 2 mm, along y, longer than the bar is wide) moving down through it in 0.08 s; with
    ``grasp``, a still sphere (radius 0.1 mm) holds the nodes within 2.1 cm of the bar's centre from t = 0; with
    ``prony``, one Prony term (a = 0.3, tau = 0.05 s: a constraint set of its own, packed anew after every step)."""
    mesh = procedural.box((LENGTH, SIDE, SIDE), (10, 2, 2))
    model = Model.from_mesh(mesh, E=1e5, nu=0.4, density=1000.0, gravity=np.asarray(gravity, dtype=np.float64))
    model.fixed[(mesh.points[:, 0] < 1e-9) | (mesh.points[:, 0] > LENGTH - 1e-9)] = True
    blade = Probe(kind="capsule", radius=0.002, times=[0.0, 0.08], positions=[[0.101, 0.02, 0.06], [0.101, 0.02, -0.06]],
                  axis=[0.0, 1.0, 0.0], length=0.1)
    model.probes = [blade]
    model.cuts = [Cut(probe=0, t_start=0.0, t_end=0.08)]
    if grasp:
        model.probes.append(Probe(kind="sphere", radius=1e-4, times=[0.0], positions=[[0.1, 0.02, 0.02]]))
        model.grasps = [Grasp(probe=1, t_close=0.0, t_release=10.0, radius=0.021)]
    if prony:
        model.material_params = dict(model.material_params, prony=[(0.3, 0.05)])
    original = Model.from_mesh(mesh, E=1e5, nu=0.4, density=1000.0)
    integrator = XPBD(model, {"substeps": 5, "iterations": 5})
    state = State.at_rest(model)
    for k in range(steps):
        state.t = k * 0.01
        state = integrator.step(state, 0.01)
    return mesh, original, model, integrator, state


def _components(tets: np.ndarray, n_nodes: int) -> int:
    """Connected pieces of the tets (joined through shared nodes)."""
    tets = tets.astype(np.int64)
    graph = coo_matrix((np.ones(tets.size - tets.shape[0]), (np.repeat(tets[:, 0], 3), tets[:, 1:].ravel())),
                       shape=(n_nodes, n_nodes))
    _, label = connected_components(graph, directed=False)
    return int(np.unique(label[np.unique(tets)]).size)


def _meets(a, b, radius, corners) -> bool:
    return capsule_meets_tet(tuple(map(float, a)), tuple(map(float, b)), radius,
                             tuple(tuple(map(float, c)) for c in corners))


def test_capsule_tet_test_is_exact_at_the_radius():
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    # a segment parallel to the face x + y + z = 1 at distance d from it, beyond the tet
    n = np.ones(3) / np.sqrt(3.0)
    a, b = np.array([0.3, 0.3, 0.4]) + 0.1 * n, np.array([0.4, 0.3, 0.3]) + 0.1 * n
    assert _meets(a, b, 0.1 + 1e-12, corners) and not _meets(a, b, 0.1 - 1e-12, corners)
    # a segment passing through the tet, its ends outside, radius 0: found by the clipping
    assert _meets(np.array([0.2, 0.2, -1.0]), np.array([0.2, 0.2, 1.0]), 0.0, corners)
    # skew to an edge: the edge x-axis [0, 1] and a segment along y at (0.5, ., -0.3): distance 0.3
    a, b = np.array([0.5, -1.0, -0.3]), np.array([0.5, 1.0, -0.3])
    assert _meets(a, b, 0.3 + 1e-12, corners) and not _meets(a, b, 0.3 - 1e-12, corners)


def test_a_cut_through_a_bar_leaves_two_pieces_with_the_volume_and_mass_of_the_tets_kept():
    mesh, original, model, integrator, state = _cut_bar()
    topology = integrator.cutter.topology
    removed = np.flatnonzero(~topology.alive)
    # the blade (x = 0.099 ... 0.103) meets every tet of the two cell columns touching x = 0.1: 2 x 24 tets
    assert removed.size == 48
    assert _components(model.tets, model.n_nodes) == 2
    # the model's tets are the original ones kept, in order; their rest volumes summed (6 per 1e-5 m^3 cell:
    # a few ulps of each) equal the original's minus the removed tets' to 1e-12
    np.testing.assert_array_equal(model.tets, mesh.tets[topology.alive])
    _, volume = rest_shape(model.X, model.tets)
    expected = original.volume.sum() - original.volume[removed].sum()
    assert volume.sum() == pytest.approx(expected, rel=1e-12)
    assert model.volume.sum() == pytest.approx(expected, rel=1e-12)
    # lumped masses summed again over the kept tets: the total is rho V; nodes in no tet have none
    assert model.mass.sum() == pytest.approx(1000.0 * expected, rel=1e-12)
    orphans = np.setdiff1d(np.arange(model.n_nodes), model.tets)
    assert orphans.size > 0 and np.all(model.mass[orphans] == 0.0) and np.all(integrator.w[orphans] == 0.0)
    # the constraints were rebuilt on the kept tets: every colour holds tets sharing no node
    assert integrator.tets.shape[0] == model.n_tets
    for c in range(integrator.colour_start.size - 1):
        colour = integrator.tets[integrator.colour_start[c]:integrator.colour_start[c + 1]]
        assert np.unique(colour).size == colour.size


def test_no_tet_inverts_after_the_cut_and_under_gravity_after_it():
    _, _, model, integrator, state = _cut_bar(gravity=(0.0, 0.0, -9.81), steps=20)
    J = np.linalg.det(tensor.deformation_gradients(state.x, model.tets, model.Dm_inv))
    assert J.min() > 0.5
    # the two cantilevers hang from their clamps, the free ends below their rest height, the orphan nodes still
    assert state.x[:, 2][np.unique(model.tets)].min() < -1e-4
    orphans = np.setdiff1d(np.arange(model.n_nodes), model.tets)
    assert np.all(state.v[orphans] == 0.0)


@pytest.mark.parametrize("prony", [False, True])
def test_removed_tets_left_inert_in_the_blocks_give_the_positions_of_blocks_packed_anew(monkeypatch, prony):
    # a removal leaves a removed tet's lane in the blocked kernel's blocks with every parameter zero (its correction
    # is then exactly 0.0) and rewrites only the mass rows of the tets around it (sim.integrators.xpbd.removal);
    # packing the blocks anew at the end of every step with a removal (repack_fraction 0) is the reference. Same
    # tets, same order within each colour, same per-lane arithmetic: the positions must agree to the bit after the
    # cut and 0.2 s under gravity. A Prony branch's set is packed anew after every step (its rest shape drifts): its
    # removed lanes are found in its own layout.
    runs = {}
    for fraction in (0.0, np.inf):
        monkeypatch.setattr(TetRemoval, "repack_fraction", fraction)
        _, _, model, integrator, state = _cut_bar(gravity=(0.0, 0.0, -9.81), steps=20, prony=prony)
        runs[fraction] = (state.x, integrator)
    removal = runs[np.inf][1].removal
    assert removal.inert[0] == 48 and runs[0.0][1].removal.inert[0] == 0
    params = runs[np.inf][1].blocks[1].reshape(-1, blocked.N_ROWS, blocked.LANES)
    dead = np.setdiff1d(np.arange(params.shape[0] * blocked.LANES), removal.slots[0])  # removed tets' and padding
    assert np.all(params[dead // blocked.LANES, :, dead % blocked.LANES] == 0.0)
    np.testing.assert_array_equal(runs[np.inf][0], runs[0.0][0])


def test_a_cutting_model_steps_in_one_call_per_substep_as_in_the_per_sweep_loop(monkeypatch):
    # sim.integrators.xpbd.sweeps runs a cutting model's sweeps in one compiled call (the blade's shaft pushing, the
    # grasp holding); the per-sweep Python loop is the reference: the same operations in the same order, so the
    # positions and the tools' loads must agree to the bit through the cut, the grasp and 0.2 s under gravity.
    from sim.integrators.xpbd import sweeps
    _, _, model, fused, state = _cut_bar(gravity=(0.0, 0.0, -9.81), steps=20, grasp=True)
    assert fused.fused is not None and model.n_tets == 240 - 48
    monkeypatch.setattr(sweeps.FusedSweeps, "covers", staticmethod(lambda xpbd, probes: False))
    _, _, _, loop, reference = _cut_bar(gravity=(0.0, 0.0, -9.81), steps=20, grasp=True)
    assert loop.fused is None
    np.testing.assert_array_equal(state.x, reference.x)
    np.testing.assert_array_equal(state.v, reference.v)


def test_grasped_nodes_the_cut_leaves_in_no_tet_let_go():
    mesh, _, model, integrator, state = _cut_bar(grasp=True)
    # grasped at t = 0: the bar's centre node (0.1, 0.02, 0.02), its 4 neighbours in the plane x = 0.1 and the 2 at
    # x = 0.08 and 0.12 (2 cm away); the cut leaves the plane's nodes in no tet (massless: a rigid attachment would
    # divide by their zero inverse mass), so they let go, and the two off the plane stay held
    assert integrator.grasps[0].closed and np.isfinite(state.x).all()
    held = mesh.points[integrator.grasps[0].nodes]
    np.testing.assert_allclose(held, [[0.08, 0.02, 0.02], [0.12, 0.02, 0.02]], atol=1e-12)


def test_the_render_surface_is_closed_and_manifold_with_the_cut_faces_apart():
    _, _, model, integrator, _ = _cut_bar()
    mesh, surface, embedding, cut = cut_surfaces(integrator.cutter.topology, model.X, "bar")
    faces = np.concatenate([surface.vertex_map[surface.triangles], cut.vertex_map[cut.triangles]])
    edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert np.all(count == 2)
    directed = faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    assert np.unique(directed, axis=0).shape[0] == directed.shape[0]  # consistently oriented
    # the cut faces are the two planes x = 0.08 and x = 0.12 of the 2 x 2 cell cross-section: 2 x 8 triangles
    assert cut.triangles.shape[0] == 16
    np.testing.assert_allclose(np.sort(np.unique(np.round(cut.points[:, 0], 12))), [0.08, 0.12])
    # the body part embeds its vertices at their nodes exactly
    from sim.mesh.embed import deform

    x = model.X + 0.01 * np.arange(model.n_nodes)[:, None]
    np.testing.assert_array_equal(deform(embedding, mesh.tets, x), x[surface.vertex_map])


def _hook_scene(scene_dict, integrator="xpbd"):
    """The minimal scene's liver block (10 x 10 x 4 cm, 2 cm cells, bottom clamped) with an L-hook pointing down
    whose 1.4 mm wire reaches 1.5 cm into it, drawn across it along y at x = 5 cm in the first frame interval."""
    scene_dict["simulation"] = {"integrator": integrator, "dt": 1 / 72, "substeps": 4, "iterations": 4,
                                "gravity": [0.0, 0.0, 0.0]}
    scene_dict["output"]["frames"] = 2
    scene_dict["tools"] = [{"name": "hook", "kind": "l_hook", "radius": 0.004, "length": 0.1, "axis": [0.0, 0.0, -1.0],
                            "keyframes": [{"t": 0.0, "position": [0.05, -0.02, 0.055]},
                                          {"t": 1 / 24, "position": [0.05, 0.12, 0.055]}],
                            "cut": [{"t_start": 0.0, "t_end": 1.0}]}]
    return scene_dict


def test_a_scene_with_a_cutting_l_hook_renders_the_cut_faces_in_the_cut_material(scene_dict, write_scene):
    from tissuerender import load_scene
    from tissuerender.pipeline import render_hdr
    from tissuerender.plan import make_plan
    from tissuerender.stages import StageRecorder
    from tissuerender.world import advance, build_world

    scene = load_scene(write_scene(_hook_scene(scene_dict)))
    plan = make_plan(scene)
    recorder = StageRecorder()
    world = build_world(scene, plan, recorder)
    advance(world, scene, recorder)
    removed = int((~world.integrators[0].cutter.topology.alive).sum())
    assert removed > 0 and 0 in world.cut_faces
    result, _ = render_hdr(world, scene, plan, recorder, 1 / 24, seed=3)
    material = result.gbuffer["material_id"]
    cut_id = 2  # block, hook, then the block's cut faces (after the tools)
    assert (material == 0).sum() > 100 and (material == cut_id).sum() > 5
    # drawn with tissue_cut: its albedo, darker than the liver's
    albedo = result.gbuffer["albedo"]
    np.testing.assert_allclose(albedo[material == cut_id][0], [0.15, 0.025, 0.02], rtol=1e-6)


@pytest.mark.parametrize("integrator", ["ebm", "none"])
def test_a_cut_needs_the_xpbd_integrator(scene_dict, write_scene, integrator):
    from tissuerender import load_scene
    from tissuerender.errors import SceneError

    data = _hook_scene(scene_dict, integrator)
    if integrator == "none":
        data["simulation"] = {"integrator": "none"}
    with pytest.raises(SceneError) as error:
        load_scene(write_scene(data))
    message = str(error.value)
    assert "tools[0].cut" in message
    assert (f"not for simulation.integrator = {integrator!r}" if integrator != "none" else "simulates nothing") in message
