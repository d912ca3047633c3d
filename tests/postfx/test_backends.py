"""The OSMesa (GLSL) backend agrees with the NumPy reference on every effect."""
from __future__ import annotations

import numpy as np
import pytest

import postfx
from postfx import osmesa
from postfx.params import (EFFECTS, Bloom, Blur, ChromaticAberration, ColorGrade, DepthOfField, LaparoscopeMask, LensFlare,
                           SensorNoise, Sharpen, Tonemap)

needs_osmesa = pytest.mark.skipif(not osmesa.library_available(),
                                  reason="libOSMesa missing: install the Debian package libosmesa6")

H, W = 120, 160
LENS = postfx.Lens(70.0, W, H)
CASES = {
    "chromatic_aberration": ChromaticAberration(strength_r=0.02, strength_b=-0.015, centre=[0.45, 0.55]),
    "depth_of_field": DepthOfField(focus_distance=0.1, aperture=0.004, max_radius_px=10.0),
    "tonemap": Tonemap(exposure=0.5, curve="aces"),
    "blur": Blur(sigma_px=2.5),
    "sharpen": Sharpen(amount=0.8, sigma_px=1.5),
    "bloom": Bloom(threshold=2.0, intensity=0.5, sigma_px=4.0),
    "sensor_noise": SensorNoise(shot=0.01, read=0.02),
    "lens_flare": LensFlare(threshold=3.0, intensity=0.5, halo_radius=0.5, blur_px=3.0),
    "color_grade": ColorGrade(lift=[0.02, 0.0, -0.01], gamma=[1.1, 1.0, 0.9], gain=[1.0, 0.95, 0.9], contrast=1.3,
                              curve=[[0.0, 0.0], [0.3, 0.22], [0.7, 0.8], [1.0, 1.0]],
                              curve_g=[[0.0, 0.02], [1.0, 0.98]], saturation=0.8),
    "laparoscope_mask": LaparoscopeMask(radius=0.9, softness=0.1, vignette=0.4, offset=[0.05, -0.03]),
}


def _inputs():
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:H, 0:W]
    hdr = (0.5 + 0.5 * np.sin(x / 7.0)[..., None] * np.cos(y / 5.0)[..., None] * [1.0, 0.7, 0.4]) * 3.0
    hdr = (hdr + rng.random((H, W, 3)) * 0.5).astype(np.float32)
    hdr[50:54, 70:74] = 40.0  # a specular highlight
    depth = (0.05 + 0.15 * x / W).astype(np.float32)
    depth[:10] = np.inf  # background
    return hdr, depth


def test_every_effect_has_a_case():
    assert set(CASES) == set(EFFECTS)


@needs_osmesa
@pytest.mark.osmesa
@pytest.mark.parametrize("name", sorted(CASES))
def test_backends_agree_per_8bit_channel(name):
    hdr, depth = _inputs()
    chain = [(name, CASES[name])] + ([] if name == "tonemap" else [("tonemap", Tonemap())])
    ref = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy")
    gpu = postfx.apply_chain(hdr, depth, chain, LENS, backend="osmesa")
    assert gpu.backend_used == "osmesa" and ref.backend_used == "numpy"
    diff = np.abs(postfx.to_uint8(ref.image).astype(int) - postfx.to_uint8(gpu.image).astype(int))
    assert diff.max() <= 2  # no border exception needed: edges are clamped identically
    assert np.abs(ref.image - gpu.image).max() < 1e-3


@needs_osmesa
@pytest.mark.osmesa
def test_full_chain_agrees_and_auto_prefers_osmesa():
    hdr, depth = _inputs()
    chain = [(n, CASES[n]) for n in postfx.DEFAULT_ORDER]
    ref = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy").image
    auto = postfx.apply_chain(hdr, depth, chain, LENS, backend="auto")
    assert auto.backend_used == "osmesa"
    assert np.abs(postfx.to_uint8(ref).astype(int) - postfx.to_uint8(auto.image).astype(int)).max() <= 2


def test_missing_osmesa_names_the_package_and_auto_falls_back(monkeypatch):
    monkeypatch.setattr(osmesa, "library_available", lambda: False)
    monkeypatch.setattr(osmesa.Context, "_instance", None)
    hdr, depth = _inputs()
    chain = [("tonemap", Tonemap())]
    with pytest.raises(postfx.OSMesaUnavailable, match="libosmesa6"):
        postfx.apply_chain(hdr, depth, chain, LENS, backend="osmesa")
    assert postfx.apply_chain(hdr, depth, chain, LENS, backend="auto").backend_used == "numpy"
