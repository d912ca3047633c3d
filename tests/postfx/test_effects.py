"""Post-effects on synthetic inputs with known answers (NumPy reference backend)."""
from __future__ import annotations

import numpy as np
import pytest

import postfx
from postfx.chromatic_aberration import ChromaticAberration, chromatic_aberration
from postfx.depth_of_field import DepthOfField, depth_of_field
from postfx.laparoscope_mask import LaparoscopeMask, mask_weights
from postfx.tonemap import Tonemap, tonemap

LENS = postfx.Lens(fov_deg=60.0, width=128, height=96)


def _centroid(channel):
    y, x = np.mgrid[0:channel.shape[0], 0:channel.shape[1]] + 0.5
    return np.array([(x * channel).sum(), (y * channel).sum()]) / channel.sum()


def test_chromatic_aberration_shifts_channels_by_the_expected_pixels():
    img = np.zeros((96, 128, 3), np.float32)
    img[47:49, 99:101] = 1.0  # white dot centred 36 px right of the optical centre (64, 48)
    k = 0.05
    out = chromatic_aberration(img, ChromaticAberration(strength_r=k, strength_g=0.0, strength_b=-k))
    r, g, b = (_centroid(out[..., c]) for c in range(3))
    assert r[0] - 64.0 == pytest.approx(36.0 * (1 + k), abs=0.05)
    assert g[0] - 64.0 == pytest.approx(36.0, abs=1e-4)
    assert b[0] - 64.0 == pytest.approx(36.0 * (1 - k), abs=0.05)
    assert r[1] == pytest.approx(48.0, abs=1e-4)


def test_depth_of_field_leaves_the_focus_plane_unchanged():
    rng = np.random.default_rng(0)
    img = rng.random((96, 128, 3)).astype(np.float32)
    depth = np.full((96, 128), 0.1, np.float32)
    out = depth_of_field(img, depth, DepthOfField(focus_distance=0.1, aperture=0.002), LENS.fov_deg)
    assert np.array_equal(out, img)


def test_out_of_focus_point_becomes_a_disc_of_the_analytic_coc():
    p = DepthOfField(focus_distance=0.1, aperture=0.008, focal_length=0.004, max_radius_px=30.0)
    depth = np.full((96, 128), 0.05, np.float32)
    f, A, df, d = 0.004, 0.008, 0.1, 0.05
    coc_diameter_px = 2 * A * f * abs(d - df) / (d * (df - f)) * 128 / (2 * f * np.tan(np.radians(30)))
    img = np.zeros((96, 128, 3), np.float32)
    img[48, 64] = 1000.0
    out = depth_of_field(img, depth, p, LENS.fov_deg)
    lit = out[..., 0] > 1e-3
    diameter = 2.0 * np.sqrt(lit.sum() / np.pi)
    assert diameter == pytest.approx(coc_diameter_px, rel=0.08)
    assert out[..., 0].sum() == pytest.approx(1000.0, rel=0.05)  # energy is spread, not created


def test_sharp_foreground_does_not_bleed_onto_the_background():
    p = DepthOfField(focus_distance=0.05, aperture=0.002, max_radius_px=10.0)
    img = np.zeros((96, 128, 3), np.float32)
    depth = np.full((96, 128), 1.0, np.float32)  # far background, blurred
    img[:, :64] = 1.0
    depth[:, :64] = 0.05  # in-focus bright foreground on the left half
    out = depth_of_field(img, depth, p, LENS.fov_deg)
    assert out[:, 66:, 0].max() < 1e-6  # nothing of the sharp foreground reaches the background


def test_mask_has_the_set_radius_and_softness():
    p = LaparoscopeMask(radius=0.8, softness=0.1, vignette=0.0)
    w = mask_weights(200, 200, p)
    row = w[100]  # through the centre; rho = |x - 100| / 100
    rho = np.abs(np.arange(200) + 0.5 - 100.0) / 100.0
    assert np.all(row[rho <= 0.75 - 1e-9] == 1.0) and np.all(row[rho >= 0.85 + 1e-9] == 0.0)
    half = np.interp(0.8, rho[100:], row[100:])
    assert half == pytest.approx(0.5, abs=0.03)


def test_vignette_darkens_towards_the_rim():
    w = mask_weights(200, 200, LaparoscopeMask(radius=1.0, softness=0.0, vignette=0.4))
    assert w[100, 100] > 0.99 and w[100, 10] == pytest.approx(1 - 0.4 * 0.895**2, abs=0.01)


@pytest.mark.parametrize("curve", ["aces", "reinhard", "clamp"])
def test_tonemap_is_monotonic_and_bounded(curve):
    x = np.linspace(0.0, 100.0, 20001, dtype=np.float32).reshape(1, -1, 1).repeat(3, axis=2)
    y = tonemap(x, Tonemap(curve=curve))[0, :, 0]
    assert np.all(np.diff(y) >= 0.0) and y[0] == 0.0 and y.max() <= 1.0


def test_extreme_parameters_stay_finite():
    rng = np.random.default_rng(1)
    img = (rng.random((48, 64, 3)) * 50).astype(np.float32)
    depth = (rng.random((48, 64)) * 0.5).astype(np.float32)
    depth[0, 0] = np.inf
    lens = postfx.Lens(60.0, 64, 48)
    chain = [("depth_of_field", DepthOfField(focus_distance=1e-6, aperture=1.0, max_radius_px=64.0)),
             ("chromatic_aberration", ChromaticAberration(strength_r=1.0, strength_b=-1.0)),
             ("tonemap", Tonemap(exposure=20.0)), ("laparoscope_mask", LaparoscopeMask(radius=4.0, softness=2.0))]
    out = postfx.apply_chain(img, depth, chain, lens, backend="numpy").image
    assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0


def test_only_listed_effects_run():
    img = np.full((8, 8, 3), 0.25, np.float32)
    res = postfx.apply_chain(img, np.ones((8, 8), np.float32), [("tonemap", Tonemap(curve="clamp", srgb=False))],
                             postfx.Lens(60, 8, 8))
    assert list(res.seconds) == ["tonemap"] and np.allclose(res.image, 0.25)
