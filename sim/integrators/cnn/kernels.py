"""Numba kernels of the CNN energy propagation (Zhang §4.1–4.2, ``sim.integrators.cnn.energy``): the forward-Euler
sub-steps of the three-layer potential (4.12 with the templates of 4.24) on a CSR template matrix, and the
nodal forces of the potential (4.28–4.30, signed). Scalar loops, no allocation inside them; the NumPy
code in ``sim.integrators.cnn.energy`` (``kernel = "numpy"``) is the reference they are tested against
(tests/sim/integrators/ebm/test_kernels.py). No ``fastmath``: the sums must match the reference to rounding.
"""
from __future__ import annotations

from numba import njit


@njit(cache=True)
def euler_substeps(phi, scratch, indptr, indices, data, Q, fixed, h, n):
    """``n`` forward-Euler sub-steps ``phi <- phi + h (A phi - Q)`` of the CNN array (Zhang 4.12, 4.22 with
    4.24) on free cells; fixed-state cells keep their value (4.26). ``A`` is CSR (``indptr, indices,
    data``); ``phi`` and ``scratch`` are (n_nodes, 3); the result is left in ``phi``."""
    n_nodes = phi.shape[0]
    src = phi
    dst = scratch
    for _ in range(n):
        for i in range(n_nodes):
            if fixed[i]:
                dst[i, 0] = src[i, 0]
                dst[i, 1] = src[i, 1]
                dst[i, 2] = src[i, 2]
                continue
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                a = data[k]
                c = indices[k]
                r0 += a * src[c, 0]
                r1 += a * src[c, 1]
                r2 += a * src[c, 2]
            dst[i, 0] = src[i, 0] + h * (r0 - Q[i, 0])
            dst[i, 1] = src[i, 1] + h * (r1 - Q[i, 1])
            dst[i, 2] = src[i, 2] + h * (r2 - Q[i, 2])
        src, dst = dst, src
    if n % 2 == 1:  # the last sub-step wrote into scratch
        phi[:, :] = scratch


@njit(cache=True)
def potential_forces(phi, direction, x, edges, edge_S, edge_w, gain, along_edges, fixed, f):
    """Nodal forces of the potential, written into ``f`` (n, 3) [N] (Zhang 4.28–4.30 with the signed
    difference of ``psi = phi . d``): per edge (i, j), ``fe = g (psi_j - psi_i) / 2 S_ij`` (median-dual
    form) or ``fe = g w_ij (psi_j - psi_i) / |x_j - x_i|^2 (x_j - x_i)`` (``along_edges``: 4.29 as written),
    added to both ends; zero on fixed cells."""
    f[:] = 0.0
    d0, d1, d2 = direction[0], direction[1], direction[2]
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        dpsi = (phi[j, 0] * d0 + phi[j, 1] * d1 + phi[j, 2] * d2) - (phi[i, 0] * d0 + phi[i, 1] * d1 + phi[i, 2] * d2)
        if along_edges:
            v0 = x[j, 0] - x[i, 0]
            v1 = x[j, 1] - x[i, 1]
            v2 = x[j, 2] - x[i, 2]
            s = gain * edge_w[e] * dpsi / (v0 * v0 + v1 * v1 + v2 * v2)
        else:
            v0 = edge_S[e, 0]
            v1 = edge_S[e, 1]
            v2 = edge_S[e, 2]
            s = 0.5 * gain * dpsi
        f[i, 0] += s * v0
        f[i, 1] += s * v1
        f[i, 2] += s * v2
        f[j, 0] += s * v0
        f[j, 1] += s * v1
        f[j, 2] += s * v2
    for i in range(f.shape[0]):
        if fixed[i]:
            f[i, 0] = 0.0
            f[i, 1] = 0.0
            f[i, 2] = 0.0
