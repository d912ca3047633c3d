"""Blur, sharpen, bloom and seeded sensor noise, with known answers (NumPy reference)."""
from __future__ import annotations

import numpy as np
import pytest

import postfx
from postfx.bloom import Bloom, bloom
from postfx.blur import Blur, blur
from postfx.sensor_noise import SensorNoise, sensor_noise
from postfx.sharpen import Sharpen, sharpen


def _delta(size=65, value=1.0):
    img = np.zeros((size, size, 3), np.float32)
    img[size // 2, size // 2] = value
    return img


def test_blur_of_a_point_is_a_normalised_gaussian_of_the_set_width():
    out = blur(_delta(), Blur(sigma_px=3.0))[..., 0]
    assert out.sum() == pytest.approx(1.0, rel=1e-5)
    y, x = np.mgrid[0:65, 0:65] - 32
    assert np.sqrt((out * x * x).sum()) == pytest.approx(3.0, rel=0.02)  # truncated at 3 sigma


def test_sharpen_keeps_flat_areas_and_overshoots_at_an_edge():
    flat = np.full((16, 16, 3), 0.4, np.float32)
    assert np.allclose(sharpen(flat, Sharpen(amount=1.0)), 0.4, atol=1e-6)
    edge = np.full((16, 32, 3), 0.3, np.float32)
    edge[:, 16:] = 0.6
    out = sharpen(edge, Sharpen(amount=1.0, sigma_px=1.0))[8, :, 0]
    assert out[15] < 0.3 - 0.02 and out[16] > 0.6 + 0.02  # the unsharp mask's halo


def test_bloom_leaves_dim_pixels_and_adds_the_highlight_excess():
    dim = np.full((32, 32, 3), 0.5, np.float32)
    assert np.array_equal(bloom(dim, Bloom(threshold=1.0)), dim)
    img = _delta(65, 11.0)
    out = bloom(img, Bloom(threshold=1.0, intensity=0.5, sigma_px=4.0))
    added = out.sum() - img.sum()
    assert added == pytest.approx(3 * 0.5 * 10.0, rel=1e-4)  # intensity x (11 - 1) per channel
    assert out[32, 40, 0] > 0.0  # a glow around the highlight


def test_sensor_noise_has_the_stated_variance_and_is_seeded():
    img = np.full((256, 256, 3), 0.25, np.float32)
    p = SensorNoise(shot=0.01, read=0.02)
    a = sensor_noise(img, p, seed=5)
    assert np.array_equal(a, sensor_noise(img, p, seed=5))
    assert not np.array_equal(a, sensor_noise(img, p, seed=6))
    assert a.var() == pytest.approx(0.01 * 0.25 + 0.02**2, rel=0.05)
    assert a.mean() == pytest.approx(0.25, abs=1e-3)


def test_noise_in_a_chain_follows_the_frame_seed():
    img = np.full((32, 32, 3), 0.3, np.float32)
    chain = [("sensor_noise", SensorNoise(shot=0.01, read=0.01))]
    lens = postfx.Lens(60.0, 32, 32)
    one = postfx.apply_chain(img, np.ones((32, 32), np.float32), chain, lens, backend="numpy", seed=1).image
    two = postfx.apply_chain(img, np.ones((32, 32), np.float32), chain, lens, backend="numpy", seed=2).image
    assert not np.array_equal(one, two)
