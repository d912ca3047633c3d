"""A static surface's finer contact grid (``SurfaceContactState.static_cell_split``, issue 21 performance) changes which
triangles a node's box tests visit, not the result: a block sliding down a tessellated incline steps bit for bit the
same with the grid split 3 times finer as with the boxes' own cell."""
import numpy as np

from sim.contact_bodies import SurfaceContact, SurfaceContactState
from sim.integrators import make_integrator
from sim.mesh import procedural
from sim.model import Model, State


def _incline(n=8, theta=np.radians(20.0)):
    """A 0.4 m square through the origin in n x n cells of two triangles each, tilted by theta about y (upward)."""
    u = np.linspace(-0.2, 0.2, n + 1)
    gx, gy = np.meshgrid(u, u, indexing="ij")
    rot = np.array([[np.cos(theta), 0.0, np.sin(theta)], [0.0, 1.0, 0.0], [-np.sin(theta), 0.0, np.cos(theta)]])
    points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1) @ rot.T
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()  # lower-left vertex of each cell
    faces = np.concatenate([np.stack([k, k + n + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + 1], 1)])
    return points, faces, rot


def _run(split, steps=15):
    SurfaceContactState.static_cell_split = split
    points, faces, rot = _incline()
    mesh = procedural.box((0.1, 0.1, 0.1), (2, 2, 2), origin=(-0.05, -0.05, 0.002))
    mesh.points = mesh.points @ rot.T
    model = Model.from_mesh(mesh, E=1e5, nu=0.3, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    model.contacts = [SurfaceContact(np.arange(model.n_nodes), faces, points, friction=0.2)]
    integrator = make_integrator("xpbd", model, {"substeps": 4, "iterations": 6})
    state = State.at_rest(model)
    loads = []
    for _ in range(steps):
        state = integrator.step(state, 0.01)
        loads.append(integrator.contact_loads.copy())
    return integrator.contacts[0], state, np.array(loads), rot


def test_a_finer_static_grid_steps_bit_for_bit_the_same():
    try:
        coarse, a, loads_a, rot = _run(1)
        fine, b, loads_b, _ = _run(3)
    finally:
        SurfaceContactState.static_cell_split = 3
    assert np.prod(fine.dims) > 8 * np.prod(coarse.dims)  # the split took effect
    # fewer triangle entries per cell: what the box tests scan
    assert fine.items.size / np.prod(fine.dims) < 0.5 * coarse.items.size / np.prod(coarse.dims)
    assert np.count_nonzero(loads_a[-5:, 0, 2]) == 5 and loads_a[-1, 0, 2] < 0.0  # resting on it: real contact
    assert np.array_equal(a.x, b.x) and np.array_equal(a.v, b.v)
    assert np.array_equal(loads_a, loads_b)
