"""Tool forces (issue 21 item 5): the force and torque the tissue exerts on each tool, from the contact impulses of
xpbd (``sim.probe.resolve_contact_load``), per frame in ``OUT/tool_forces.csv`` and the manifest."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import tissuerender
from sim.constitutive import elastic
from sim.integrators import make_integrator
from sim.mesh import procedural, select
from sim.model import Model, PrescribedDisplacement, State
from sim.probe import Probe
from tissuerender import load_scene

G = 9.81


def _settle(model, settings, steps, dt):
    integrator = make_integrator("xpbd", model, settings)
    state = State.at_rest(model)
    for _ in range(steps):
        state = integrator.step(state, dt)
    return integrator, state


def test_a_probe_carrying_a_block_under_gravity_carries_its_weight():
    """A 1 kg block rests on a sphere of radius 0.2 m; rollers on its top face (x and y held, z free) keep it from
    tipping but carry no vertical load, so at rest the tissue presses the tool down with the block's weight. XPBD's
    contact impulses conserve momentum with the elastic corrections (which sum to zero), so the mean contact force
    equals the weight up to the remaining motion: measured -9.8100011 N against 9.81 N."""
    mesh = procedural.box((0.1, 0.1, 0.1), (4, 4, 4))
    model = Model.from_mesh(mesh, E=1e5, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -G]))
    top = select.nodes_on_side(mesh.points, 2, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.zeros(3), held=np.eye(3)[:2]))
    model.probes = [Probe("sphere", 0.2, [0.0], [[0.05, 0.05, -0.2]])]
    integrator, state = _settle(model, {"substeps": 10, "iterations": 4, "damping": 10.0}, 100, 0.01)
    force, torque = integrator.tool_loads[0, :3], integrator.tool_loads[0, 3:]
    weight = model.mass.sum() * G
    assert force[2] == pytest.approx(-weight, rel=1e-4)
    assert np.abs(force[:2]).max() < 1e-3 * weight
    assert np.abs(torque).max() < 1e-12  # a sphere's frictionless contact forces all point through its centre


def test_probe_indentation_force_agrees_with_the_reference_reaction_within_2_percent():
    """A sphere (R = 0.2 m) indents a clamped 10 cm block by 5 mm and holds. The reference integrator, with the
    nodes the sphere touches prescribed at xpbd's positions for them, gives the reaction at those nodes (their
    internal elastic forces: what the tissue exerts on the tool). Measured: xpbd 2.177 N, reference 2.200 N (-1.05 %:
    xpbd not fully converged at 50 iterations and 10 substeps; -0.4 % with 100 iterations and 80 steps of 0.01 s)."""
    mesh = procedural.box((0.1, 0.1, 0.1), (4, 4, 4))
    model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0, constitutive="stable_neo_hookean")
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    R, depth = 0.2, 0.005
    top = [0.05, 0.05, 0.1 + R]
    model.probes = [Probe("sphere", R, [0.0, 0.3, 0.6], [top, [0.05, 0.05, top[2] - depth], [0.05, 0.05, top[2] - depth]])]
    integrator, state = _settle(model, {"substeps": 10, "iterations": 50, "damping": 10.0}, 40, 0.02)
    force = integrator.tool_loads[0, :3]
    distance = np.linalg.norm(state.x - model.probes[0].position(state.t), axis=1)
    contact = np.flatnonzero(distance < R + 1e-6)  # on the sphere (the next nodes are 0.2 mm off it)
    assert contact.size == 5

    reference_model = Model.from_mesh(mesh, E=1e4, nu=0.3, density=1000.0, constitutive="stable_neo_hookean")
    reference_model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    reference_model.prescribed = [PrescribedDisplacement(np.array([i]), state.x[i] - mesh.points[i]) for i in contact]
    reference = make_integrator("reference", reference_model, {"mode": "quasistatic"})
    x = reference.step(State(x=state.x.copy(), v=np.zeros_like(state.x)), 1.0).x
    reaction = elastic.elastic_forces(reference_model, x)[contact].sum(axis=0)
    assert reaction[2] > 2.0  # the tissue pushes the tool up
    assert force[2] == pytest.approx(reaction[2], rel=0.02)
    assert np.abs(force[:2]).max() < 0.01 * force[2]


def _dynamic(scene_dict):
    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1 / 24, "substeps": 4, "iterations": 4}
    scene_dict["tools"] = [{"name": "probe", "radius": 0.015, "keyframes": [
        {"t": 0.0, "position": [0.04, 0.04, 0.06]}, {"t": 0.2, "position": [0.04, 0.04, 0.01]}]}]
    scene_dict["output"]["frames"] = 3
    return scene_dict


def test_render_writes_tool_forces_per_frame_and_a_resumed_render_rewrites_them_identically(
        scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(_dynamic(scene_dict)))
    out = tmp_path / "out"
    tissuerender.render(scene, out, progress=False)
    text = (out / "tool_forces.csv").read_text()
    rows = list(csv.DictReader(text.splitlines()))
    assert list(rows[0]) == ["frame", "time", "tool", "fx", "fy", "fz", "tx", "ty", "tz"]
    assert [int(r["frame"]) for r in rows] == [1, 2, 3] and {r["tool"] for r in rows} == {"probe"}
    assert [float(r["time"]) for r in rows] == pytest.approx([0.0, 1 / 24, 2 / 24])
    fz = [float(r["fz"]) for r in rows]
    # frame 1: nothing simulated yet; the sphere (on the node column x = y = 0.04 m) reaches the top face z = 0.04 m
    # at t = 0.02 s, in frame 2's interval, and presses deeper in frame 3's: the tissue pushes it up ever harder
    assert fz[0] == 0.0 and 0.0 < fz[1] < fz[2]
    manifest = json.loads((out / "manifest.json").read_text())
    summary = manifest["tool_forces"]
    assert summary["file"] == "tool_forces.csv"
    assert summary["tools"]["probe"]["last_frame"] == 3
    assert summary["tools"]["probe"]["last_force_N"][2] == pytest.approx(fz[2], rel=1e-15)
    assert summary["tools"]["probe"]["peak_frame"] == 3

    (out / "tool_forces.csv").unlink()  # every frame is kept: the resumed render only simulates
    tissuerender.render(scene, out, resume=True, progress=False)
    assert (out / "tool_forces.csv").read_text() == text
