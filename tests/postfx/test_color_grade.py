"""Colour grading: lift/gamma/gain, filmic S-curve, editable monotone tone curves, saturation."""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from postfx.color_grade import ColorGrade, color_grade
from postfx.kernels import LUMA


def _ramp(n=1001):
    x = np.linspace(0.0, 1.0, n, dtype=np.float32)
    return x, np.repeat(x.reshape(1, -1, 1), 3, axis=2)


def test_defaults_are_the_identity():
    rng = np.random.default_rng(0)
    img = rng.random((32, 48, 3)).astype(np.float32)
    assert np.abs(color_grade(img, ColorGrade()) - img).max() < 1e-6


def test_tone_curve_passes_through_its_points_and_is_monotone():
    points = [[0.0, 0.05], [0.25, 0.1], [0.6, 0.8], [1.0, 0.95]]
    x, img = _ramp()
    y = color_grade(img, ColorGrade(curve=points))[0, :, 0]
    for px, py in points:
        assert y[int(round(px * 1000))] == pytest.approx(py, abs=2e-3)
    assert np.all(np.diff(y) >= -1e-7)  # monotone cubic: no overshoot between the points


def test_per_channel_curve_changes_only_its_channel():
    x, img = _ramp()
    out = color_grade(img, ColorGrade(curve_b=[[0.0, 0.0], [1.0, 0.5]]))[0]
    assert np.allclose(out[:, 0], x, atol=1e-6) and np.allclose(out[:, 1], x, atol=1e-6)
    assert np.allclose(out[:, 2], 0.5 * x, atol=1e-3)


def test_filmic_s_curve_fixes_black_mid_grey_and_white_and_adds_contrast():
    x, img = _ramp()
    y = color_grade(img, ColorGrade(contrast=1.5))[0, :, 0]
    assert y[0] == pytest.approx(0.0, abs=1e-6) and y[500] == pytest.approx(0.5, abs=1e-3)
    assert y[-1] == pytest.approx(1.0, abs=1e-6)
    assert y[250] < 0.25 - 0.05 and y[750] > 0.75 + 0.05  # 0.25^1.5/(0.25^1.5+0.75^1.5) = 0.16
    assert y[250] == pytest.approx(0.25**1.5 / (0.25**1.5 + 0.75**1.5), abs=1e-3)


def test_lift_gamma_gain():
    x, img = _ramp()
    out = color_grade(img, ColorGrade(lift=[0.1, 0.0, 0.0], gamma=[1.0, 2.0, 1.0], gain=[1.0, 1.0, 0.5]))[0]
    assert out[0, 0] == pytest.approx(0.1, abs=1e-3)  # lift raises black, keeps white
    assert out[-1, 0] == pytest.approx(1.0, abs=1e-6)
    assert out[250, 1] == pytest.approx(0.25**0.5, abs=1e-3)
    assert out[-1, 2] == pytest.approx(0.5, abs=1e-6)


def test_saturation_zero_gives_rec709_luma_grey():
    rng = np.random.default_rng(1)
    img = rng.random((8, 8, 3)).astype(np.float32)
    out = color_grade(img, ColorGrade(saturation=0.0))
    luma = img @ np.array(LUMA, np.float32)
    assert np.allclose(out, luma[..., None], atol=1e-5)


@pytest.mark.parametrize("curve, message", [
    ([[0.0, 0.0], [0.5, 0.2], [0.4, 1.0]], "strictly increasing"),
    ([[0.0, 0.0]], "at least 2"),
    ([[0.0, 0.0], [1.0, 1.5]], "less than or equal to 1"),
])
def test_bad_curves_are_rejected_with_the_reason(curve, message):
    with pytest.raises(ValidationError, match=message):
        ColorGrade(curve=curve)
