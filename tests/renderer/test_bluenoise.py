"""Blue-noise sample offsets: the texture, and what it does to a render's error."""
from __future__ import annotations

import numpy as np
import pytest

from materials import get_preset
from materials.optics import untextured
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame
from tissuerender.renderer import bluenoise

UNTEXTURED_LIVER = untextured(get_preset("liver").optics)  # the BSDF alone: noise, not texture


def _low_frequency_share(x):
    power = np.abs(np.fft.fft2(x - x.mean())) ** 2
    f = np.fft.fftfreq(x.shape[0])
    r = np.hypot(f[:, None], f[None, :])
    return power[(r > 0) & (r < 0.1)].mean() / power[r > 0].mean()


def test_stored_tiles_are_the_generator_output_and_a_permutation():
    stored = np.load(bluenoise.STORED)
    for seed in (0, 1):
        assert np.array_equal(stored[seed], bluenoise.generate(64, seed))
        values = np.sort(bluenoise.texture(64, seed).ravel())
        assert np.array_equal(values, (np.arange(64 * 64) + 0.5) / 4096)  # uniform: each level once


def test_tile_has_almost_no_low_frequency_power():
    blue = _low_frequency_share(bluenoise.texture(64, 0))
    white = _low_frequency_share(np.random.default_rng(0).random((64, 64)))
    assert blue < 0.01 and white > 0.5
    # the two channels are not copies of each other
    a, b = bluenoise.texture(64, 0).ravel(), bluenoise.texture(64, 1).ravel()
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.05


def _penumbra_scene():
    p = np.array([[-0.2, -0.2, 0.0], [0.2, -0.2, 0.0], [0.2, 0.2, 0.0], [-0.2, 0.2, 0.0]])
    floor = RenderObject(points=p, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=np.tile([0.0, 0, 1], (4, 1)),
                         uv=None, material="liver", optics=UNTEXTURED_LIVER)
    q = np.array([[-0.03, -0.03, 0.1], [0.03, -0.03, 0.1], [0.03, 0.03, 0.1], [-0.03, 0.03, 0.1]])
    blocker = RenderObject(points=q, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=np.tile([0.0, 0, 1], (4, 1)),
                           uv=None, material="liver", optics=UNTEXTURED_LIVER)
    cam = Camera((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 0.01, 5.0, 64, 64)
    return [floor, blocker], cam


def _render(pattern, samples, ss=2, seed=3):
    objects, cam = _penumbra_scene()
    light = AreaLight(size=(0.08, 0.08), radiance=(3000.0,) * 3, attach="world", position=(0.0, 0.0, 0.3),
                      normal=(0, 0, -1), sampling="uniform", samples=samples, pattern=pattern)
    return render_frame(objects, cam, light, RenderSettings(shadows=True, supersampling=ss, seed=seed)).hdr[..., 0]


def test_blue_noise_offsets_keep_the_mean_and_cut_the_visible_error():
    """Soft shadow of a square blocker: with 2 light samples per supersample (8 per pixel), blue-noise
    offsets with the pixel's supersamples stratified together give the same image mean as white noise
    (both unbiased), a smaller error, and a smaller error after a blur of a few pixels (what the eye
    and FLIP's contrast-sensitivity filter see)."""
    reference = _render("white_noise", 256)
    penumbra = (reference > 0.05 * reference.max()) & (reference < 0.95 * reference.max())
    assert penumbra.sum() > 200
    blue, white = _render("blue_noise", 2), _render("white_noise", 2)
    assert blue.mean() == pytest.approx(reference.mean(), rel=0.01)
    assert white.mean() == pytest.approx(reference.mean(), rel=0.01)

    def blur(x):
        k = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
        k /= k.sum()
        x = np.apply_along_axis(lambda r: np.convolve(r, k, mode="same"), 0, x)
        return np.apply_along_axis(lambda r: np.convolve(r, k, mode="same"), 1, x)

    err_blue, err_white = blue - reference, white - reference
    rms = [np.sqrt(np.mean(e[penumbra] ** 2)) for e in (err_blue, err_white)]
    seen = [np.sqrt(np.mean(blur(e)[penumbra] ** 2)) for e in (err_blue, err_white)]
    assert rms[0] < 0.8 * rms[1]  # measured 0.66
    assert seen[0] < 0.8 * seen[1]  # measured 0.65


def test_same_seed_same_pixels_with_blue_noise():
    assert np.array_equal(_render("blue_noise", 2, seed=4), _render("blue_noise", 2, seed=4))
    assert not np.array_equal(_render("blue_noise", 2, seed=4), _render("blue_noise", 2, seed=5))
