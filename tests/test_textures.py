"""Procedural organic textures (Qian 6.2.1-6.2.2): determinism, blend modes, multi-scale structure,
palette extraction, normal maps and per-layer bakes."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.cluster.vq import kmeans2

from materials.textures import MOTTLE, Level, Quadtree, apply_palette, bake_layer, blend, normal_map, quadtree

# A fibre-like pattern (long thin stamps, little rotation) and palette extraction from a reference image:
# used only here, to check the generator and the palette gradient.
FIBRES = Quadtree(levels=tuple(Level(opacity=0.6, aspect=12.0, size_jitter=0.5, rotation=0.35, value=(0.2, 1.0))
                               for _ in range(5)), start_level=2, background=0.5, softness=0.8)


def extract_palette(image: np.ndarray, k: int = 5, seed: int = 0) -> np.ndarray:
    """``k`` representative colours (k, 3) of an RGB image in [0, 1], by seeded k-means (scipy),
    sorted from dark to light (Rec. 709 luma)."""
    pixels = np.asarray(image, dtype=np.float64).reshape(-1, 3)
    if pixels.shape[0] < k:
        raise ValueError(f"a palette of {k} colours needs at least {k} pixels, found {pixels.shape[0]}")
    rng = np.random.default_rng(seed)
    sample = pixels[rng.choice(pixels.shape[0], size=min(pixels.shape[0], 20000), replace=False)]
    centres, _ = kmeans2(sample, k, minit="++", seed=seed)
    luma = centres @ np.array([0.2126, 0.7152, 0.0722])
    return centres[np.argsort(luma)]


def test_same_seed_same_texture_other_seed_other_texture():
    a = quadtree(64, MOTTLE, seed=3)
    assert np.array_equal(a, quadtree(64, MOTTLE, seed=3))
    b = quadtree(64, MOTTLE, seed=4)
    assert np.abs(a - b).mean() > 0.02
    assert a.min() >= 0.0 and a.max() <= 1.0


@pytest.mark.parametrize("mode, expected", [
    ("normal", 0.8), ("multiply", 0.4 * 0.8), ("screen", 1 - 0.6 * 0.2), ("add", 1.0), ("max", 0.8),
    ("overlay", 2 * 0.4 * 0.8),
])
def test_blend_modes_at_full_and_half_coverage(mode, expected):
    base, layer = np.array([0.4]), np.array([0.8])
    assert blend(base, layer, np.array([1.0]), mode)[0] == pytest.approx(expected)
    assert blend(base, layer, np.array([0.5]), mode)[0] == pytest.approx(0.5 * 0.4 + 0.5 * expected)
    with pytest.raises(ValueError, match="unknown blend mode"):
        blend(base, layer, np.array([1.0]), "dodge")


def test_every_level_adds_structure_at_its_own_scale():
    # one level at a time: the texture's power moves to finer wavelengths as the level deepens
    def peak_frequency(level):
        tex = quadtree(128, Quadtree(levels=(Level(opacity=1.0, opacity_jitter=0.0),), start_level=level), seed=1)
        power = np.abs(np.fft.rfft2(tex - tex.mean())) ** 2
        fy = np.abs(np.fft.fftfreq(128))[:, None] * 128
        fx = np.fft.rfftfreq(128)[None, :] * 128
        f = np.hypot(fx, fy)
        return float((power * f).sum() / power.sum())

    freqs = [peak_frequency(level) for level in (1, 2, 3, 4)]
    assert all(b > 1.5 * a for a, b in zip(freqs, freqs[1:]))


def test_fibre_stamps_are_anisotropic():
    tex = quadtree(128, FIBRES, seed=2)
    gx = np.abs(np.diff(tex, axis=1)).mean()
    gy = np.abs(np.diff(tex, axis=0)).mean()
    assert max(gx, gy) / min(gx, gy) > 1.3  # elongated stamps with small rotation: a dominant direction


def test_palette_extraction_recovers_the_reference_colours():
    colours = np.array([[0.8, 0.3, 0.3], [0.2, 0.05, 0.05], [0.9, 0.7, 0.6]])
    rng = np.random.default_rng(0)
    image = colours[rng.integers(0, 3, size=(60, 60))] + rng.normal(0, 0.01, (60, 60, 3))
    palette = extract_palette(image, k=3, seed=1)
    expected = colours[np.argsort(colours @ [0.2126, 0.7152, 0.0722])]
    assert np.allclose(palette, expected, atol=0.01)
    assert np.allclose(apply_palette(np.array([0.0, 1.0]), palette), palette[[0, -1]])


def test_normal_map_of_a_ramp_is_the_tilted_plane():
    size = 32
    ramp = np.tile(np.arange(size) / size, (size, 1)) * 0.25  # h = x / 4 (not tiling at the seam)
    n = normal_map(ramp, strength=1.0)[:, 1:-1]
    assert np.allclose(n[..., 0], -0.25 / np.sqrt(1 + 0.0625), atol=1e-9)
    assert np.allclose(n[..., 2], 1 / np.sqrt(1 + 0.0625), atol=1e-9)


def test_bake_layer_gives_consistent_maps():
    palette = np.array([[0.3, 0.05, 0.05], [0.7, 0.3, 0.3], [0.9, 0.6, 0.55]])
    bake = bake_layer(64, palette, roughness=0.3, seed=5, vessel_density=1.5)
    assert bake.albedo.shape == (64, 64, 3) and bake.normal.shape == (64, 64, 3)
    assert np.all(bake.albedo >= 0) and np.all(bake.albedo <= 1)
    assert np.all((bake.roughness >= 0.3 * 0.7 - 1e-12) & (bake.roughness <= 0.3 * 1.3 + 1e-12))
    assert np.allclose(np.linalg.norm(bake.normal, axis=-1), 1.0)
    assert 0.01 < bake.vessels.mean() < 0.9
    # vessels darken the albedo where they are
    dark = bake.vessels > 0.5
    plain = bake_layer(64, palette, roughness=0.3, seed=5, vessel_density=0.0)
    assert (bake.albedo[dark] < plain.albedo[dark] - 1e-6).all()


def _checker(size: int = 64) -> np.ndarray:
    """A one-texel RGB checker of 0 and 1: mean 0.5, the highest frequency a texture can hold."""
    j, i = np.mgrid[0:size, 0:size]
    return np.repeat(((i + j) % 2).astype(np.float64)[..., None], 3, axis=2)


def test_mip_mapped_checker_seen_small_averages_to_its_mean_where_bilinear_speckles():
    """Issue 19: a 160x120 render must not speckle. A one-texel checker (mean 0.5) on a plane 1 m away, tiled every
    1 cm, seen by a 64-pixel-wide 60-degree camera: one sample covers 2 tan(30 deg) / 64 m = 1.8 cm = 115 texels,
    so the mip-mapped lookup reads the 1 x 1 level, the mean, exactly (every level from 1 on is 0.5: sums of
    0.25-weighted 0s and 1s are exact in binary); the plain bilinear lookup at the same points spreads over
    [0, 1]: between two 0s and two 1s it is 1/2 - 2 (x - 1/2)(y - 1/2), of standard deviation 4 (1/12) / 2 = 1/6
    at uniform points."""
    from types import SimpleNamespace

    from materials.textures import mip_chain, sample_mipmapped
    from tissuerender.renderer.camera import Camera
    from tissuerender.renderer.gbuffer import sample_footprint, textured_surface

    chain = mip_chain(_checker())
    assert len(chain) == 7 and chain[-1].shape == (1, 1, 3) and np.all(chain[1] == 0.5)
    rng = np.random.default_rng(3)
    k = 500
    xy = rng.uniform(-0.3, 0.3, (k, 2))
    position = np.column_stack([xy[:, 0], np.ones(k), xy[:, 1]])  # the plane y = 1, facing the camera
    normal, wo = np.tile([0.0, -1.0, 0.0], (k, 1)), -position / np.linalg.norm(position, axis=1, keepdims=True)
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 1.0, 0.0), up=(0.0, 0.0, 1.0), fov_deg=60.0, near=0.01,
                    far=10.0, width=64, height=48)
    footprint = sample_footprint(position, normal, wo, camera, 64)
    assert np.all(footprint >= 2.0 * np.tan(np.radians(30.0)) / 64)  # at least the on-axis sample's 1.8 cm
    layers = SimpleNamespace(texture_seed=1, texture_period=0.01, baked_albedo=_checker,
                             baked_roughness_factor=lambda: np.ones((64, 64)),
                             baked_normal=lambda: np.tile([0.0, 0.0, 1.0], (64, 64, 1)))
    optics = [SimpleNamespace(layers=layers)]
    args = (optics, np.zeros(k, np.int64), xy, np.zeros((k, 3)), normal, np.full(k, 0.3))
    mipmapped = textured_surface(*args, footprint=footprint)[0]
    np.testing.assert_allclose(mipmapped, 0.5, rtol=0, atol=1e-15)
    speckle = textured_surface(*args)[0]  # without a footprint: bilinear level 0
    assert speckle.std() > 0.15 and np.ptp(speckle) > 0.9
    # seen from close (a quarter texel per sample) the lookup is the plain bilinear one
    st = rng.uniform(0.0, 1.0, (k, 2))
    np.testing.assert_allclose(sample_mipmapped(chain, st, np.full(k, 0.25)),
                               sample_mipmapped(chain[:1], st, np.ones(k)), rtol=0, atol=0)
