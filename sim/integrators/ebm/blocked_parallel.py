"""The blocked EBM sweeps on several threads (large meshes; settings-independent: ``sim.integrators.ebm`` picks
this path from ``blocked.PARALLEL_MIN_TETS`` tets when numba has more than one thread).

Both passes of a sweep are race-free: a block writes only its own output rows, a node only its own position and its
own corner slots. So each pass is split into one contiguous chunk per thread (blocks for the lane pass, free nodes for
the node pass, balanced by incidence count), each chunk running the serial code on its range: every tet and every
node sum is computed by the same instructions in the same order, and the positions are bit-identical whatever the
number of threads (tests/sim/integrators/test_threads.py). The parallel functions are compiled only when a run takes
this path.
"""
from __future__ import annotations

import numpy as np
from numba import literally, njit, prange, types
from numba.extending import overload

from sim.integrators.ebm.blocked import all_blocks, load_corners, node_range
from sim.integrators.ebm.blocked_f32 import all_blocks_f32, load_displacements_f32, nan_denominators_f32, node_range_f32


@njit(cache=True, inline="always")
def _chunk_bounds(free_start, n_free, ch, chunks):
    """First and one-past-last free node of chunk ``ch`` of ``chunks``: consecutive nodes with about the same number
    of incidences."""
    total = free_start[n_free]
    q0 = min(np.searchsorted(free_start, total * ch // chunks), n_free)
    q1 = n_free if ch + 1 >= chunks else min(np.searchsorted(free_start, total * (ch + 1) // chunks), n_free)
    return q0, q1


@njit(cache=True, parallel=True)
def node_pass_parallel(x, out, corners, free_nodes, free_start, free_slot, node_scale, chunks):
    """:func:`sweeps`'s node pass in ``chunks`` ranges of free nodes, one per thread; False when a position is
    non-finite."""
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    n_free = free_nodes.shape[0]
    ok = np.ones(chunks, np.bool_)
    for ch in prange(chunks):
        q0, q1 = _chunk_bounds(free_start, n_free, ch, chunks)
        ok[ch] = node_range(x, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1)
    return ok.all()


_LANE_PASSES: dict = {}


def lane_pass_parallel(code, prony, forces, single=False):
    """A compiled ``(corners, params, relax, out, relax_a, chunks) -> NaN multipliers`` (float32 with ``single``:
    ``(corners, params, out, chunks) -> 0``) that runs the lane loop of one (material, Prony, forces) over the blocks
    in ``chunks`` contiguous ranges, one per thread (the constants are the closure's, so each compiles on first use
    and is cached on disk, as :func:`variant`)."""
    key = (int(code), bool(prony), bool(forces), bool(single))
    if key not in _LANE_PASSES:
        c, pr, fo = key[:3]
        if single:
            @njit(cache=True, parallel=True)
            def lane_pass(corners, params, out, chunks):
                nb = corners.shape[0]
                for ch in prange(chunks):
                    all_blocks_f32(corners, params, out, c, fo, nb * ch // chunks, nb * (ch + 1) // chunks)
                return 0
        else:
            @njit(cache=True, parallel=True)
            def lane_pass(corners, params, relax, out, relax_a, chunks):
                nb = corners.shape[0]
                bad = np.zeros(chunks, np.int64)
                for ch in prange(chunks):
                    bad[ch] = all_blocks(corners, params, relax, out, c, pr, fo, relax_a, nb * ch // chunks,
                                          nb * (ch + 1) // chunks)
                return bad.sum()
        _LANE_PASSES[key] = lane_pass
    return _LANE_PASSES[key]


def parallel_lanes(corners, params, relax, out, code, prony, forces, relax_a, chunks):
    """:func:`lane_pass_parallel`'s pass for literal (``code``, ``prony``, ``forces``); compiled code only."""
    raise NotImplementedError("sim.integrators.ebm.blocked.parallel_lanes runs in compiled code only")


@overload(parallel_lanes, prefer_literal=True)
def _parallel_lanes_variant(corners, params, relax, out, code, prony, forces, relax_a, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, prony, forces)):
        return None
    lane_pass = lane_pass_parallel(int(code.literal_value), bool(prony.literal_value), bool(forces.literal_value))

    def impl(corners, params, relax, out, code, prony, forces, relax_a, chunks):
        return lane_pass(corners, params, relax, out, relax_a, chunks)

    return impl


def parallel_lanes_f32(corners, params, out, code, forces, chunks):
    """:func:`lane_pass_parallel`'s float32 pass for literal (``code``, ``forces``); compiled code only."""
    raise NotImplementedError("sim.integrators.ebm.blocked.parallel_lanes_f32 runs in compiled code only")


@overload(parallel_lanes_f32, prefer_literal=True)
def _parallel_lanes_f32_variant(corners, params, out, code, forces, chunks):
    if not all(isinstance(a, types.Literal) for a in (code, forces)):
        return None
    lane_pass = lane_pass_parallel(int(code.literal_value), False, bool(forces.literal_value), single=True)

    def impl(corners, params, out, code, forces, chunks):
        return lane_pass(corners, params, out, chunks)

    return impl


@njit(cache=True)
def sweeps_parallel(x, node_index, params, relax, out, corners, free_nodes, free_start, free_slot, node_scale, code,
                    prony, relax_a, iterations, chunks):
    """:func:`sweeps` with each pass split over ``chunks`` threads (bit-identical results)."""
    literally(code)
    literally(prony)
    load_corners(x, node_index, corners)
    for it in range(iterations):
        bad = parallel_lanes(corners, params, relax, out, code, prony, False, relax_a, chunks)
        finite = node_pass_parallel(x, out, corners, free_nodes, free_start, free_slot, node_scale, chunks)
        if not (finite and bad == 0):
            return it
    return iterations


@njit(cache=True, parallel=True)
def node_pass_f32_parallel(x, X, out, corners, free_nodes, free_start, free_slot, node_scale, chunks):
    """:func:`sweeps_f32`'s node pass in ``chunks`` ranges of free nodes, one per thread; False when a position is
    non-finite."""
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    n_free = free_nodes.shape[0]
    ok = np.ones(chunks, np.bool_)
    for ch in prange(chunks):
        q0, q1 = _chunk_bounds(free_start, n_free, ch, chunks)
        ok[ch] = node_range_f32(x, X, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1)
    return ok.all()


@njit(cache=True)
def sweeps_f32_parallel(x, X, node_index, params, out, corners, free_nodes, free_start, free_slot, node_scale, code,
                        iterations, chunks):
    """:func:`sweeps_f32` with each pass split over ``chunks`` threads (bit-identical results)."""
    literally(code)
    load_displacements_f32(x, X, node_index, corners)
    for it in range(iterations):
        parallel_lanes_f32(corners, params, out, code, False, chunks)
        if not node_pass_f32_parallel(x, X, out, corners, free_nodes, free_start, free_slot, node_scale, chunks):
            return it
    if iterations > 0 and nan_denominators_f32(out) > 0:
        return iterations - 1
    return iterations
