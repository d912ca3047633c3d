"""The blocked (lane-vectorised) XPBD Gauss–Seidel kernel against the straightforward per-tet scalar
kernel (``project_tet``): same positions after several steps, up to rounding."""
from __future__ import annotations

import numba
import numpy as np
import pytest

from sim.integrators.xpbd import blocked
from sim.integrators.xpbd.colouring import split_into_domains
from sim.integrators.xpbd.solver import XPBD
from sim.mesh import procedural, select
from sim.model import Model, State
from sim.probe import Probe


def _slab_with_probe():
    """Soft slab on a fixed base, indented by a sphere moving 4 mm per step; E varies per tet."""
    mesh = procedural.box((0.1, 0.1, 0.03), (4, 4, 2))
    E = np.linspace(3000.0, 9000.0, mesh.n_tets)
    model = Model.from_mesh(mesh, E=E, nu=0.45, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[select.nodes_on_side(mesh.points, 2, "min")] = True
    model.probes = [Probe("sphere", 0.02, times=[0.0, 0.1], positions=[[0.05, 0.05, 0.05], [0.05, 0.05, 0.01]])]
    return model


def _hanging_beam():
    """Cantilever of 1,296 tets (several blocks per colour) sagging under gravity."""
    mesh = procedural.box((0.4, 0.06, 0.06), (24, 3, 3))
    model = Model.from_mesh(mesh, E=2000.0, nu=0.49, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    return model


def _run(model, steps, **settings):
    integrator = XPBD(model, {"substeps": 4, "iterations": 5, **settings})
    state = State.at_rest(model)
    for _ in range(steps):
        state = integrator.step(state, 0.01)
    return state.x


@pytest.mark.parametrize("coupling", ["coupled", "sequential"])
@pytest.mark.parametrize("case, domains", [("probe", 1), ("probe", 2), ("beam", 1), ("beam", 3)])
def test_blocked_kernel_matches_the_scalar_per_tet_kernel(coupling, case, domains):
    model = _slab_with_probe() if case == "probe" else _hanging_beam()
    extra = {"damping": 5.0, "strain_max": 1.05} if case == "probe" else {}
    extra["domains"] = domains
    x_blocked = _run(model, 8, coupling=coupling, kernel="blocked", **extra)
    x_scalar = _run(model, 8, coupling=coupling, kernel="scalar", **extra)
    moved = np.abs(x_scalar - model.X).max()
    assert moved > 2e-3  # the comparison is over a real deformation (cm), not a body at rest
    # 8 steps x 4 substeps x 5 iterations = 160 sweeps; a tet's projection is ~100 flops, each rounding <= U of
    # |x| <= 0.4 m; the coloured Gauss-Seidel iteration is contractive, so the sweeps' differences add at most:
    # 160 x 100 U |x| = 7e-13 m (measured 3e-16 .. 5e-15 m)
    assert np.abs(x_blocked - x_scalar).max() <= 160 * 100 * 2.0**-53 * np.abs(x_scalar).max()
    fixed = model.fixed
    assert np.array_equal(x_blocked[fixed], model.X[fixed])  # w = 0 nodes are not moved by either kernel


@pytest.mark.parametrize("domains", [1, 2])
def test_block_layout_holds_every_tet_once_and_no_node_twice_per_colour(domains):
    model = _hanging_beam()
    xpbd = XPBD(model, {"domains": domains})
    node_index, params, lanes_used, colour_block = xpbd.blocks
    L = blocked.LANES
    seen = []
    for c in range(colour_block.size - 1):
        nodes = []
        for blk in range(colour_block[c], colour_block[c + 1]):
            n = lanes_used[blk]
            assert 0 < n <= L
            idx = node_index[blk].reshape(4, L)
            nodes.append(idx[:, :n].ravel() // 3)
            seen.append(np.sort(idx[:, :n] // 3, axis=0).T)
            pad = params[blk].reshape(blocked.N_ROWS, L)[:, n:]
            assert not pad.any()  # padding lanes: zero B, M and w, so their correction is zero
        nodes = np.concatenate(nodes)
        assert np.unique(nodes).size == nodes.size
    seen = np.concatenate(seen)
    assert seen.shape[0] == model.n_tets
    expected = np.sort(model.tets, axis=1)
    assert np.array_equal(np.unique(seen, axis=0), np.unique(expected, axis=0))


def test_degenerate_tet_gets_no_correction_in_either_kernel():
    # all four nodes of one tet collapsed onto a point: |F| = 0, project_tet returns early; the blocked
    # kernel's select form must leave the nodes where they are (and produce no NaN)
    mesh = procedural.box((0.1, 0.1, 0.1), (1, 1, 1))
    model = Model.from_mesh(mesh, E=3000.0, nu=0.45)
    xpbd = XPBD(model, {})
    x = np.zeros_like(model.X)
    node_index, params, lanes_used, colour_block = xpbd.blocks
    blocked.gauss_seidel_blocked(x, node_index, params, lanes_used, colour_block, xpbd.domain_colour, 1e4, 1, 3, 1)
    assert np.array_equal(x, np.zeros_like(model.X))


def test_domain_interiors_share_no_node_and_the_separator_is_thin():
    model = _hanging_beam()
    parts = split_into_domains(model.X, model.tets, 3)
    assert sum(p.size for p in parts) == model.n_tets
    nodes = [set(model.tets[p].ravel()) for p in parts[:-1]]
    for a in range(3):
        for b in range(a + 1, 3):
            assert not nodes[a] & nodes[b]
    sizes = np.array([p.size for p in parts[:-1]])
    assert parts[-1].size <= 0.1 * model.n_tets  # two cell layers of 24
    assert sizes.max() <= 1.2 * sizes.min()


def _thick_beam():
    """Cantilever of 2,304 tets: colours of up to 9 blocks, which one domain splits into two chunks."""
    mesh = procedural.box((0.4, 0.06, 0.06), (24, 4, 4))
    model = Model.from_mesh(mesh, E=2000.0, nu=0.49, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    return model


@pytest.mark.parametrize("case, domains", [("hanging", 2), ("thick", 1)])
def test_two_threads_give_the_one_thread_result_bit_for_bit(monkeypatch, case, domains):
    """The solver hands ``numba.get_num_threads()`` to the kernel; above one thread the kernel sweeps the domain
    interiors in a prange (two domains) and splits colours of at least 2 x MIN_BLOCKS_PER_THREAD blocks into one
    chunk per thread (one domain: every colour is shared). Both only reorder work between tets that share no
    node, so the positions must equal the one-thread sweep bit for bit.

    The thread count the solver sees is set to 2 whatever numba started with: under NUMBA_NUM_THREADS=1 (the
    suite) the parallel branches run their chunks on one thread; under .ci/run's NUMBA_NUM_THREADS=2 on two."""
    model = _hanging_beam() if case == "hanging" else _thick_beam()
    xpbd = XPBD(model, {"domains": domains})
    colour_block = xpbd.blocks[3]
    if domains == 2:
        assert xpbd.domain_colour.size - 2 == 2  # two domain interiors: the prange over domains runs
    else:
        assert (np.diff(colour_block) >= 2 * blocked.MIN_BLOCKS_PER_THREAD).sum() >= 3  # chunked colours run
    previous = numba.np.ufunc.parallel.get_num_threads()
    results = {}
    try:
        for threads in (1, 2):
            monkeypatch.setattr(numba, "get_num_threads", lambda threads=threads: threads)
            numba.np.ufunc.parallel.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            results[threads] = _run(model, 3, domains=domains)
    finally:
        numba.np.ufunc.parallel.set_num_threads(previous)
    assert np.abs(results[1] - model.X).max() > 1e-4  # the beam sags: a real comparison
    assert np.array_equal(results[1], results[2])
