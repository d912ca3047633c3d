"""The ratio estimator of the area light's diffuse term (light.estimator = "ratio"; Heitz, Hill & McGuire
2018): the closed-form unshadowed cosine integral of the rectangle, times the sampled (f V) / (n.wi)."""
from __future__ import annotations

import numpy as np
import pytest

from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame
from tissuerender.renderer.light import irradiance, light_frame, unshadowed_cosine_integral
from tissuerender.renderer.shade_kernel import rect_cosine_integral
from tissuerender.scene.schema import Light

CAM = Camera((0, -1, 1), (0, 0, 0), (0, 0, 1), 60, 0.01, 10, 8, 8)


def _corner_form_factor(a, b, c):
    """Point-to-parallel-rectangle form factor, the point below one corner (sides a, b, distance c)."""
    A, B = a / c, b / c
    return (A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
            + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))) / (2 * np.pi)


def _brute_force(p, n, centre, ln, eu, ev, cells=2000):
    """Midpoint rule of int (n.wi)+ cos(theta_l)+ / r^2 dA over the rectangle."""
    u = (np.arange(cells) + 0.5) / cells * 2 - 1
    U, V = np.meshgrid(u, u)
    d = centre + U[..., None] * eu + V[..., None] * ev - p
    r2 = (d * d).sum(-1)
    w = d / np.sqrt(r2)[..., None]
    f = np.clip(w @ n, 0, None) * np.clip(-(w @ ln), 0, None) / r2
    return f.mean() * 4 * np.linalg.norm(eu) * np.linalg.norm(ev)


def test_closed_form_matches_the_rectangle_form_factor_and_clips_at_the_horizon():
    h, w, l = 0.1, 0.02, 0.03
    centre, ln = np.array([0.0, 0.0, h]), np.array([0.0, 0.0, -1.0])
    eu, ev = np.array([w / 2, 0.0, 0.0]), np.array([0.0, l / 2, 0.0])
    # below the centre: four corner rectangles; the cosine integral is pi times the form factor. Both sides: ~100
    # float64 operations and 8 arctangents (libm: <= 1 ulp each): (100 + 16) u = 1.3e-14, bound 1e-13
    assert rect_cosine_integral(0, 0, 0, 0, 0, 1.0, centre, ln, eu, ev) == pytest.approx(
        np.pi * 4 * _corner_form_factor(w / 2, l / 2, h), rel=1e-13)
    # tilted normals cut the light with the horizon (one with the light half below it)
    rng = np.random.default_rng(1)
    for n in [(1.0, 0.0, 0.0), (1.0, 0.0, 0.3), (0.3, -1.0, 0.05), (0.2, 0.1, 1.0), (0.0, 1.0, 0.0)]:
        n = np.asarray(n) / np.linalg.norm(n)
        p = rng.uniform(-0.01, 0.01, 3) * [1, 1, 0]
        exact = rect_cosine_integral(*p, *n, centre, ln, eu, ev)
        assert exact == pytest.approx(_brute_force(p, n, centre, ln, eu, ev), rel=2e-6)
    # behind the light, or the light wholly below the horizon: nothing
    assert rect_cosine_integral(0, 0, 0.2, 0, 0, -1.0, centre, ln, eu, ev) == 0.0
    assert rect_cosine_integral(0, 0, 0, 0, 0, -1.0, centre, ln, eu, ev) == 0.0


@pytest.mark.parametrize("distance", [0.02, 0.3, 3.0, 300.0])
def test_small_angle_series_agrees_with_the_arctangent(distance):
    """Far from the light each edge subtends a small angle and the edge term uses a series instead of
    arctan2: both forms agree to round-off at every distance: four edge terms of ~30 operations and an arctangent
    (<= 1 ulp) each, the series truncated below u: (4 x 32) u = 1.4e-14 relative, bound 1e-13."""
    centre, ln = np.zeros(3), np.array([0.0, 0.0, -1.0])
    eu, ev = np.array([0.006, 0.0, 0.0]), np.array([0.0, 0.004, 0.0])
    p = np.array([0.003, -0.002, -distance])
    n = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    corners = [centre - eu - ev, centre + eu - ev, centre + eu + ev, centre - eu + ev]
    total = 0.0
    for k in range(4):
        a, b = corners[k] - p, corners[(k + 1) % 4] - p
        c = np.cross(a, b)
        total += np.arctan2(np.linalg.norm(c), a @ b) * (n @ c) / np.linalg.norm(c)
    assert rect_cosine_integral(*p, *n, centre, ln, eu, ev) == pytest.approx(0.5 * abs(total), rel=1e-13)


