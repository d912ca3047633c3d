"""EBM (float64, float32), CNN, explicit and XPBD on two threads: the positions do not depend on the thread count.

Large meshes take the parallel kernels (sim.integrators.ebm.blocked: each sweep's lane pass over blocks and node pass over free
nodes split into one chunk per thread; sim.force_kernels.forces_and_energy_parallel: per-tet corner forces, then a
per-node gather in tet order). Every tet and every node sum is computed by the same code in the same order whatever the
chunking, so 1 and 2 threads must agree bit for bit, and with the serial kernels too.

The integrators read the thread count from ``numba.get_num_threads()``; the tests set it to 2 even when numba was
started with one thread (NUMBA_NUM_THREADS=1, as the suite runs), so the parallel path and its two chunks run either
way (on one thread then: the result cannot depend on how the chunks are scheduled, only on the chunking).
XPBD's default settings are also built under the start-up thread count ``numba.config.NUMBA_NUM_THREADS`` of a
one-thread and a two-thread worker: nothing in its defaults (the sweep order: ``domains``) may follow it.
"""
from __future__ import annotations

import numba
import numpy as np
import pytest

from sim.constitutive import force_kernels
from sim.integrators import make_integrator
from sim.integrators.ebm import blocked as ebm_blocked
from sim.mesh import procedural, select
from sim.model import Model, State
from sim.probe import Probe

STARTUP_THREADS = numba.config.NUMBA_NUM_THREADS  # the size of numba's thread pool in this process


def _beam(cells, constitutive="stable_neo_hookean") -> Model:
    """The throughput benchmark's beam (x = 0 face fixed, gravity), 6 tets per cell."""
    mesh = procedural.box((2.0, 0.2, 0.2), cells)
    model = Model.from_mesh(mesh, E=3000.0, nu=0.49, density=1000.0, gravity=np.array([0.0, 0.0, -9.81]),
                            constitutive=constitutive)
    model.fixed[select.nodes_on_side(mesh.points, 0, "min")] = True
    return model


LARGE = (24, 4, 4)  # 2,304 tets: above both kernels' PARALLEL_MIN_TETS


def _run(monkeypatch, name, model, settings, threads, steps=3, dt=1e-3):
    """Positions after ``steps`` steps with ``threads`` numba threads (as the integrator sees them)."""
    monkeypatch.setattr(numba, "get_num_threads", lambda: threads)
    previous = numba.np.ufunc.parallel.get_num_threads()
    numba.np.ufunc.parallel.set_num_threads(min(threads, STARTUP_THREADS))
    try:
        integrator = make_integrator(name, model, settings)
        state = State.at_rest(model)
        for _ in range(steps):
            state = integrator.step(state, dt)
    finally:
        numba.np.ufunc.parallel.set_num_threads(previous)
    return integrator, state.x


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_ebm_positions_do_not_depend_on_the_thread_count(monkeypatch, precision):
    model = _beam(LARGE, "neo_hookean" if precision == "float32" else "stable_neo_hookean")
    assert model.n_tets >= ebm_blocked.PARALLEL_MIN_TETS
    settings = {"substeps": 2, "iterations": 10, "precision": precision}
    runs = {}
    for threads in (1, 2, 3):
        integrator, runs[threads] = _run(monkeypatch, "ebm", model, settings, threads)
        assert integrator._blocked_kernels()[2] == threads  # 1: the serial kernel; 2, 3: the parallel one
    sag = np.abs(runs[1] - model.X).max()
    assert 1e-6 < sag < 0.1  # the beam moved (gravity), finitely
    for threads in (2, 3):
        assert np.array_equal(runs[threads], runs[1])


def test_ebm_small_meshes_keep_the_serial_kernel(monkeypatch):
    model = _beam((14, 3, 2))  # 504 tets
    assert model.n_tets < ebm_blocked.PARALLEL_MIN_TETS
    integrator, _ = _run(monkeypatch, "ebm", model, {"substeps": 1, "iterations": 2}, 2, steps=1)
    assert integrator._blocked_kernels()[2] == 1


@pytest.mark.parametrize("name", ["cnn", "explicit"])
def test_constitutive_forces_do_not_depend_on_the_thread_count(monkeypatch, name):
    model = _beam(LARGE)
    assert model.n_tets >= force_kernels.PARALLEL_MIN_TETS
    runs = {}
    for threads in (1, 2):
        integrator, runs[threads] = _run(monkeypatch, name, model, {"substeps": 10}, threads)
        assert integrator.accel._threads() == threads
    sag = np.abs(runs[1] - model.X).max()
    assert 1e-7 < sag < 0.1
    assert np.array_equal(runs[2], runs[1])


@pytest.mark.parametrize("probe", [False, True])
def test_xpbd_default_positions_do_not_depend_on_the_thread_count(monkeypatch, probe):
    """The same scene on a one-thread and a two-thread worker: XPBD with its default settings (no ``domains``) built
    and stepped under NUMBA_NUM_THREADS = 1 and 2 gives the same bytes. With a probe pressing on the beam the
    substeps run in the fused sweeps (sim.integrators.xpbd.sweeps), without one in the blocked kernel's launches."""
    model = _beam(LARGE)
    if probe:  # a sphere touching the beam's top face near its free end, pressing 1 cm down during the 3 steps
        model.probes = [Probe("sphere", 0.1, times=[0.0, 0.003], positions=[[1.5, 0.1, 0.3], [1.5, 0.1, 0.29]])]
    runs = {}
    for threads in (1, 2):
        monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", threads)  # as a worker started with that many
        integrator, runs[threads] = _run(monkeypatch, "xpbd", model, {}, threads)
        assert integrator.domain_colour.size - 2 > 1  # several domain interiors: the parallel sweep runs
        assert (integrator.fused is not None) == probe
    sag = np.abs(runs[1] - model.X).max()
    assert 1e-6 < sag < 0.1
    assert runs[2].tobytes() == runs[1].tobytes()


def test_parallel_forces_equal_the_serial_kernel_bit_for_bit():
    """The per-tet pass and the per-node gather add the scatter's terms in the scatter's order: forces, energy and
    stretch equal forces_and_energy's exactly, on a deformed anisotropic mesh."""
    rng = np.random.default_rng(3)
    model = _beam((6, 2, 2), "anisotropic_neo_hookean")
    x = model.X + rng.normal(scale=0.01, size=model.X.shape)
    accel = make_integrator("explicit", model, {}).accel
    args = accel._kernel_args
    f0 = np.empty_like(x)
    f1 = np.empty_like(x)
    e0, s0 = force_kernels.forces_and_energy(x, f0, *args)
    assert np.abs(f0).max() > 0.0
    for chunks in (1, 2, 5):
        e1, s1 = force_kernels.forces_and_energy_parallel(x, f1, *args, *accel._scratch(), chunks)
        assert np.array_equal(f0, f1)
        assert (e0, s0) == (e1, s1)
    assert force_kernels.count_inverted_parallel(x, accel._tets) == force_kernels.count_inverted(x, accel._tets)
