"""The multi-layer mucosa stack (Qian 6.2.3): energy conservation, reduction to the base, the wet
clear-coat highlight and the coat's absorption."""
from __future__ import annotations

import numpy as np
import pytest

from materials import get_preset
from materials.optics import MucosaLayers
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame
from tissuerender.renderer.bsdf.microfacet import refracted_cos
from tissuerender.renderer.bsdf.mucosa import layered_reflectance_cos
from tissuerender.renderer.bsdf.tissue import reflectance_cos


def _dirs(theta_o, k):
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    wo = np.tile([np.sin(theta_o), 0.0, np.cos(theta_o)], (k, 1))
    return n, wo


def _stack(k, layers: MucosaLayers, n, wo, wi, albedo=1.0, f0=0.027, alpha=0.3):
    """(the tissue lobes alone: a neutral coat and no granular lobe, the full stack)."""
    def stack(st):
        return layered_reflectance_cos(n, wo, wi, np.full((k, 3), albedo), np.full(k, alpha), np.full(k, f0), None,
                                       st.coat_roughness, st.coat_ior, st.coat_thickness,
                                       np.tile(st.coat_absorption, (k, 1)), np.full(k, st.granular_weight),
                                       np.full(k, st.granular_roughness))
    return stack(MucosaLayers(coat_ior=1.0, coat_thickness=0.0, granular_weight=0.0)), stack(layers)


def _cosine_hemisphere(k, seed=0):
    rng = np.random.default_rng(seed)
    u1, u2 = rng.random(k), rng.random(k)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=1)


@pytest.mark.parametrize("theta_deg", [0, 30, 60, 80, 89])
@pytest.mark.parametrize("coat_roughness", [0.02, 0.1, 0.4])
def test_white_furnace_stack_reflects_at_most_what_arrives(theta_deg, coat_roughness):
    # one-sample MIS between cosine sampling and sampling the coat's GGX half-vectors, so the sharp
    # coat lobe is estimated with low variance
    k = 400_000
    a = coat_roughness
    layers = MucosaLayers(coat_roughness=a, coat_absorption=(0.0, 0.0, 0.0), granular_weight=0.3)
    n, wo = _dirs(np.radians(theta_deg), k)
    rng = np.random.default_rng(2)
    u, v = rng.random(k), rng.random(k)
    cos_h = np.sqrt((1 - u) / (1 + (a * a - 1) * u))
    sin_h = np.sqrt(1 - cos_h**2)
    h = np.stack([sin_h * np.cos(2 * np.pi * v), sin_h * np.sin(2 * np.pi * v), cos_h], axis=1)
    wi_ggx = 2 * np.einsum("ij,ij->i", wo, h)[:, None] * h - wo
    wi = np.where((rng.random(k) < 0.5)[:, None], _cosine_hemisphere(k, 3), wi_ggx)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    above = wi[:, 2] > 0
    hh = wo + wi
    hh /= np.linalg.norm(hh, axis=1, keepdims=True)
    D = a * a / (np.pi * (hh[:, 2] ** 2 * (a * a - 1) + 1) ** 2)
    pdf = 0.5 * np.maximum(wi[:, 2], 0) / np.pi + 0.5 * D * hh[:, 2] / (4 * np.abs(np.einsum("ij,ij->i", wo, hh)))
    _, full = _stack(k, layers, n, wo, np.where(above[:, None], wi, [0.0, 0.0, 1.0]))
    albedo = np.sum(np.where(above, full[:, 0] / np.maximum(pdf, 1e-12), 0.0)) / k
    assert albedo <= 1.0 + 0.01  # Monte Carlo tolerance


def test_neutral_coat_leaves_the_tissue_specular_lobe_exactly():
    """ior 1 (F = 0, so the coat's albedo table is exactly 0), zero thickness, no granular lobe: the stack's
    specular part is the tissue's Cook-Torrance lobe itself (factors of exactly 1); with albedo 0 nothing else."""
    k = 1000
    n, wo = _dirs(0.4, k)
    wi = _cosine_hemisphere(k, 1)
    _, full = _stack(k, MucosaLayers(coat_ior=1.0, coat_thickness=0.0, granular_weight=0.0), n, wo, wi, albedo=0.0)
    f0 = np.full(k, 0.027)
    lobe = reflectance_cos(n, wo, wi, np.zeros((k, 3)), np.full(k, 0.3), f0)  # albedo 0: the GGX lobe alone
    np.testing.assert_allclose(full, lobe, rtol=1e-12, atol=0.0)


def test_wet_coat_adds_a_sharp_mirror_highlight():
    theta = np.radians(40.0)
    n, wo = _dirs(theta, 2)
    mirror = np.array([-np.sin(theta), 0.0, np.cos(theta)])
    off = np.array([-np.sin(theta + 0.3), 0.0, np.cos(theta + 0.3)])
    wi = np.stack([mirror, off])
    base, full = _stack(2, MucosaLayers(), n, wo, wi, albedo=0.5)
    assert full[0, 0] > 4 * base[0, 0]  # the glossy mucus highlight (Qian Fig. 6.9)
    # and the highlight is sharp: the stack's peak-to-off-peak ratio is far above the base's
    assert full[0, 0] / full[1, 0] > 3 * base[0, 0] / base[1, 0]