def _patch_light(samples, estimator):
    return AreaLight(size=(0.02, 0.03), radiance=(1000.0,) * 3, attach="world", position=(0.01, 0.0, 0.1),
                     normal=(0, 0, -1), up=(0, 1, 0), sampling="uniform", samples=samples, estimator=estimator)


def _patch_points(k=200, seed=3):
    rng = np.random.default_rng(seed)
    pos = np.column_stack([rng.uniform(-0.05, 0.05, k), rng.uniform(-0.05, 0.05, k), np.zeros(k)])
    n = rng.normal(size=(k, 3)) * [0.3, 0.3, 0.0] + [0.0, 0.0, 1.0]
    return pos, n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.mark.parametrize("m", [1, 2, 7, 64])
def test_unshadowed_lambert_patch_equals_the_closed_form_at_any_sample_count(m):
    pos, n = _patch_points()
    light = _patch_light(m, "ratio")
    exact = 1000.0 * unshadowed_cosine_integral(pos, n, *light_frame(light, CAM))
    np.testing.assert_allclose(irradiance(pos, n, light, CAM, np.full(len(pos), m)), exact, rtol=1e-12)
    # the plain Monte Carlo estimate is not exact at a few samples
    mc = irradiance(pos, n, _patch_light(m, "mc"), CAM, np.full(len(pos), m))
    if m < 64:
        assert np.abs(mc / exact - 1).max() > 1e-4


def test_half_shadowed_estimate_converges_to_the_exact_integral_as_m_grows():
    """A straight occluder edge hides the light's half x < x0 from every point: the exact answer is the
    closed form over the visible sub-rectangle. The ratio estimator's error falls with m (below 4 % at
    64 samples, where 35 % of the light is visible), and the fully lit points stay exact."""
    pos, n = _patch_points(300, seed=4)
    light = _patch_light(1, "ratio")
    centre, ln, eu, ev = light_frame(light, CAM)
    shadowed = np.arange(len(pos)) % 2 == 0

    def visible(p, q):  # the edge crosses the light at u = 0.3 (local coordinate, -1 ... 1)
        return ~shadowed | ((q - centre) @ eu / (eu @ eu) >= 0.3)

    lit_half_u = (1.0 - 0.3) / 2.0  # visible part of the light: u in [0.3, 1]
    sub_centre = centre + (0.3 + lit_half_u) * eu
    exact = np.where(shadowed, unshadowed_cosine_integral(pos, n, sub_centre, ln, eu * lit_half_u, ev),
                     unshadowed_cosine_integral(pos, n, centre, ln, eu, ev)) * 1000.0
    errors = {}
    for est in ("ratio", "mc"):
        for m in (1, 4, 16, 64):
            lt = _patch_light(m, est)
            e = irradiance(pos, n, lt, CAM, np.full(len(pos), m), seed=m, visible=visible)
            errors[est, m] = np.sqrt(np.mean((e - exact)[shadowed] ** 2)) / exact[shadowed].mean()
            if est == "ratio":
                np.testing.assert_allclose(e[~shadowed], exact[~shadowed], rtol=1e-12)
    ratio = [errors["ratio", m] for m in (1, 4, 16, 64)]
    assert all(b < a for a, b in zip(ratio, ratio[1:]))
    # measured 1.37, 0.37, 0.10, 0.022: the stratified points' error falls about as 1/m across an edge,
    # like the Monte Carlo estimate's (the ratio only removes the unshadowed part of the noise)
    assert ratio[-1] < 0.04 and ratio[0] / ratio[-1] > 30


def _floor_and_blocker():
    def quad(z, size, material):
        p = np.array([[-size, -size, z], [size, -size, z], [size, size, z], [-size, size, z]])
        return RenderObject(points=p, triangles=np.array([[0, 1, 2], [0, 2, 3]]),
                            normals=np.tile([0.0, 0.0, 1.0], (4, 1)), uv=None, material=material)

    return [quad(0.0, 0.2, "liver"), quad(0.15, 0.03, "plastic")]


