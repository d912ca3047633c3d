"""Single-precision blocked EBM sweeps (settings ``precision = "float32"``): the split models only, without Prony.

The lane loop runs on float32 (16 lanes per zmm register instead of 8), in the sweeps and in the energy accounting;
the node pass adds a node's increments two at a time in float32 and accumulates these pair sums in float64 (the
choice against whole float32 or whole float64 sums is measured in docs/ebm.md#how-fast-and-why); positions, the
prediction, the velocities and the accounting's sums stay float64. The corner rows hold the displacements
u = x - X (float32), so that H = F - I = (u_k - u_0) b_k comes without the cancellation of F - I in single precision.
:func:`_split_model_f32` is ``sim.integrators.ebm.blocked._split_model`` in float32 and :func:`node_range_f32`
repeats ``blocked.node_range``'s write-back: both kept separate for speed (docs/ebm.md#how-fast-and-why).
"""
from __future__ import annotations

import numpy as np
from numba import literally, njit, types
from numba.core.errors import TypingError
from numba.extending import overload

from sim.constitutive.kernels import ANISOTROPIC_NEO_HOOKEAN, NEO_HOOKEAN
from sim.integrators.ebm.blocked import (LANES, N_OUT, OFF_L, OFF_L2, OFF_Y, OFF_Z, OUT_D, OUT_FF, OUT_W, ROW_B,
                                         ROW_ETA, ROW_FIBRE, ROW_FIBRE_NORM, ROW_KAPPA, ROW_MU, ROW_VOLUME, ROW_W)

_F32_ONE = np.float32(1.0)
_F32_TWO = np.float32(2.0)
_F32_THREE = np.float32(3.0)
_F32_HALF = np.float32(0.5)
_F32_THIRD = np.float32(1.0 / 3.0)
_F32_TWO_THIRDS = np.float32(2.0 / 3.0)
_F32_C2 = np.float32(2.0 / 9.0)
_F32_C3 = np.float32(14.0 / 81.0)
_F32_TINY = np.float32(1e-37)  # "at rest to the last bit": no increment (float32's smallest normal is 1.2e-38)
_F32_NAN = np.float32(np.nan)
_F32_ZERO = np.float32(0.0)
_INV_CBRT_MAGIC_F32 = np.float32((4.0 / 3.0 * 127.0 - 0.066) * 2.0 ** 23)


@njit(cache=True, inline="always")
def _inverse_cube_root_f32(J):
    """J^(-1/3) in float32 as ``sim.constitutive.kernels.inverse_cube_root`` (exponent-bit seed within 3.4 %, two quartic
    steps); NaN for J <= 0."""
    y = np.int32(_INV_CBRT_MAGIC_F32 - np.float32(np.float32(J).view(np.int32)) * _F32_THIRD).view(np.float32)
    for _ in range(2):
        r = _F32_ONE - J * (y * y * y)
        y = y + y * r * (_F32_THIRD + r * (_F32_C2 + r * _F32_C3))
    return y if J > _F32_ZERO else _F32_NAN


