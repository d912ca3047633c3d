"""Mesh tools that turn (issue 21 item 4; sim.contact_bodies.MeshProbe, docs/interaction.md "Mesh tools"): the
keyframes' orientations turn the tool's surface about its path point, in the push-out, the tool's load and the
drawing."""
from __future__ import annotations

import numpy as np
import pytest

from sim.contact_bodies import MeshProbe
from sim.integrators.xpbd.solver import XPBD
from sim.mesh import procedural
from sim.mesh.types import TetMesh
from sim.model import Model, State
from sim.pose import quat_matrix

HALF = 0.035  # the cube tool's half side [m]
SIDE, HEIGHT = 0.16, 0.04  # the block: 16 x 16 x 4 cells of 1 cm


def _cube(half: float) -> tuple[np.ndarray, np.ndarray]:
    """A cube of half side ``half`` centred on the origin: 8 corners, 12 outward triangles."""
    points = half * np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                              [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                      [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]], dtype=np.int64)
    return points, faces


def _about_z(degrees: float) -> np.ndarray:
    half = np.radians(degrees) / 2.0
    return np.array([np.cos(half), 0.0, 0.0, np.sin(half)])


def _press(centre_xy, degrees: float | None, turn_world: float = 0.0, steps: int = 10):
    """The cube (turned ``degrees`` about z; None: no orientation given) lowered from touching the clamped block's
    top to 5 mm into it over 0.1 s. ``turn_world``: the whole setup (block, path, tool) turned that many degrees about
    the z axis through the origin. Returns (model, integrator, state, centre at the end, tool rotation)."""
    mesh = procedural.box((SIDE, SIDE, HEIGHT), (16, 16, 4))
    W = quat_matrix(_about_z(turn_world))
    model = Model.from_mesh(TetMesh(mesh.points @ W.T, mesh.tets) if turn_world else mesh,
                            E=1e4, nu=0.3, density=1000.0)
    model.fixed[mesh.points[:, 2] < 1e-9] = True
    path = np.array([[*centre_xy, HEIGHT + HALF], [*centre_xy, HEIGHT - 0.005 + HALF]]) @ W.T
    points, faces = _cube(HALF)
    orientations = None
    if degrees is not None or turn_world:
        q = _about_z(turn_world + (degrees or 0.0))
        orientations = [q, q]
    model.probes = [MeshProbe(points, faces, [0.0, 0.1], path, orientations=orientations)]
    integrator = XPBD(model, {"substeps": 10, "iterations": 8, "damping": 10.0, "domains": 1})
    state = State.at_rest(model)
    for k in range(steps):
        state.t = k * 0.01
        state = integrator.step(state, 0.01)
    return model, integrator, state, path[-1], model.probes[0].rotation(0.1)


def test_a_cube_turned_45_degrees_leaves_no_node_inside_and_presses_a_diamond():
    model, _, state, centre, R = _press((0.08, 0.08), 45.0)
    local = (state.x - centre) @ R  # R^T (x - c): the nodes in the tool frame
    depth = np.where((np.abs(local) < HALF).all(axis=1), (HALF - np.abs(local)).min(axis=1), 0.0)
    # the tool's projection runs last in every sweep, so the nodes end on its surface up to the rounding of a few
    # operations on 0.1 m coordinates (1e-16 m each); 1e-12 m leaves room for the grid's
    assert depth.max() < 1e-12
    # the imprint: the top nodes pressed to the cube's bottom face (z = 3.5 cm) are those under the turned square (a
    # diamond in the world: |u|, |v| <= HALF in the tool frame). Pressed: within 1 um of the face (a node under it
    # but outside the tool is pulled below it by its neighbours in the last sweep, not pushed back: measured 3e-7 m);
    # not pressed: more than 1 mm above it (measured 2.4 mm and more)
    top = np.flatnonzero(np.abs(model.X[:, 2] - HEIGHT) < 1e-9)
    offset = model.X[top, :2] - 0.08
    u = np.abs(offset @ R[:2, :2]).max(axis=1)  # rest positions in the tool frame: the diamond is u <= HALF
    dz = state.x[top, 2] - (centre[2] - HALF)
    pressed, free = np.abs(dz) < 1e-6, dz > 1e-3
    assert (pressed | free).all()
    np.testing.assert_array_equal(pressed, u < HALF)  # no rest node lies within 2 mm of the outline
    # the corners of the unturned square, at offsets (+-3, +-3) cm (inside |dx|, |dy| <= 3.5 cm, outside the diamond:
    # u = 4.2 cm), stand free; the diamond's tips at (+-4, 0) and (0, +-4) cm (outside the unturned square) are pressed
    corners = (np.abs(np.abs(offset) - 0.03) < 1e-9).all(axis=1)
    tips = (np.abs(np.abs(offset).max(axis=1) - 0.04) < 1e-9) & (np.abs(offset).min(axis=1) < 1e-9)
    assert corners.sum() == 4 and free[corners].all()
    assert tips.sum() == 4 and pressed[tips].all()


def test_turning_the_whole_setup_turns_the_tool_force_and_torque_about_the_path_point():
    # the same press, off the block's centre (its torque about the path point is not zero), computed once as is and
    # once with block, path and tool turned 30 degrees about z: positions, force and torque must turn with them.
    # Turned coordinates round differently (a few ulps of 0.1 m, 1e-17 m, per operation), and the 6 x 10 x 8 sweeps
    # carry that rounding along (a contraction) without amplifying it: measured 2.3e-15 m in the positions and 5e-14
    # of the load in force and torque; 1e-13 m and 1e-11 leave margins of 40 and 200
    _, plain, state, _, _ = _press((0.1, 0.07), None, steps=6)
    _, turned, state_turned, _, _ = _press((0.1, 0.07), None, turn_world=30.0, steps=6)
    W = quat_matrix(_about_z(30.0))
    np.testing.assert_allclose(state_turned.x, state.x @ W.T, rtol=0, atol=1e-13)
    force, torque = plain.tool_loads[0, :3], plain.tool_loads[0, 3:]
    assert force[2] > 0.1 and np.linalg.norm(torque) > 1e-3 * np.linalg.norm(force) * HALF
    scale = np.linalg.norm(force)
    np.testing.assert_allclose(turned.tool_loads[0, :3], W @ force, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(turned.tool_loads[0, 3:], W @ torque, rtol=0, atol=1e-11 * scale * HALF)