def _frame(estimator, samples, seed=5, material="liver"):
    objects = _floor_and_blocker()
    objects[0].material = material
    cam = Camera((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0, 0.01, 5.0, 48, 36)
    light = AreaLight(size=(0.03, 0.02), radiance=(2000.0,) * 3, attach="world", position=(0.01, 0.0, 0.25),
                      normal=(0, 0, -1), sampling="uniform", samples=samples, estimator=estimator)
    return render_frame(objects, cam, light, RenderSettings(shadows=True, sss=True, seed=seed)).hdr


@pytest.mark.parametrize("material", ["liver", "colon_mucosa", "plastic"])
def test_renderer_ratio_estimate_converges_to_the_monte_carlo_one(material):
    """Whole frames with shadows, SSS and each kind of material (tissue, mucosa stack, rough plastic):
    the ratio estimate approaches a 1024-sample Monte Carlo frame as m grows, and at 4 samples it is
    closer than Monte Carlo with 4 samples; the same seed gives the same bits."""
    reference = _frame("mc", 1024, material=material)
    scale = float(np.sqrt(np.mean(reference ** 2)))
    err = {(est, m): float(np.sqrt(np.mean((_frame(est, m, material=material) - reference) ** 2))) / scale
           for est in ("ratio", "mc") for m in (1, 4, 64)}
    assert err["ratio", 1] > err["ratio", 4] > err["ratio", 64]
    assert err["ratio", 64] < 0.01
    assert err["ratio", 4] < err["mc", 4]
    assert np.array_equal(_frame("ratio", 4, seed=9, material=material), _frame("ratio", 4, seed=9, material=material))


def test_ratio_estimator_options_are_validated():
    assert Light().estimator == "ratio"  # the default, chosen by benchmarks/render_convergence.py
    assert Light(reflection_cone=True).estimator == "mc"  # the cone's NumPy path has no ratio estimator
    with pytest.raises(ValueError, match="reflection_cone"):
        Light(estimator="ratio", reflection_cone=True)
    with pytest.raises(ValueError):
        Light(estimator="analytic")
    cam = Camera((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0, 0.01, 5.0, 8, 8)
    with pytest.raises(NotImplementedError, match="ratio"):
        render_frame(_floor_and_blocker(), cam, AreaLight(estimator="ratio"), RenderSettings(fused=False))
    with pytest.raises(ValueError, match="estimator"):
        render_frame(_floor_and_blocker(), cam, AreaLight(estimator="exact"), RenderSettings())


def _penumbra_frame(penumbra, samples=2, estimator="ratio", ss=1):
    objects = _floor_and_blocker()
    cam = Camera((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0, 0.01, 5.0, 48, 36)
    light = AreaLight(size=(0.03, 0.02), radiance=(2000.0,) * 3, attach="world", position=(0.01, 0.0, 0.25),
                      normal=(0, 0, -1), sampling="uniform", samples=samples, estimator=estimator,
                      penumbra_samples=penumbra)
    return render_frame(objects, cam, light, RenderSettings(shadows=True, sss=True, seed=5, supersampling=ss)).hdr


@pytest.mark.parametrize("estimator,ss", [("ratio", 1), ("mc", 2)])
def test_penumbra_samples_reshade_only_the_penumbra_and_lower_its_error(estimator, ss):
    """Pixels whose first shadow rays disagree (and their neighbours) are shaded again with more samples:
    the rest of the frame keeps its bits, and the error against a converged frame falls."""
    reference = _frame("mc", 1024)
    if ss > 1:
        reference = _penumbra_frame(0, 256, "mc", ss)
    plain, refined = _penumbra_frame(0, 2, estimator, ss), _penumbra_frame(32, 2, estimator, ss)
    changed = np.any(plain != refined, axis=2)
    assert 0.01 < changed.mean() < 0.5  # the blocker's penumbra, not the whole frame
    def err(img, where=slice(None)):
        return float(np.sqrt(np.mean(((img - reference) ** 2)[where])))

    # measured: 14x lower on the re-shaded pixels, 1.3-1.5x lower over the frame (the rest is the penumbra
    # the first rays missed, and the specular noise)
    assert err(refined, changed) < 0.2 * err(plain, changed)
    assert err(refined) < 0.85 * err(plain)
    assert np.array_equal(refined, _penumbra_frame(32, 2, estimator, ss))  # deterministic
    # without shadows there is no penumbra: the option changes nothing
    cam = Camera((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0, 0.01, 5.0, 16, 12)
    no_shadows = [render_frame(_floor_and_blocker(), cam, AreaLight(samples=2, penumbra_samples=p),
                               RenderSettings(sss=True, seed=5)).hdr for p in (0, 32)]
    assert np.array_equal(*no_shadows)


def test_penumbra_samples_are_validated():
    assert Light(penumbra_samples=16).penumbra_samples == 16
    with pytest.raises(ValueError, match="reflection_cone"):
        Light(penumbra_samples=16, reflection_cone=True)
    with pytest.raises(ValueError):
        Light(penumbra_samples=-1)
