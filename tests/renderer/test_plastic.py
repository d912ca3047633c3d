"""The rough-plastic reference BSDF (Mitsuba 3's roughplastic model)."""
from __future__ import annotations

import numpy as np
import pytest

from tissuerender.renderer.bsdf.microfacet import fresnel, ggx_D, smith_G1, smith_G1_oriented
from tissuerender.renderer.bsdf.plastic import (_coating_albedo, internal_diffuse_reflectance, roughplastic_cos,
                                                smooth_internal_reflectance, transmittance)


def test_fresnel_limits():
    assert fresnel(np.array([1.0]), 1.5)[0] == pytest.approx(0.04)  # ((1.5 - 1) / 2.5)^2
    assert fresnel(np.array([0.0]), 1.5)[0] == pytest.approx(1.0)
    assert fresnel(np.array([0.5]), 1 / 1.5)[0] == 1.0  # beyond the critical angle (cos 0.745) from inside
    assert fresnel(np.array([0.3]), 1.0)[0] == pytest.approx(0.0)


def test_internal_diffuse_reflectance_matches_the_published_fit():
    # Egan & Hilgeman's fit for a relative index below 1 (what Mitsuba's fresnel_diffuse_reflectance
    # uses seen from inside): eta = 1/1.49 -> 0.5906
    e = 1.0 / 1.49
    fit = -1.4399 * e * e + 0.7099 * e + 0.6681 + 0.0636 / e
    assert smooth_internal_reflectance(1.49) == pytest.approx(fit, abs=2e-3)
    # a rough interface reflects less from inside (masking), and tends to the smooth one as alpha -> 0
    assert internal_diffuse_reflectance(1.49, 0.25) < smooth_internal_reflectance(1.49)
    assert internal_diffuse_reflectance(1.49, 0.01) == pytest.approx(fit, abs=0.03)


def _facet_grid(n=600):
    """Microfacet normals on a midpoint grid in (theta, phi) over the hemisphere, with solid angles."""
    th = (np.arange(n) + 0.5) / n * (np.pi / 2)
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    t, p = np.meshgrid(th, ph, indexing="ij")
    m = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    return m, ((np.pi / 2 / n) * (np.pi / n) * np.sin(t)).ravel()


@pytest.mark.parametrize("alpha", [0.05, 0.25, 0.6])
@pytest.mark.parametrize("mu", [0.1, 0.4, 0.9])
def test_transmittance_table_is_the_interface_transmission_albedo(alpha, mu):
    """t(mu) against a deterministic quadrature of the same integral over a fine grid of facet normals,
    T = int (1 - F) G1(wi) G1(wt) D (wi.m) / mu dm, and bounded by what the coating does not reflect."""

    eta = 1.49
    m, dw = _facet_grid()
    wi = np.array([np.sqrt(1 - mu * mu), 0.0, mu])
    c = m @ wi
    cos_t = np.sqrt(np.maximum(1 - (1 - c * c) / eta**2, 0))
    wt = -wi / eta + (c / eta - cos_t)[:, None] * m
    f = (ggx_D(m[:, 2], alpha) * smith_G1_oriented(np.broadcast_to(wi, m.shape), m, alpha) * np.maximum(c, 0) / mu
         * (1 - fresnel(c, eta)) * smith_G1_oriented(wt, m, alpha))
    exact = np.sum(f * dw)
    assert transmittance(np.array([mu]), alpha, eta)[0] == pytest.approx(exact, abs=2e-3)
    mus, albedo = _coating_albedo(alpha, eta)
    assert transmittance(np.array([mu]), alpha, eta)[0] <= 1.0 - np.interp(mu, mus, albedo) + 1e-3


@pytest.mark.parametrize("alpha", [0.05, 0.25, 0.6])
def test_coating_lobe_albedo_matches_brute_force(alpha):
    # brute-force Monte Carlo of the coating's directional albedo at 60 degrees, cosine sampling
    eta, mu = 1.49, 0.5
    rng = np.random.default_rng(0)
    k = 2_000_000
    u1, u2 = rng.random(k), rng.random(k)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    wi = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=1)
    wo = np.tile([np.sqrt(1 - mu * mu), 0.0, mu], (k, 1))
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    f_cos = roughplastic_cos(n, wo, wi, np.zeros((k, 3)), alpha, eta)[:, 0]  # coating only
    albedo = np.mean(f_cos * np.pi / wi[:, 2])
    tol = 0.01 if alpha > 0.1 else 0.03  # a sharp lobe is noisy under cosine sampling

    mus, table = _coating_albedo(alpha, eta)
    assert np.interp(mu, mus, table) == pytest.approx(albedo, abs=tol)


def test_reciprocal_and_finite_at_grazing():
    rng = np.random.default_rng(1)
    k = 1000
    a = rng.normal(size=(k, 3))
    b = rng.normal(size=(k, 3))
    a[:, 2], b[:, 2] = np.abs(a[:, 2]), np.abs(b[:, 2])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    rho = np.full((k, 3), 0.5)
    f_ab = roughplastic_cos(n, a, b, rho, 0.3, 1.49) / b[:, 2:3]
    f_ba = roughplastic_cos(n, b, a, rho, 0.3, 1.49) / a[:, 2:3]
    assert np.allclose(f_ab, f_ba, rtol=1e-9, atol=1e-12)
    graze = roughplastic_cos(n[:1], np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]), rho[:1], 0.3, 1.49)
    assert np.isfinite(graze).all() and (graze >= 0).all()
    assert smith_G1(np.array([1.0]), 0.3)[0] == pytest.approx(1.0)
