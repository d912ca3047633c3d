"""sim.numba_inline: numba's inliner with one memo for the callee's IR copy compiles the same code as the stock one."""
from __future__ import annotations

import contextlib
import inspect
import re

import numpy as np
import pytest
from numba import njit
from numba.core import inline_closurecall

from sim import numba_inline
from sim.constitutive.kernels import (ANISOTROPIC_NEO_HOOKEAN, NEO_HOOKEAN, STABLE_NEO_HOOKEAN, STVK,
                                      energy_piola_root)


def test_installed_exactly_when_numba_has_the_stock_copy():
    """Installed on a numba whose ``inline_ir`` holds the per-block copy it replaces (the pinned one), never else."""
    worker = inline_closurecall.InlineWorker
    if numba_inline.installed:
        assert numba_inline.stock_inline_ir is not None and worker.inline_ir is not numba_inline.stock_inline_ir
        stock = inspect.getsource(numba_inline.stock_inline_ir)
        assert "copy.deepcopy(the_ir.blocks[block_label])" in stock
        assert worker.inline_ir.__code__.co_filename == inspect.getsourcefile(numba_inline.stock_inline_ir)
    else:
        assert "copy.deepcopy(the_ir.blocks[block_label])" not in inspect.getsource(worker.inline_ir)


@contextlib.contextmanager
def _stock_inliner():
    worker = inline_closurecall.InlineWorker
    patched = worker.inline_ir
    worker.inline_ir = numba_inline.stock_inline_ir
    try:
        yield
    finally:
        worker.inline_ir = patched


def _lane_kernel():
    """A fresh (uncached) lane loop over every material of energy_piola_root, its helpers inlined."""
    @njit
    def lanes(F, mu, lam, eta, a, out):
        for code_index in range(4):
            for l in range(F.shape[0]):
                f = (F[l, 0], F[l, 1], F[l, 2], F[l, 3], F[l, 4], F[l, 5], F[l, 6], F[l, 7], F[l, 8])
                if code_index == 0:
                    psi, P = energy_piola_root(NEO_HOOKEAN, f, mu, lam, eta, a[0], a[1], a[2], True)
                elif code_index == 1:
                    psi, P = energy_piola_root(ANISOTROPIC_NEO_HOOKEAN, f, mu, lam, eta, a[0], a[1], a[2], True)
                elif code_index == 2:
                    psi, P = energy_piola_root(STABLE_NEO_HOOKEAN, f, mu, lam, eta, a[0], a[1], a[2], False)
                else:
                    psi, P = energy_piola_root(STVK, f, mu, lam, eta, a[0], a[1], a[2], False)
                out[code_index, l, 0] = psi
                for k in range(9):
                    out[code_index, l, k + 1] = P[k]
    return lanes


def _normalised_asm(dispatcher):
    """The compiled function's assembly without the names numba and LLVM give symbols and labels."""
    (asm,) = dispatcher.inspect_asm().values()
    asm = re.sub(r"_ZN[\w$.]+", "SYM", asm)
    asm = re.sub(r"\.L\w+", "LABEL", asm)
    return [line for line in asm.splitlines() if line.strip() and not line.lstrip().startswith((".", "#"))]


@pytest.mark.skipif(not numba_inline.installed, reason="the stock inliner is in use: nothing to compare")
def test_same_machine_code_and_bit_identical_results_as_the_stock_inliner():
    rng = np.random.default_rng(3)
    F = np.eye(3).ravel() + 0.2 * rng.standard_normal((37, 9))
    a = np.array([0.6, 0.0, 0.8])
    results, asm = [], []
    for stock in (True, False):
        with _stock_inliner() if stock else contextlib.nullcontext():
            kernel = _lane_kernel()
            out = np.zeros((4, 37, 10))
            kernel(F, 3000.0, 20000.0, 500.0, a, out)
        results.append(out)
        asm.append(_normalised_asm(kernel))
    assert np.isfinite(results[0]).all() and np.abs(results[0]).max() > 100.0  # the energies and stresses are there
    assert np.array_equal(results[0].view(np.uint64), results[1].view(np.uint64))
    assert len(asm[0]) > 500 and asm[0] == asm[1]
