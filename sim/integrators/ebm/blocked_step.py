"""One EBM substep in one compiled call (``kernel = "blocked"``): prediction 5.13, the sweeps of
``sim.integrators.ebm.blocked`` (or ``blocked_f32``, ``blocked_parallel``), velocities 5.15 and the energy
accounting.

Each run compiles only the variants it uses: ``code``, ``prony``, the precision and the threading are literals, and
:func:`variant` returns compiled closures that pass them as constants.
"""
from __future__ import annotations

import numpy as np
from numba import literally, njit, types
from numba.extending import overload

from sim.constitutive.kernels import ANISOTROPIC_NEO_HOOKEAN, NEO_HOOKEAN
from sim.integrators.ebm.blocked import LANES, N_OUT, OFF_L, OFF_L2, OUT_FF, OUT_W, all_blocks, sweeps
from sim.integrators.ebm.blocked_f32 import all_blocks_f32, sweeps_f32
from sim.integrators.ebm.blocked_parallel import (parallel_lanes, parallel_lanes_f32, sweeps_f32_parallel,
                                                  sweeps_parallel)
from sim.model import ramp_fraction


def _any_sweeps(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
    """:func:`sweeps`, or with ``single`` (a literal) :func:`sweeps_f32`, or with ``parallel`` (a literal) their
    versions on ``chunks`` threads; compiled code only. (A plain ``if single``
    in :func:`step` is not pruned before typing, so the float32 path would be typed for materials it does not
    support.)"""
    raise NotImplementedError("sim.integrators.ebm.blocked._any_sweeps runs in compiled code only")


@overload(_any_sweeps, prefer_literal=True)
def _any_sweeps_variant(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes,
                        free_start, free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, prony, single, parallel)):
        return None
    c, pr = int(code.literal_value), bool(prony.literal_value)
    if bool(single.literal_value) and bool(parallel.literal_value):
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps_f32_parallel(x, X, node_index, params32, out32, corners32, free_nodes, free_start,
                                       free_slot, node_scale, c, iterations, chunks)
    elif bool(single.literal_value):
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps_f32(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                              node_scale, c, iterations)
    elif bool(parallel.literal_value):
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps_parallel(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot,
                                   node_scale, c, pr, relax_a, iterations, chunks)
    else:
        def impl(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes, free_start,
                 free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks):
            return sweeps(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                          c, pr, relax_a, iterations)
    return impl


def _accounting(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                chunks):
    """The energy accounting's lane loop at the positions the sweeps left in the corner rows: ``dW/dx``, ``W`` and
    ``|F|^2`` per tet; returns the flattened output rows (float64, or float32 with ``single``, where it runs the float32
    loop on the displacement rows ``corners32``; with ``parallel``, on ``chunks`` threads). Compiled code only (``code``,
    ``prony``, ``single``, ``parallel`` literals)."""
    raise NotImplementedError("sim.integrators.ebm.blocked._accounting runs in compiled code only")


@overload(_accounting, prefer_literal=True)
def _accounting_variant(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel,
                        relax_a, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, prony, single, parallel)):
        return None
    c, pr = int(code.literal_value), bool(prony.literal_value)
    if bool(single.literal_value) and bool(parallel.literal_value):
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            parallel_lanes_f32(corners32, params32, out32, c, True, chunks)
            return out32.reshape(out32.size)
    elif bool(single.literal_value):
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            all_blocks_f32(corners32, params32, out32, c, True, 0, corners32.shape[0])
            return out32.reshape(out32.size)
    elif bool(parallel.literal_value):
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            parallel_lanes(corners, params, relax, out, c, pr, True, relax_a, chunks)
            return out.reshape(out.size)
    else:
        def impl(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                 chunks):
            all_blocks(corners, params, relax, out, c, pr, True, relax_a, 0, corners.shape[0])
            return out.reshape(out.size)
    return impl


