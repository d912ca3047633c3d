"""Lens flare from HDR highlights: ghosts and halo where the geometry puts them (NumPy reference)."""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from postfx.lens_flare import LensFlare, lens_flare

H, W = 240, 320
CENTRE = np.array([160.0, 120.0])  # optical centre [0.5, 0.5] in pixels (x, y)


def _dot(value=50.0, background=0.1):
    """A 4x4 highlight centred on (x, y) = (202, 62): aligned with the half- and quarter-res blocks, so
    its downsampled images are centred on the same point."""
    img = np.full((H, W, 3), background, np.float32)
    img[60:64, 200:204] = value
    return img, np.array([202.0, 62.0])


def _centroid(channel):
    y, x = np.mgrid[0:channel.shape[0], 0:channel.shape[1]] + 0.5
    return np.array([(x * channel).sum(), (y * channel).sum()]) / channel.sum()


def test_each_ghost_of_a_point_sits_at_its_scaled_mirror_image_with_the_energy_of_its_tint():
    # one ghost per channel: mirrored through the centre (s = -1), mirrored and smaller (s = -0.75, read
    # from the quarter-res image), magnified on the same side (s = 1.5)
    scales = (-1.0, -0.75, 1.5)
    tints = np.eye(3) * 0.5
    p = LensFlare(threshold=1.0, intensity=1.0, ghosts=[[s, *t] for s, t in zip(scales, tints)],
                  halo_tint=[0.0, 0.0, 0.0], falloff=0, blur_px=2.0)
    img, x = _dot()
    added = lens_flare(img, p) - img
    bright_energy = 16 * (50.0 - 1.0)  # per channel: 16 pixels of (50 - threshold), grey
    for c, s in enumerate(scales):
        expected = CENTRE + s * (x - CENTRE)
        assert _centroid(added[..., c]) == pytest.approx(expected, abs=0.1)  # s = -0.75: 0.06 px (resampling)
        # the 1/s^2 dimming keeps the ghost's energy at tint x the highlight's, whatever its size
        assert added[..., c].sum() == pytest.approx(0.5 * bright_energy, rel=0.02)


def test_ghosts_fade_with_the_source_distance_from_the_centre():
    img, x = _dot()
    p = LensFlare(threshold=1.0, intensity=1.0, ghosts=[[-1.0, 1.0, 1.0, 1.0]], halo_tint=[0.0, 0.0, 0.0],
                  falloff=3, blur_px=0.0)
    added = (lens_flare(img, p) - img)[..., 0].sum()
    rho = 0.5 * np.hypot(W, H)  # half diagonal
    fade = (1.0 - np.linalg.norm(x - CENTRE) / rho) ** 3
    assert added == pytest.approx(fade * 16 * 49.0, rel=0.01)


def test_halo_puts_a_point_halo_radius_further_out_on_its_ray():
    img, x = _dot()
    p = LensFlare(threshold=1.0, intensity=1.0, ghosts=[], halo_radius=0.3, halo_tint=[1.0, 1.0, 1.0], falloff=0,
                  blur_px=0.0)
    added = (lens_flare(img, p) - img)[..., 0]
    ray = (x - CENTRE) / np.linalg.norm(x - CENTRE)
    h = 0.3 * 0.5 * H  # fraction of half the height, in pixels
    expected = CENTRE + (np.linalg.norm(x - CENTRE) + h) * ray
    got = _centroid(added)
    assert np.linalg.norm(got - expected) < 1.0  # the arc's centroid, within a pixel on a 36 px radius
    assert np.dot(got - CENTRE, ray) == pytest.approx(np.linalg.norm(x - CENTRE) + h, abs=1.0)


def test_no_highlight_leaves_the_image_unchanged():
    rng = np.random.default_rng(3)
    img = (rng.random((H, W, 3)) * 0.9).astype(np.float32)  # luminance below the threshold everywhere
    assert np.array_equal(lens_flare(img, LensFlare(threshold=1.0, intensity=2.0)), img)


def test_added_energy_scales_with_intensity():
    img, _ = _dot()
    energies = [(lens_flare(img, LensFlare(threshold=1.0, intensity=k)) - img).sum() for k in (0.1, 0.3, 0.0)]
    assert energies[0] > 0.0
    assert energies[1] == pytest.approx(3.0 * energies[0], rel=1e-4)
    assert energies[2] == 0.0


@pytest.mark.parametrize("ghosts, message", [
    ([[0.2, 1.0, 1.0, 1.0]], "ghost 0: scale"),
    ([[-1.0, 1.0, -1.0, 1.0]], "ghost 0: tint"),
    ([[-1.0, 1.0, 1.0]], "at least 4"),
])
def test_bad_ghosts_are_rejected_with_the_reason(ghosts, message):
    with pytest.raises(ValidationError, match=message):
        LensFlare(ghosts=ghosts)
