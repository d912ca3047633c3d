"""Low-order spherical-harmonic environment light for the wet mucus reflection (Qian §7.2.2).

The environment is a two-colour gradient around an axis — ``L(w) = down + (up - down) (1 + w.axis) / 2``,
the lit cavity in front of the scope against the darker surround — held as real SH coefficients up to
band 2 (9 per channel; the gradient needs only bands 0 and 1, exactly). A glossy lobe of GGX roughness
alpha reads the environment through a band attenuation ``exp(-alpha^2 l (l + 1) / 2)`` (a Gaussian lobe's
zonal factors), evaluated in the mirror direction and weighted by the coat's Fresnel reflectance.
"""
from __future__ import annotations

import numpy as np

# real SH normalisation constants, bands 0-2
_C0 = 0.5 * np.sqrt(1.0 / np.pi)
_C1 = np.sqrt(3.0 / (4.0 * np.pi))
_C2 = (0.5 * np.sqrt(15.0 / np.pi), 0.25 * np.sqrt(5.0 / np.pi), 0.25 * np.sqrt(15.0 / np.pi))
BAND = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])


def sh_basis(d: np.ndarray) -> np.ndarray:
    """(k, 9) real SH basis values for unit directions d (k, 3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack([np.full_like(x, _C0), _C1 * y, _C1 * z, _C1 * x,
                     _C2[0] * x * y, _C2[0] * y * z, _C2[1] * (3 * z * z - 1), _C2[0] * x * z,
                     _C2[2] * (x * x - y * y)], axis=1)


def gradient_environment(up, down, axis) -> np.ndarray:
    """(9, 3) SH coefficients of ``down + (up - down) (1 + w.axis) / 2`` (exact: bands 0 and 1 only)."""
    up, down = np.asarray(up, float), np.asarray(down, float)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    mean = 0.5 * (up + down)
    slope = 0.5 * (up - down)  # L = mean + slope (w . a)
    coeffs = np.zeros((9, 3))
    coeffs[0] = mean * np.sqrt(4.0 * np.pi)  # int mean Y00 = mean / C0 ... = mean sqrt(4 pi)
    # int (w . a) Y1m dw = (4 pi / 3) C1 a_m, with Y1 = C1 (y, z, x)
    coeffs[1:4] = (4.0 * np.pi / 3.0) * _C1 * np.array([a[1], a[2], a[0]])[:, None] * slope[None, :]
    return coeffs


def evaluate(coeffs: np.ndarray, d: np.ndarray, alpha: np.ndarray | float = 0.0) -> np.ndarray:
    """Environment radiance (k, 3) seen along d through a lobe of roughness alpha."""
    alpha = np.broadcast_to(np.asarray(alpha, float), (d.shape[0],))
    atten = np.exp(-0.5 * alpha[:, None] ** 2 * (BAND * (BAND + 1))[None, :])
    return (sh_basis(d) * atten) @ coeffs
