"""The spherical-harmonic environment and the wet mucus reflection (Qian 7.2.2)."""
from __future__ import annotations

import numpy as np
import pytest

from tissuerender.renderer import sh
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame


def _directions(k=500, seed=0):
    d = np.random.default_rng(seed).normal(size=(k, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_gradient_environment_is_reproduced_exactly():
    up, down, axis = (2.0, 1.5, 1.0), (0.2, 0.1, 0.1), (0.3, -0.2, 0.9)
    coeffs = sh.gradient_environment(up, down, axis)
    d = _directions()
    a = np.asarray(axis) / np.linalg.norm(axis)
    expected = np.asarray(down) + (np.asarray(up) - np.asarray(down)) * ((1 + d @ a) / 2)[:, None]
    assert np.allclose(sh.evaluate(coeffs, d), expected, atol=1e-12)


def test_sh_basis_is_orthonormal():
    rng = np.random.default_rng(1)
    d = _directions(400_000, 2)
    Y = sh.sh_basis(d)
    gram = 4 * np.pi * (Y.T @ Y) / d.shape[0]
    assert np.allclose(gram, np.eye(9), atol=0.02)


def test_rough_lobe_sees_a_blurred_environment():
    coeffs = sh.gradient_environment((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0, 0, 1))
    top, bottom = np.array([[0, 0, 1.0]]), np.array([[0, 0, -1.0]])
    sharp = sh.evaluate(coeffs, top, 0.0) - sh.evaluate(coeffs, bottom, 0.0)
    rough = sh.evaluate(coeffs, top, 0.8) - sh.evaluate(coeffs, bottom, 0.8)
    assert sharp[0, 0] == pytest.approx(1.0) and 0.0 < rough[0, 0] < 0.8 * sharp[0, 0]
    assert sh.evaluate(coeffs, top, 0.8)[0, 0] + sh.evaluate(coeffs, bottom, 0.8)[0, 0] == pytest.approx(1.0)


def _render(theta_deg, reflection):
    pts = np.array([[-0.2, -0.2, 0.0], [0.2, -0.2, 0.0], [0.2, 0.2, 0.0], [-0.2, 0.2, 0.0]])
    slab = RenderObject(points=pts, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=None,
                        material="colon_mucosa")
    t = np.radians(theta_deg)
    cam = Camera(position=(0.0, -0.1 * np.sin(t), 0.1 * np.cos(t)), look_at=(0.0, 0.0, 0.0),
                 up=(0.0, 1.0, 0.0) if theta_deg < 45 else (0.0, 0.0, 1.0),
                 fov_deg=10.0, near=0.01, far=1.0, width=8, height=8)
    settings = RenderSettings(mucus_reflection=reflection, environment_up=(1.0, 1.0, 1.0),
                              environment_down=(0.0, 0.0, 0.0))
    return render_frame([slab], cam, AreaLight(radiance=(0.0, 0.0, 0.0), samples=1), settings).hdr[4, 4]


def test_mucus_reflects_the_environment_more_at_grazing_angles():
    assert np.allclose(_render(0, False), 0.0)  # no light, no environment: black
    head_on = _render(0, True)
    grazing = _render(80, True)
    f0 = ((1.34 - 1) / 2.34) ** 2
    # looking straight down, the mirror direction is straight up: F0 x up (a little blurred by the coat)
    assert head_on[0] == pytest.approx(f0, rel=0.1)
    assert grazing[0] > 5 * head_on[0]  # Fresnel rises towards grazing