def test_coat_absorption_follows_the_refracted_path_length():
    theta = np.radians(50.0)
    n, wo = _dirs(theta, 1)
    wi = np.array([[0.3, 0.2, np.sqrt(1 - 0.13)]])
    clear = MucosaLayers(coat_absorption=(0.0, 0.0, 0.0), granular_weight=0.0, coat_roughness=0.02)
    tinted = MucosaLayers(coat_absorption=(2000.0, 0.0, 0.0), coat_thickness=300e-6, granular_weight=0.0,
                          coat_roughness=0.02)
    _, a = _stack(1, clear, n, wo, wi, albedo=0.5)
    _, b = _stack(1, tinted, n, wo, wi, albedo=0.5)
    mu_i, mu_o = wi[0, 2], np.cos(theta)
    path = 1 / refracted_cos(np.array(mu_i), 1.34) + 1 / refracted_cos(np.array(mu_o), 1.34)
    base_part_a = a[0, 0]  # the coat's own highlight is negligible this far from the mirror direction
    assert b[0, 0] == pytest.approx(base_part_a * np.exp(-2000.0 * 300e-6 * path), rel=1e-3)
    assert b[0, 1] == a[0, 1]  # green is not absorbed: exp(-0 x path) = 1 exactly, the same operations


def test_colon_mucosa_preset_has_the_stack_and_its_base_colour():
    optics = get_preset("colon_mucosa").optics
    assert optics.layers is not None
    base = np.array(optics.diffuse_albedo)
    assert np.all(base > 0) and np.all(base < 1) and base[0] > base[1] > 0  # pink-red


def test_colon_mucosa_texture_varies_across_the_surface_and_keeps_its_mean_colour():
    pts = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
    uv = pts[:, :2] * 1.0  # metres, like the box projection of procedural bodies
    slab = RenderObject(points=pts, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=uv,
                        material="colon_mucosa")
    cam = Camera(position=(0.0, 0.0, 0.08), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=60.0,
                 near=0.01, far=1.0, width=64, height=64)
    out = render_frame([slab], cam, AreaLight(samples=1), RenderSettings())
    albedo = out.gbuffer["albedo"]
    base = np.array(get_preset("colon_mucosa").optics.diffuse_albedo)
    # mottle and vessels: not a flat colour. Relative spread per channel: 6-9 % here (mip-filtered to the 64 px
    # footprint), 8-11 % at 256 px, 0 for a flat colour
    assert (albedo.std(axis=0) / albedo.mean(axis=0)).min() > 0.04
    assert np.allclose(albedo.mean(axis=0), base, rtol=0.15)  # but the preset's colour on average
    again = render_frame([slab], cam, AreaLight(samples=1), RenderSettings())
    assert np.array_equal(out.hdr, again.hdr)  # deterministic


def test_mucosa_relief_bends_the_shading_normals_slightly():
    pts = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
    slab = RenderObject(points=pts, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=pts[:, :2] * 1.0,
                        material="colon_mucosa")
    cam = Camera(position=(0.0, 0.0, 0.08), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=60.0,
                 near=0.01, far=1.0, width=64, height=64)
    n = render_frame([slab], cam, AreaLight(samples=1), RenderSettings()).gbuffer["normal"]
    tilt = np.degrees(np.arccos(np.clip(n[:, 2], -1, 1)))
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    assert 0.5 < tilt.mean() < 15.0 and tilt.max() < 45.0  # a fine relief, not a flat mirror, not noise
    assert abs(n[:, 0].mean()) < 0.05 and abs(n[:, 1].mean()) < 0.05  # no net tilt


def test_mucosa_roughness_map_modulates_the_tissue_and_granular_roughness():
    """The bake's roughness map reaches shading: the G-buffer roughness follows the mottle within
    0.7 ... 1.3 x the preset's alpha and averages to it."""
    pts = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
    slab = RenderObject(points=pts, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=pts[:, :2] * 1.0,
                        material="colon_mucosa")
    cam = Camera(position=(0.0, 0.0, 0.08), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=60.0,
                 near=0.01, far=1.0, width=64, height=64)
    alpha = render_frame([slab], cam, AreaLight(samples=1), RenderSettings()).gbuffer["roughness"]
    preset = get_preset("colon_mucosa").optics.roughness
    factor = alpha / preset
    assert factor.min() >= 0.7 - 1e-9 and factor.max() <= 1.3 + 1e-9
    assert factor.std() > 0.03  # it varies across the surface (measured 0.047)
    assert factor.mean() == pytest.approx(1.0, abs=0.1)
    layers = get_preset("colon_mucosa").optics.layers
    tex = layers.baked_roughness_factor()
    assert tex.shape == (layers.texture_size, layers.texture_size) and 0.7 <= tex.min() and tex.max() <= 1.3


def test_layer_channels_exist_only_with_a_layered_material_and_hold_its_values():
    pts = np.array([[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.05, 0.05, 0.0], [-0.05, 0.05, 0.0]])
    cam = Camera(position=(0.0, 0.0, 0.08), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=60.0,
                 near=0.01, far=1.0, width=32, height=32)

    def render(material):
        slab = RenderObject(points=pts, triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=pts[:, :2],
                            material=material)
        return render_frame([slab], cam, AreaLight(samples=1), RenderSettings()).gbuffer

    plain = render("plastic")
    assert "layer_albedo" not in plain and "mucus_weight" not in plain
    assert plain["specular"] == pytest.approx(get_preset("plastic").optics.f0)
    colon = render("colon_mucosa")
    layers = get_preset("colon_mucosa").optics.layers
    assert np.allclose(colon["layer_albedo"][:, 0], layers.connective_colour)
    assert np.allclose(colon["layer_albedo"][:, 1], layers.submucosa_colour)
    # water-like coat seen nearly head-on: Fresnel ((n - 1) / (n + 1))^2 = 0.021 for n = 1.34, a little
    # more towards the image corners
    f_normal = ((layers.coat_ior - 1) / (layers.coat_ior + 1)) ** 2
    assert colon["mucus_weight"].min() == pytest.approx(f_normal, rel=0.02)
    assert colon["mucus_weight"].max() < 2 * f_normal