@njit(cache=True, inline="always")
def _split_model_f32(h00, h01, h02, h10, h11, h12, h20, h21, h22, mu, kappa, eta, ax, ay, az, a0_norm, fibre):
    """``sim.integrators.ebm.blocked._split_model`` in float32 from H (every operand float32); kept for the
    float32 lane loop's speed (docs/ebm.md#how-fast-and-why)."""
    f00, f11, f22 = h00 + _F32_ONE, h11 + _F32_ONE, h22 + _F32_ONE
    f01, f02, f10, f12, f20, f21 = h01, h02, h10, h12, h20, h21
    c00 = h11 * h22 - f21 * f12
    c01 = f12 * f20 - h22 * f10
    c02 = f10 * f21 - f20 * h11
    c10 = f21 * f02 - f01 * h22
    c11 = h22 * h00 - f02 * f20
    c12 = f20 * f01 - h00 * f21
    c20 = f01 * f12 - h11 * f02
    c21 = f02 * f10 - f12 * h00
    c22 = h00 * h11 - f10 * f01
    tr = h00 + h11 + h22
    I2 = c00 + c11 + c22
    detH = h00 * c00 + f01 * c01 + f02 * c02
    j = tr + I2 + detH
    J = _F32_ONE + j
    HH = (h00 * h00 + f01 * f01 + f02 * f02 + f10 * f10 + h11 * h11 + f12 * f12 + f20 * f20 + f21 * f21
          + h22 * h22)
    d = _F32_TWO * tr + HH
    C00 = _F32_ONE + (h11 + h22) + c00
    C11 = _F32_ONE + (h00 + h22) + c11
    C22 = _F32_ONE + (h00 + h11) + c22
    C01, C02, C12 = c01 - f10, c02 - f20, c12 - f21
    C10, C20, C21 = c10 - f01, c20 - f02, c21 - f12
    y = _inverse_cube_root_f32(J)
    y2 = y * y
    inv_J = y2 * y
    Q = y2 + y + _F32_ONE
    N = -j * inv_J * (y + _F32_ONE)
    a = mu * y2
    b = a * (_F32_THREE + d) * _F32_THIRD * inv_J
    s = kappa * j - b
    num = _F32_HALF * mu * ((_F32_THREE + d) * N + d * Q) + _F32_HALF * kappa * j * j * Q
    if fibre:
        fa0 = f00 * ax + f01 * ay + f02 * az
        fa1 = f10 * ax + f11 * ay + f12 * az
        fa2 = f20 * ax + f21 * ay + f22 * az
        I4 = fa0 * fa0 + fa1 * fa1 + fa2 * fa2
        ha0, ha1, ha2 = h00 * ax + h01 * ay + h02 * az, h10 * ax + h11 * ay + h12 * az, h20 * ax + h21 * ay + h22 * az
        q = _F32_TWO * (ax * ha0 + ay * ha1 + az * ha2) + ha0 * ha0 + ha1 * ha1 + ha2 * ha2 + a0_norm
        D = (_F32_ONE + q) * N + q * Q
        num = num * Q + _F32_HALF * eta * D * D
        den = Q * Q
        e = eta * (y2 * I4 - _F32_ONE) * y2
        s = s - e * _F32_TWO_THIRDS * I4 * inv_J
        e2 = _F32_TWO * e
        u0, u1, u2 = e2 * fa0, e2 * fa1, e2 * fa2
        P = (a * f00 + s * C00 + u0 * ax, a * f01 + s * C01 + u0 * ay, a * f02 + s * C02 + u0 * az,
             a * f10 + s * C10 + u1 * ax, a * f11 + s * C11 + u1 * ay, a * f12 + s * C12 + u1 * az,
             a * f20 + s * C20 + u2 * ax, a * f21 + s * C21 + u2 * ay, a * f22 + s * C22 + u2 * az)
        return num, den, P
    P = (a * f00 + s * C00, a * f01 + s * C01, a * f02 + s * C02,
         a * f10 + s * C10, a * f11 + s * C11, a * f12 + s * C12,
         a * f20 + s * C20, a * f21 + s * C21, a * f22 + s * C22)
    return num, Q, P


