"""The OSMesa (GLSL) backend agrees with the NumPy reference on every effect."""
from __future__ import annotations

import numpy as np
import pytest

import postfx
from postfx import depth_of_field, pointwise
from postfx.bloom import Bloom
from postfx.blur import Blur
from postfx.chromatic_aberration import ChromaticAberration
from postfx.color_grade import ColorGrade
from postfx.depth_of_field import DepthOfField
from postfx.gl import chain as gl_chain
from postfx.gl import context
from postfx.laparoscope_mask import LaparoscopeMask
from postfx.lens_flare import LensFlare
from postfx.registry import EFFECTS
from postfx.sensor_noise import SensorNoise
from postfx.sharpen import Sharpen
from postfx.tonemap import Tonemap

# tests marked osmesa skip where the backend cannot run, and fail under CI=true (tests/conftest.py)
H, W = 120, 160
LENS = postfx.Lens(70.0, W, H)
# Tolerances. GLSL computes in float32 (unit roundoff u32 = 2^-24 = 6e-8), the NumPy reference in float32 or float64,
# and the driver may contract a * b + c into an FMA or evaluate exp / pow to a few ulp (the GLSL specification
# allows that):
# - one effect, relative to the image's peak: a gather of up to 97 taps (sigma 16) sums 97 terms, each rounded
#   <= u32, plus ~30 operations for the weight: <= 130 u32 = 7.8e-6 -> 1e-5; pointwise effects (~30 operations):
#   <= 30 u32 = 1.8e-6 -> 2e-6;
# - fused against separate passes: the same operations, intermediates kept in RGBA32F textures (exact), the order
#   of a few additions changed by the compiler: <= 16 u32 = 1e-6;
# - a whole chain with its tonemap's exp and pow, after 8-bit quantisation: at most 2 levels (a value within 1e-3
#   of a rounding boundary may land on either side, and the curve's slope reaches 2 levels per 1e-3 in the toe).
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


@pytest.mark.osmesa
def test_full_chain_agrees_and_auto_prefers_osmesa():
    hdr, depth = _inputs()
    chain = [(n, CASES[n]) for n in postfx.DEFAULT_ORDER]
    ref = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy").image
    auto = postfx.apply_chain(hdr, depth, chain, LENS, backend="auto")
    assert auto.backend_used == "osmesa"
    assert np.abs(postfx.to_uint8(ref).astype(int) - postfx.to_uint8(auto.image).astype(int)).max() <= 2


def test_missing_osmesa_names_the_package_and_auto_falls_back(monkeypatch):
    monkeypatch.setattr(context, "library_available", lambda: False)
    monkeypatch.setattr(context.Context, "_instance", None)
    hdr, depth = _inputs()
    chain = [("tonemap", Tonemap())]
    with pytest.raises(postfx.OSMesaUnavailable, match="libosmesa6"):
        postfx.apply_chain(hdr, depth, chain, LENS, backend="osmesa")
    assert postfx.apply_chain(hdr, depth, chain, LENS, backend="auto").backend_used == "numpy"


