"""Grasping (issue 21 item 2): tissue nodes attach to a tool's jaws at t_close, follow it rigidly, detach at
t_release or tear above tear_force (``sim.contact``, in ``sim.integrators.xpbd``)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.contact import Grasp
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, State
from sim.probe import Probe

SETTINGS = {"substeps": 5, "iterations": 8, "damping": 20.0}


def _block(grasp, lift=0.01, t_lift=0.2):
    """A 10 cm block (5x5x5 nodes, bottom clamped); a sphere of radius 1 cm at the top face's centre grasps and
    lifts by ``lift`` over ``t_lift`` seconds, then holds."""
    mesh = procedural.box((0.1, 0.1, 0.1), (4, 4, 4))
    model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0)
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    top = [0.05, 0.05, 0.1 + 0.01]
    model.probes = [Probe("sphere", 0.01, [0.0, t_lift], [top, [0.05, 0.05, top[2] + lift]])]
    model.grasps = [grasp]
    return model


def _run(model, steps, dt=0.02, state=None, integrator=None):
    integrator = integrator or make_integrator("xpbd", model, SETTINGS)
    state = state or State.at_rest(model)
    for _ in range(steps):
        state = integrator.step(state, dt)
    return integrator, state


def test_grasped_nodes_follow_the_jaws_and_the_body_returns_to_rest_after_release():
    model = _block(Grasp(probe=0, t_close=0.0, t_release=0.6, radius=0.03))
    integrator, state = _run(model, 15)  # t = 0.3: lifted by 1 cm, holding
    grasp = integrator.grasps[0]
    # within 3 cm of the sphere's centre 1 cm above the top face (2.5 cm grid): the face's centre node (1 cm) and its
    # 4 edge neighbours (2.69 cm); the diagonal ones are 3.68 cm away, the node below 3.5 cm
    assert grasp.nodes.size == 5
    moved = state.x[grasp.nodes] - model.X[grasp.nodes]
    # zero compliance, projected last in each sweep: the attached nodes sit exactly at their offset from the tool
    # (rounding of a few additions of numbers ~0.1 m: 1e-15 m; 1e-12 m is a wide bound)
    np.testing.assert_allclose(moved, np.broadcast_to([0.0, 0.0, 0.01], moved.shape), atol=1e-12)
    assert -integrator.tool_loads[0, 2] > 0.0  # the tissue pulls the tool down
    integrator, state = _run(model, 50, state=state, integrator=integrator)  # released at 0.6 s, t = 1.3 s
    assert grasp.nodes.size == 0
    # damped elastic body back at rest: 1 cm lift decays (damping 20/s over 0.7 s, stiff block) below 1e-5 m
    assert np.abs(state.x - model.X).max() < 1e-5
    assert np.abs(integrator.tool_loads).max() == 0.0  # released, the probe above the surface: no load


def test_tear_force_breaks_the_attachment_when_pulled_hard():
    kept = _block(Grasp(probe=0, t_close=0.0, t_release=10.0, radius=0.03, tear_force=None), lift=0.03)
    integrator, state = _run(kept, 15)
    assert integrator.grasps[0].nodes.size == 5  # no threshold: still attached, 3 cm up
    force = -integrator.tool_loads[0, 2]
    assert force > 0.0
    # per node: the 5 nodes share the total force, so half its share (0.1 of it) tears the most loaded one, then the rest
    torn = _block(Grasp(probe=0, t_close=0.0, t_release=10.0, radius=0.03, tear_force=0.1 * force), lift=0.03)
    integrator, state = _run(torn, 15)
    grasp = integrator.grasps[0]
    assert grasp.nodes.size == 0 and grasp.torn >= 1
    # torn, the top face hangs back well below the tool
    assert state.x[:, 2].max() < 0.1 + 0.01


def _scene(scene_dict, integrator="xpbd"):
    """The minimal scene's 10x10x4 cm liver block, unfixed, resting on a floor at z = 0 (friction 0.5), grasped at its
    top face's centre by a still sphere from t = 0."""
    body = scene_dict["objects"][0]
    del body["fixed"]
    body["floor"] = {"point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0], "friction": 0.5}
    scene_dict["simulation"] = {"integrator": integrator, "dt": 1 / 48, "substeps": 10, "iterations": 4}
    if integrator == "xpbd":
        scene_dict["simulation"]["xpbd"] = {"damping": 20.0}
    scene_dict["tools"] = [{"name": "jaws", "radius": 0.005, "visible": False,
                            "keyframes": [{"t": 0.0, "position": [0.04, 0.04, 0.045]}],
                            "grasp": [{"t_close": 0.0, "t_release": 100.0, "radius": 0.022}]}]
    return scene_dict


def test_a_scene_grasp_and_floor_share_the_weight_of_the_block(scene_dict, write_scene):
    from tissuerender import load_scene
    from tissuerender.plan import make_plan
    from tissuerender.stages import StageRecorder
    from tissuerender.world import ToolForceLog, advance, build_world

    scene = load_scene(write_scene(_scene(scene_dict)))
    plan = make_plan(scene)
    recorder = StageRecorder()
    world = build_world(scene, plan, recorder)
    model = world.bodies[0].model
    assert model.contact_planes[0].friction == 0.5 and model.grasps[0].radius == 0.022
    for _ in range(24):
        advance(world, scene, recorder)
    assert world.integrators[0].grasps[0].nodes.size == 5  # the top node under the jaws and its 4 neighbours (2 cm grid)
    weight = model.mass.sum() * 9.81
    tool, floor = world.tool_loads
    # at rest, the jaws (holding the top face's centre) and the floor carry the weight between them: the impulses of
    # gravity, contact and attachment balance up to the remaining motion (damped 20/s for 0.5 s: measured 4e-10)
    assert tool[2] + floor[2] == pytest.approx(-weight, rel=0.01)
    assert floor[2] < -0.5 * weight
    log = ToolForceLog(scene)
    assert log.names == ["jaws", "floor:block"]


@pytest.mark.parametrize("integrator", ["explicit", "none"])
def test_grasp_and_floor_need_the_xpbd_integrator(scene_dict, write_scene, integrator):
    from tissuerender import load_scene
    from tissuerender.errors import SceneError

    data = _scene(scene_dict, integrator)
    data["simulation"] = {"integrator": integrator} | ({"dt": 1 / 48} if integrator != "none" else {})
    del data["tools"][0]["visible"]
    with pytest.raises(SceneError) as error:
        load_scene(write_scene(data))
    message = str(error.value)
    assert "tools[0].grasp" in message
    assert (f"not for simulation.integrator = {integrator!r}" if integrator != "none" else "simulates nothing") in message