@njit(cache=True, inline="always")
def _lanes_f32(fibre, forces, c, p, out, blk, lanes):
    """The lane loop in float32 (``c``: displacement rows u = x - X). Sweep (``forces`` False): writes
    ``-lambda' g_k`` (the node pass multiplies by w_k) and the denominators (row ``OUT_W``: the caller counts the NaN
    ones in a separate pass; a counter in the loop would make it a reduction, or with 64 bits cap the vector width
    at 8 lanes). Forces (the energy accounting of a float32 step): ``dW/dx_k = V P b_k``, ``W = V Psi`` and
    ``|F|^2``, as :func:`_lanes` with ``forces``."""
    for l in range(lanes):
        b10, b11, b12 = p[blk, (ROW_B + 0) * LANES + l], p[blk, (ROW_B + 1) * LANES + l], p[blk, (ROW_B + 2) * LANES + l]
        b20, b21, b22 = p[blk, (ROW_B + 3) * LANES + l], p[blk, (ROW_B + 4) * LANES + l], p[blk, (ROW_B + 5) * LANES + l]
        b30, b31, b32 = p[blk, (ROW_B + 6) * LANES + l], p[blk, (ROW_B + 7) * LANES + l], p[blk, (ROW_B + 8) * LANES + l]
        x0, y0, z0 = c[blk, 0 * LANES + l], c[blk, 1 * LANES + l], c[blk, 2 * LANES + l]
        e1x, e1y, e1z = c[blk, 3 * LANES + l] - x0, c[blk, 4 * LANES + l] - y0, c[blk, 5 * LANES + l] - z0
        e2x, e2y, e2z = c[blk, 6 * LANES + l] - x0, c[blk, 7 * LANES + l] - y0, c[blk, 8 * LANES + l] - z0
        e3x, e3y, e3z = c[blk, 9 * LANES + l] - x0, c[blk, 10 * LANES + l] - y0, c[blk, 11 * LANES + l] - z0
        num, den, P = _split_model_f32(
            e1x * b10 + e2x * b20 + e3x * b30, e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32,
            e1y * b10 + e2y * b20 + e3y * b30, e1y * b11 + e2y * b21 + e3y * b31, e1y * b12 + e2y * b22 + e3y * b32,
            e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31, e1z * b12 + e2z * b22 + e3z * b32,
            p[blk, ROW_MU * LANES + l], p[blk, ROW_KAPPA * LANES + l], p[blk, ROW_ETA * LANES + l],
            p[blk, (ROW_FIBRE + 0) * LANES + l], p[blk, (ROW_FIBRE + 1) * LANES + l],
            p[blk, (ROW_FIBRE + 2) * LANES + l], p[blk, ROW_FIBRE_NORM * LANES + l], fibre)
        if forces:
            V = p[blk, ROW_VOLUME * LANES + l]
            P = (V * P[0], V * P[1], V * P[2], V * P[3], V * P[4], V * P[5], V * P[6], V * P[7], V * P[8])
        g1x = P[0] * b10 + P[1] * b11 + P[2] * b12
        g1y = P[3] * b10 + P[4] * b11 + P[5] * b12
        g1z = P[6] * b10 + P[7] * b11 + P[8] * b12
        g2x = P[0] * b20 + P[1] * b21 + P[2] * b22
        g2y = P[3] * b20 + P[4] * b21 + P[5] * b22
        g2z = P[6] * b20 + P[7] * b21 + P[8] * b22
        g3x = P[0] * b30 + P[1] * b31 + P[2] * b32
        g3y = P[3] * b30 + P[4] * b31 + P[5] * b32
        g3z = P[6] * b30 + P[7] * b31 + P[8] * b32
        g0x = -(g1x + g2x + g3x)
        g0y = -(g1y + g2y + g3y)
        g0z = -(g1z + g2z + g3z)
        if forces:
            s = _F32_ONE
            out[blk, OUT_W * LANES + l] = p[blk, ROW_VOLUME * LANES + l] * (num / den)
            h00, h11, h22 = e1x * b10 + e2x * b20 + e3x * b30, e1y * b11 + e2y * b21 + e3y * b31, \
                e1z * b12 + e2z * b22 + e3z * b32
            h01, h02 = e1x * b11 + e2x * b21 + e3x * b31, e1x * b12 + e2x * b22 + e3x * b32
            h10, h12 = e1y * b10 + e2y * b20 + e3y * b30, e1y * b12 + e2y * b22 + e3y * b32
            h20, h21 = e1z * b10 + e2z * b20 + e3z * b30, e1z * b11 + e2z * b21 + e3z * b31
            out[blk, OUT_FF * LANES + l] = (_F32_THREE + _F32_TWO * (h00 + h11 + h22) + h00 * h00 + h01 * h01
                                            + h02 * h02 + h10 * h10 + h11 * h11 + h12 * h12 + h20 * h20 + h21 * h21
                                            + h22 * h22)  # |I + H|^2
        else:
            w0, w1 = p[blk, (ROW_W + 0) * LANES + l], p[blk, (ROW_W + 1) * LANES + l]
            w2, w3 = p[blk, (ROW_W + 2) * LANES + l], p[blk, (ROW_W + 3) * LANES + l]
            denom = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
                     + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
            ok = denom > _F32_TINY
            lam_k = num / (den * denom if ok else _F32_ONE)
            nan = denom != denom
            out[blk, OUT_W * LANES + l] = denom
            s = -(lam_k if ok else (_F32_NAN if nan else _F32_ZERO))
        out[blk, (OUT_D + 0) * LANES + l] = s * g0x
        out[blk, (OUT_D + 1) * LANES + l] = s * g0y
        out[blk, (OUT_D + 2) * LANES + l] = s * g0z
        out[blk, (OUT_D + 3) * LANES + l] = s * g1x
        out[blk, (OUT_D + 4) * LANES + l] = s * g1y
        out[blk, (OUT_D + 5) * LANES + l] = s * g1z
        out[blk, (OUT_D + 6) * LANES + l] = s * g2x
        out[blk, (OUT_D + 7) * LANES + l] = s * g2y
        out[blk, (OUT_D + 8) * LANES + l] = s * g2z
        out[blk, (OUT_D + 9) * LANES + l] = s * g3x
        out[blk, (OUT_D + 10) * LANES + l] = s * g3y
        out[blk, (OUT_D + 11) * LANES + l] = s * g3z