@pytest.mark.osmesa
@pytest.mark.parametrize("shape", [(23, 37), (70, 90)])
def test_blocked_dof_gather_matches_numpy_on_odd_sizes_and_random_coc(shape):
    """Partial 4x4 blocks and 16 px tiles at the image edge, every pixel with its own CoC (up to 6 px)."""
    rng = np.random.default_rng(3)
    h, w = shape
    hdr = (rng.random((h, w, 3)) * 4.0).astype(np.float32)
    depth = (0.05 + rng.random((h, w)) * 0.2).astype(np.float32)
    depth[:, : w // 2] = 0.1  # the left half in focus: at 90 px its first tiles get a bound of 1/4
    p = DepthOfField(focus_distance=0.1, aperture=0.002, max_radius_px=6.0)
    lens = postfx.Lens(70.0, w, h)
    if w == 90:
        assert depth_of_field.dof_tiles(depth_of_field.dof_reach2(depth_of_field.coc_radius_px(depth, p, 70.0, w)))[:, 0].max() == 0.25
    ref = postfx.apply_effect("depth_of_field", hdr, depth, p, lens)
    gpu = gl_chain.apply_effect("depth_of_field", hdr, depth, p, lens)
    assert np.abs(ref - gpu).max() <= 1e-5 * np.abs(ref).max()


def test_dof_tiles_bound_every_source_that_reaches_the_tile():
    rng = np.random.default_rng(5)
    reach2 = (rng.random((40, 50)) ** 4 * 30.0 + 0.25).astype(np.float32)
    reach2[5, 7] = 100.25  # one wide disc (r = 10)
    tiles = depth_of_field.dof_tiles(reach2)
    tile = depth_of_field.DOF_TILE
    assert tiles.shape == (3, 4)
    jq, iq = np.mgrid[0:40, 0:50]
    for ty in range(3):
        for tx in range(4):
            bound = 0.0  # brute force: the largest reach2 of the sources whose disc covers a pixel of the tile
            for j in range(ty * tile, min((ty + 1) * tile, 40)):
                for i in range(tx * tile, min((tx + 1) * tile, 50)):
                    covers = (jq - j) ** 2 + (iq - i) ** 2 <= reach2
                    bound = max(bound, float(reach2[covers].max()))
            assert tiles[ty, tx] >= bound


@pytest.mark.osmesa
def test_fused_pointwise_passes_equal_the_separate_passes():
    hdr, depth = _inputs()
    chain = [(n, CASES[n]) for n in postfx.DEFAULT_ORDER]
    fused, seconds, _ = gl_chain.run_chain(hdr, depth, chain, LENS, seed=3)
    separate, separate_seconds, _ = gl_chain.run_chain(hdr, depth, chain, LENS, seed=3, fuse=False)
    assert "blur+sensor_noise+tonemap+color_grade" in seconds and "sharpen+laparoscope_mask" in seconds
    assert set(separate_seconds) == set(postfx.DEFAULT_ORDER)
    assert np.abs(fused - separate).max() <= 1e-6
    res = postfx.apply_chain(hdr, depth, chain, LENS, backend="osmesa", seed=3)  # seconds keyed by effect names
    assert res.fused == {"blur": ["sensor_noise", "tonemap", "color_grade"], "sharpen": ["laparoscope_mask"]}
    assert set(res.seconds) == set(postfx.DEFAULT_ORDER) - {"sensor_noise", "tonemap", "color_grade", "laparoscope_mask"}


@pytest.mark.osmesa
@pytest.mark.parametrize("sigma", [0.6, 16.0])
def test_blocked_gaussian_matches_numpy_on_odd_sizes(sigma):
    """Blocks of 4 outputs with partial blocks at the edges; at sigma 16 (97 taps) the taps reach far
    past the 23 x 37 image, so most of them are clamped to its edge."""
    rng = np.random.default_rng(11)
    img = (rng.random((23, 37, 3)) * 4.0).astype(np.float32)
    lens = postfx.Lens(70.0, 37, 23)
    for name, p in (("blur", Blur(sigma_px=sigma)), ("sharpen", Sharpen(amount=0.7, sigma_px=min(sigma, 8.0)))):
        x = img if name == "blur" else img / 4.0
        ref = postfx.apply_effect(name, x, None, p, lens)
        gpu = gl_chain.apply_effect(name, x, None, p, lens)
        assert np.abs(ref - gpu).max() <= 2e-6 * max(1.0, float(np.abs(ref).max()))


@pytest.mark.parametrize("width", [W, 37])  # odd width: noise pairs straddle rows
def test_numpy_pointwise_run_equals_the_effects_one_after_the_other(width):
    hdr, depth = _inputs()
    hdr, depth = hdr[:, :width].copy(), depth[:, :width].copy()
    lens = postfx.Lens(70.0, width, H)
    run = [(n, CASES[n]) for n in ("sensor_noise", "tonemap", "color_grade", "laparoscope_mask")]
    separate = hdr
    for name, p in run:
        separate = postfx.apply_effect(name, separate, depth, p, lens, seed=9).astype(np.float32)
    assert np.array_equal(pointwise.pointwise_chain(hdr, run, seed=9), separate)  # to the bit
    res = postfx.apply_chain(hdr, depth, [("blur", CASES["blur"]), *run], lens, backend="numpy", seed=9)
    assert res.fused == {"sensor_noise": ["tonemap", "color_grade", "laparoscope_mask"]}
    assert set(res.seconds) == {"blur", "sensor_noise"}


@pytest.mark.osmesa
def test_a_repeated_pointwise_effect_starts_a_new_pass():
    hdr, depth = _inputs()
    chain = [("blur", CASES["blur"]), ("tonemap", Tonemap(exposure=-1.0)), ("tonemap", Tonemap(exposure=0.5, curve="reinhard"))]
    assert [[n for n, _ in g] for g in gl_chain.fused_groups(chain)] == [["blur", "tonemap"], ["tonemap"]]
    ref = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy").image
    gpu = postfx.apply_chain(hdr, depth, chain, LENS, backend="osmesa").image
    assert np.abs(ref - gpu).max() < 1e-5


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_osmesa_reach2_kernel_equals_numpy_to_the_bit(dtype):
    """depth_of_field.coc_reach2 (one numba loop) selects the gather's taps: it must give the very float32
    reach2 of depth_of_field.dof_reach2(depth_of_field.coc_radius_px(...)), special depths included, and the tile maxima."""
    rng = np.random.default_rng(13)
    h, w = 37, 53  # partial tiles on both axes
    depth = (rng.random((h, w)) * 0.4 - 0.02).astype(dtype)  # some at or behind the camera
    depth.flat[:6] = [np.inf, -np.inf, np.nan, 0.0, 0.1, 1e-12]
    for p, fov in ((DepthOfField(focus_distance=0.1, aperture=0.002, max_radius_px=8.0), 70.0),
                   (DepthOfField(focus_distance=0.0047, aperture=0.003, focal_length=0.0045, max_radius_px=64.0), 30.0),
                   (DepthOfField(), 75.0)):
        ref = depth_of_field.dof_reach2(depth_of_field.coc_radius_px(depth, p, fov, w))
        reach2, tiles = depth_of_field.coc_reach2(depth, p, fov, w)
        assert reach2.dtype == np.float32 and np.array_equal(reach2.view(np.uint32), ref.view(np.uint32))
        padded = np.full((48, 64), -1.0, np.float32)
        padded[:h, :w] = ref
        assert np.array_equal(tiles, padded.reshape(3, 16, 4, 16).max(axis=(1, 3)))
        assert np.array_equal(depth_of_field.dilate_tiles(tiles, float(ref.max())), depth_of_field.dof_tiles(ref))


@pytest.mark.osmesa
def test_dof_after_another_effect_builds_its_source_on_the_gl_side():
    """The first effect of a chain reads the frame from the CPU (the DoF then builds its padded source
    there); a DoF later in the chain draws the source pass from a texture. Both agree with NumPy on the
    linear HDR result (before any clipping)."""
    hdr, depth = _inputs()
    p = CASES["depth_of_field"]
    for chain in ([("depth_of_field", p)], [("blur", CASES["blur"]), ("depth_of_field", p)]):
        ref = hdr
        for name, params in chain:
            ref = postfx.apply_effect(name, ref, depth, params, LENS)
        gpu, _, _ = gl_chain.run_chain(hdr, depth, chain, LENS)
        assert np.abs(gpu - ref).max() <= 1e-5 * float(np.abs(ref).max())
    chain = [("depth_of_field", p), ("tonemap", CASES["tonemap"]), ("laparoscope_mask", CASES["laparoscope_mask"])]
    fused, seconds, _ = gl_chain.run_chain(hdr, depth, chain, LENS)  # the pointwise run drawn inside the gather
    assert list(seconds) == ["depth_of_field+tonemap+laparoscope_mask"]
    separate, _, _ = gl_chain.run_chain(hdr, depth, chain, LENS, fuse=False)
    assert np.abs(fused - separate).max() <= 1e-6
    ref = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy").image
    assert np.abs(np.clip(fused, 0.0, 1.0) - ref).max() <= 1e-5



@pytest.mark.osmesa
def test_dof_source_reused_between_frames_keeps_each_frame_exact():
    """The DoF's padded source lives in a host array and a texture kept from chain to chain: a second
    frame of the same size (other colours, other CoC, then a larger CoC that widens the padding)
    must come out as if computed afresh."""
    rng = np.random.default_rng(17)
    h, w = 40, 56
    lens = postfx.Lens(70.0, w, h)
    for max_r in (4.0, 4.0, 7.0):
        hdr = (rng.random((h, w, 3)) * 4.0).astype(np.float32)
        depth = (0.05 + rng.random((h, w)) * 0.2).astype(np.float32)
        p = DepthOfField(focus_distance=0.1, aperture=0.002, max_radius_px=max_r)
        ref = postfx.apply_effect("depth_of_field", hdr, depth, p, lens)
        gpu = gl_chain.apply_effect("depth_of_field", hdr, depth, p, lens)
        assert np.abs(ref - gpu).max() <= 1e-5 * np.abs(ref).max()


@pytest.mark.osmesa
def test_dof_stores_reach_the_next_pass_without_a_barrier_on_llvmpipe():
    """On llvmpipe the gather's imageStore results are read by the next pass without glMemoryBarrier
    (a full finish there): the same bits as with it, chained into effects that read neighbours."""
    hdr, depth = _inputs()
    chain = [("depth_of_field", CASES["depth_of_field"]), ("chromatic_aberration", CASES["chromatic_aberration"]),
             ("blur", CASES["blur"]), ("tonemap", Tonemap())]
    ctx = context.Context.get()
    if "llvmpipe" not in ctx.renderer:
        pytest.skip(f"renderer {ctx.renderer!r}: the barrier is kept")
    assert not ctx.barrier_after_stores
    try:
        ctx.barrier_after_stores = True
        with_barrier, _, _ = gl_chain.run_chain(hdr, depth, chain, LENS, seed=2)
    finally:
        ctx.barrier_after_stores = False
    without, _, _ = gl_chain.run_chain(hdr, depth, chain, LENS, seed=2)
    assert np.array_equal(with_barrier, without)
    ref = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy", seed=2).image
    assert np.abs(np.clip(without, 0.0, 1.0) - ref).max() < 1e-3


@pytest.mark.osmesa
def test_effect_seconds_are_keyed_by_the_fused_groups():
    """The passes are queued without a wait per effect; each group of fused effects gets the difference
    of its GL timestamps, under the names of its effects joined by "+" (no assertion on the figures:
    issue 16, no timing assertions in tests)."""
    hdr, depth = _inputs()
    chain = [(n, CASES[n]) for n in postfx.DEFAULT_ORDER]
    _, seconds, total = gl_chain.run_chain(hdr, depth, chain, LENS)
    assert list(seconds) == ["depth_of_field", "chromatic_aberration", "lens_flare", "bloom",
                             "blur+sensor_noise+tonemap+color_grade", "sharpen+laparoscope_mask"]
    assert all(np.isfinite(v) for v in [*seconds.values(), total])


@pytest.mark.osmesa
def test_row_blocked_last_pass_is_read_back_in_place_and_its_target_reused_cleanly():
    """A chain ending in a Gaussian of radius <= 3 writes 4 rows per fragment into the layers of a 3D
    target and reads them back row by row; the same pooled target then serves a horizontal pass of
    another image (16 x 8 row-blocked is 16 x 2 x 4, the blocks of a 64 x 2 image): both exact."""
    rng = np.random.default_rng(5)
    for h, w in ((8, 16), (2, 64), (7, 16), (8, 16)):
        img = (rng.random((h, w, 3)) * 2.0).astype(np.float32)
        lens = postfx.Lens(70.0, w, h)
        chain = [("blur", Blur(sigma_px=1.0)), ("sharpen", Sharpen(amount=0.6, sigma_px=0.8))]
        ref = postfx.apply_chain(img, None, chain, lens, backend="numpy").image
        gpu = postfx.apply_chain(img, None, chain, lens, backend="osmesa").image
        assert np.abs(ref - gpu).max() <= 2e-6
    assert not context.Context.get().row_blocked  # every row-blocked target was read back or released
    # a row-blocked blur read by a sharpen that is not last (its unsharp mask fetches the blocked rows,
    # one output per fragment), and Gaussians of larger radius on either side (plain images between)
    img = (rng.random((13, 21, 3)) * 2.0).astype(np.float32)
    lens = postfx.Lens(70.0, 21, 13)
    for chain in ([("blur", Blur(sigma_px=1.0)), ("sharpen", Sharpen(amount=0.6, sigma_px=0.8)),
                   ("chromatic_aberration", ChromaticAberration(strength_r=0.01))],
                  [("blur", Blur(sigma_px=3.0)), ("sharpen", Sharpen(amount=0.6, sigma_px=0.8))],
                  [("blur", Blur(sigma_px=1.0)), ("sharpen", Sharpen(amount=0.6, sigma_px=3.0))]):
        ref = postfx.apply_chain(img, None, chain, lens, backend="numpy").image
        gpu = postfx.apply_chain(img, None, chain, lens, backend="osmesa").image
        assert np.abs(ref - gpu).max() <= 1e-5


@pytest.mark.osmesa
@pytest.mark.parametrize("h, w", [(120, 160), (23, 37), (75, 100), (480, 640)])
def test_dof_gather_stores_every_output(h, w):
    """The gather stores every output with imageStore (partial blocks at odd sizes): the output target
    comes from the pool pre-filled with NaN here, so an output it missed would show (a pooled target
    holding an earlier, equal result would hide it)."""
    rng = np.random.default_rng(h + w)
    img = (rng.random((h, w, 3)) * 3.0).astype(np.float32)
    depth = (0.05 + 0.2 * rng.random((h, w))).astype(np.float32)
    lens = postfx.Lens(70.0, w, h)
    p = DepthOfField(focus_distance=0.1, aperture=0.003, max_radius_px=6.0)
    ctx = context.Context.get()
    nan = ctx.upload(np.full((h, w, 3), np.nan, np.float32))
    ctx.release(ctx.draw("copy", {"img": nan}, {}, w, h))  # the next w x h target holds NaN
    gpu, _, _ = gl_chain.run_chain(img, depth, [("depth_of_field", p)], lens)
    ref = postfx.apply_effect("depth_of_field", img, depth, p, lens)
    assert np.isfinite(gpu).all()
    assert np.abs(gpu - ref).max() <= 1e-5 * float(np.abs(ref).max())