@njit(cache=True)
def step(x_prev, v_prev, x, v, t, h, body, kinematic, blocks, blocks32, code, prony, single, parallel, relax_a,
         iterations, chunks):
    """One EBM step of length ``h`` ending at time ``t``, from (``x_prev``, ``v_prev``) into (``x``, ``v``).

    The arrays come in four tuples (unpacked first; the arithmetic is the same as with separate arguments):
    ``body = (X, f_ext, w, last_load)``; ``kinematic = (kin_nodes, kin_group, kin_displacement, group_t0, group_t1,
    kin_start, kin_slot)``; ``blocks = (node_index, params, relax, out, corners, free_nodes, free_start, free_slot,
    node_scale, n_tets)`` (``sim.integrators.ebm.blocked``); ``blocks32 = (params32, out32, corners32)``.


    1. prediction 5.13, ``x = x_prev + h (v_prev + h f_ext w)``, kinematic nodes at their targets
       (``X + ramp_fraction(t) displacement`` of their prescribed group, the group ramped from ``group_t0`` to
       ``group_t1``; ``kin_group`` -1: fixed at X): the arrays of ``sim.model.KinematicTargets``;
    2. :func:`sweeps`;
    3. velocities ``v = (x - x_prev) / h`` (5.15, our reading);
    4. energy accounting at the new positions: the strain energy, the largest stretch ``|F|_F / sqrt 3`` and
       the work increment of the loads (external forces, plus the reactions ``-f_int`` at kinematic nodes),
       trapezoidal with ``last_load`` (updated in place).

    Returns ``(sweeps done, work increment [J], strain energy [J], largest stretch)``. ``code``, ``prony`` and
    ``single`` are compiled as literals (one specialisation per material and Prony in use). ``single``: the sweeps
    run :func:`sweeps_f32` on ``params32``, ``out32``, ``corners32`` and the accounting's lane loop in float32 on the
    displacement rows the sweeps leave there (positions, prediction, velocities and the sums of the accounting stay
    float64). ``parallel`` (a literal): the sweeps' and the accounting's passes on ``chunks`` threads (bit-identical
    results; the parallel functions compile only for such a variant)."""
    literally(code)
    literally(prony)
    literally(single)
    literally(parallel)
    X, f_ext, w, last_load = body
    kin_nodes, kin_group, kin_displacement, group_t0, group_t1, kin_start, kin_slot = kinematic
    node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale, n_tets = blocks
    params32, out32, corners32 = blocks32
    n = x.shape[0]
    for i in range(n):
        for d in range(3):
            x[i, d] = x_prev[i, d] + h * (v_prev[i, d] + h * f_ext[i, d] * w[i])
    for q in range(kin_nodes.shape[0]):
        i = kin_nodes[q]
        grp = kin_group[q]
        if grp < 0:
            for d in range(3):
                x[i, d] = X[i, d]
        else:
            frac = ramp_fraction(t, group_t0[grp], group_t1[grp])
            for d in range(3):
                x[i, d] = X[i, d] + frac * kin_displacement[q, d]
    done = _any_sweeps(x, X, node_index, params, relax, out, corners, params32, out32, corners32, free_nodes,
                       free_start, free_slot, node_scale, code, prony, single, parallel, relax_a, iterations, chunks)
    for i in range(n):
        for d in range(3):
            v[i, d] = (x[i, d] - x_prev[i, d]) / h
    if done < iterations:
        return done, 0.0, 0.0, 0.0
    # accounting: dW/dx, W and |F|^2 per tet at the new positions (the corners hold them; float32 with single)
    of = _accounting(corners, params, relax, out, corners32, params32, out32, code, prony, single, parallel, relax_a,
                     chunks)
    strain = 0.0
    FF = 0.0
    for t in range(n_tets):
        base = (t // LANES) * (N_OUT * LANES) + t % LANES
        strain += of[base + OUT_W * LANES]
        FF = max(FF, of[base + OUT_FF * LANES])
    # loads: f_ext everywhere, plus the reaction -f_int = sum dW/dx at kinematic nodes
    work = 0.0
    q = 0
    for i in range(n):
        lx = f_ext[i, 0]
        ly = f_ext[i, 1]
        lz = f_ext[i, 2]
        if q < kin_nodes.shape[0] and kin_nodes[q] == i:
            fx = 0.0
            fy = 0.0
            fz = 0.0
            for k in range(kin_start[q], kin_start[q + 1]):
                o = kin_slot[k]
                fx -= of[o]
                fy -= of[o + OFF_L]
                fz -= of[o + OFF_L2]
            lx = -fx + lx
            ly = -fy + ly
            lz = -fz + lz
            q += 1
        work += ((lx + last_load[i, 0]) * (x[i, 0] - x_prev[i, 0]) + (ly + last_load[i, 1]) * (x[i, 1] - x_prev[i, 1])
                 + (lz + last_load[i, 2]) * (x[i, 2] - x_prev[i, 2]))
        last_load[i, 0] = lx
        last_load[i, 1] = ly
        last_load[i, 2] = lz
    return done, 0.5 * work, strain, np.sqrt(FF / 3.0)


_VARIANTS: dict = {}


def variant(code, prony, single=False, parallel=False):
    """``(step, sweeps)`` for one material ``code``, ``prony`` flag, precision (``single``: the float32 sweeps of
    :func:`sweeps_f32`, split models without Prony only) and threading (``parallel``: each pass split over the
    ``chunks`` threads given as the last argument of both, :func:`sweeps_parallel`; the serial variants take and ignore
    it): :func:`step` and :func:`sweeps` (or :func:`sweeps_f32`) without their literal arguments, compiled (on first
    use, cached on disk) for that combination only.

    ``step`` and ``sweeps`` take ``code`` and ``prony`` as literals (``numba.literally``): called from Python with
    plain values, every call would go through the slow literal re-dispatch; these wrappers pass them as
    compile-time constants, so a call costs what an ordinary compiled call does."""
    key = (int(code), bool(prony), bool(single), bool(parallel))
    if single and (prony or key[0] not in (NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN)):
        raise ValueError("ebm: precision float32 supports neo_hookean and anisotropic_neo_hookean without Prony only")
    if key not in _VARIANTS:
        _VARIANTS[key] = _make_variant(*key)
    return _VARIANTS[key]


def _make_variant(code, prony, single, parallel):
    # the closure's constants are part of numba's cache key: one entry per (code, prony, single, parallel)
    @njit(cache=True)
    def step_variant(x_prev, v_prev, x, v, t, h, body, kinematic, blocks, blocks32, relax_a, iterations, chunks):
        return step(x_prev, v_prev, x, v, t, h, body, kinematic, blocks, blocks32, code, prony, single, parallel,
                    relax_a, iterations, chunks)

    if single and parallel:
        @njit(cache=True)
        def sweeps_variant(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                           node_scale, iterations, chunks):
            return sweeps_f32_parallel(x, X, node_index, params32, out32, corners32, free_nodes, free_start,
                                       free_slot, node_scale, code, iterations, chunks)
    elif single:
        @njit(cache=True)
        def sweeps_variant(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                           node_scale, iterations, chunks):
            return sweeps_f32(x, X, node_index, params32, out32, corners32, free_nodes, free_start, free_slot,
                              node_scale, code, iterations)
    elif parallel:
        @njit(cache=True)
        def sweeps_variant(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                           relax_a, iterations, chunks):
            return sweeps_parallel(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot,
                                   node_scale, code, prony, relax_a, iterations, chunks)
    else:
        @njit(cache=True)
        def sweeps_variant(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                           relax_a, iterations, chunks):
            return sweeps(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale,
                          code, prony, relax_a, iterations)

    return step_variant, sweeps_variant