def all_blocks_f32(corners, params, out, code, forces, first, last):
    """The float32 lane loop of blocks ``first:last`` (``code`` and ``forces`` literals; a split model). Compiled code only."""
    raise NotImplementedError("sim.integrators.ebm.blocked.all_blocks_f32 runs in compiled code only")


@overload(all_blocks_f32, prefer_literal=True, jit_options={"error_model": "numpy"})
def _all_blocks_f32_variant(corners, params, out, code, forces, first, last):
    """No fastmath (docs/xpbd.md, "Determinism")."""
    if not (isinstance(code, types.Literal) and isinstance(forces, types.Literal)):
        return None
    c, fo = int(code.literal_value), bool(forces.literal_value)
    if c not in (NEO_HOOKEAN, ANISOTROPIC_NEO_HOOKEAN):
        raise TypingError(f"sim.integrators.ebm.blocked: no float32 kernel for material code {c} (split models only)")
    fi = c == ANISOTROPIC_NEO_HOOKEAN

    def impl(corners, params, out, code, forces, first, last):
        lanes = corners.shape[1] // N_OUT
        for blk in range(first, last):
            _lanes_f32(fi, fo, corners, params, out, blk, lanes)

    return impl


@njit(cache=True, error_model="numpy")
def nan_denominators_f32(out):
    """How many of the last float32 sweep's denominators (row ``OUT_W``, padding lanes included) are NaN."""
    # a run-time trip count: with LANES as a constant LLVM unrolls the row and vectorises the loop over blocks with
    # gathers instead
    lanes = out.shape[1] // N_OUT
    bad = 0
    for blk in range(out.shape[0]):
        for l in range(lanes):
            d = out[blk, OUT_W * LANES + l]
            bad += 1 if d != d else 0
    return bad


@njit(cache=True)
def load_displacements_f32(x, X, node_index, corners):
    """Every tet's node displacements ``x - X`` (float32) into ``corners``, as :func:`load_corners` (each node's
    displacement rounded once, then gathered: faster than rounding per corner, docs/ebm.md#how-fast-and-why)."""
    xf = x.reshape(x.size)
    Xf = X.reshape(X.size)
    u = np.empty(xf.size, np.float32)
    for j in range(xf.size):
        u[j] = np.float32(xf[j] - Xf[j])
    for blk in range(node_index.shape[0]):
        for k in range(4):
            for l in range(LANES):
                i = node_index[blk, k * LANES + l]
                corners[blk, (3 * k) * LANES + l] = u[i]
                corners[blk, (3 * k + 1) * LANES + l] = u[i + OFF_Y]
                corners[blk, (3 * k + 2) * LANES + l] = u[i + OFF_Z]


@njit(cache=True)
def sweeps_f32(x, X, node_index, params, out, corners, free_nodes, free_start, free_slot, node_scale, code,
               iterations):
    """:func:`sweeps` with the float32 lane loop (``params``, ``out``, ``corners`` float32; ``corners`` rows hold
    displacements; ``node_scale`` includes the inverse masses). The node sums run in tet order, in float64 over float32
    sums of consecutive pairs of incidences; ``x`` is float64.
    ``code`` (a split model) is compiled as a literal.

    NaN multipliers are counted after the last sweep only (a pass over the denominators every sweep costs time,
    docs/ebm.md#how-fast-and-why): a NaN multiplier of a tet with a free node makes that node's position NaN in the same sweep,
    which the finiteness check catches there, and a tet whose nodes are all kinematic has the same multiplier in
    every sweep. Either way the sweeps fail (fewer than ``iterations`` done), as in :func:`sweeps`."""
    literally(code)
    load_displacements_f32(x, X, node_index, corners)
    of = out.reshape(out.size)
    cf = corners.reshape(corners.size)
    for it in range(iterations):
        all_blocks_f32(corners, params, out, code, False, 0, corners.shape[0])
        finite = node_range_f32(x, X, of, cf, free_nodes, free_start, free_slot, node_scale, 0, free_nodes.shape[0])
        if not finite:
            return it
    if iterations > 0 and nan_denominators_f32(out) > 0:
        return iterations - 1
    return iterations


@njit(cache=True)
def node_range_f32(x, X, of, cf, free_nodes, free_start, free_slot, node_scale, q0, q1):
    """The node pass of :func:`sweeps_f32` for free nodes ``q0:q1`` (the same code); False when a position is
    non-finite. Its write-back loop repeats :func:`sim.integrators.ebm.blocked.node_range`'s
    on purpose: kept separate, a shared ``inline="always"`` helper was slower (docs/ebm.md#how-fast-and-why)."""
    finite = True
    for q in range(q0, q1):
        k0 = free_start[q]
        k1 = free_start[q + 1]
        ax = 0.0
        ay = 0.0
        az = 0.0
        k = k0
        while k + 1 < k1:
            o = free_slot[k]
            o2 = free_slot[k + 1]
            ax += np.float64(of[o] + of[o2])
            ay += np.float64(of[o + OFF_L] + of[o2 + OFF_L])
            az += np.float64(of[o + OFF_L2] + of[o2 + OFF_L2])
            k += 2
        if k < k1:
            o = free_slot[k]
            ax += np.float64(of[o])
            ay += np.float64(of[o + OFF_L])
            az += np.float64(of[o + OFF_L2])
        i = free_nodes[q]
        sc = node_scale[i]
        vx = x[i, 0] + ax * sc
        vy = x[i, 1] + ay * sc
        vz = x[i, 2] + az * sc
        x[i, 0] = vx
        x[i, 1] = vy
        x[i, 2] = vz
        ux = np.float32(vx - X[i, 0])
        uy = np.float32(vy - X[i, 1])
        uz = np.float32(vz - X[i, 2])
        k = k0
        while k + 1 < k1:
            o = free_slot[k]
            o2 = free_slot[k + 1]
            cf[o] = ux
            cf[o + OFF_L] = uy
            cf[o + OFF_L2] = uz
            cf[o2] = ux
            cf[o2 + OFF_L] = uy
            cf[o2 + OFF_L2] = uz
            k += 2
        if k < k1:
            o = free_slot[k]
            cf[o] = ux
            cf[o + OFF_L] = uy
            cf[o + OFF_L2] = uz
        if not (abs(vx) < np.inf and abs(vy) < np.inf and abs(vz) < np.inf):
            finite = False
    return finite
