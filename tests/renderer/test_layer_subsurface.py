"""Per-layer subsurface colour and attenuation of the layered tissue (issue 19 item 1): each tissue layer's
``sss_colour`` and ``sigma`` reach the thickness term as ``materials.optics.OpticalMaterial.subsurface_colour``
and ``layered_transmittance`` say, in the numba pass and the NumPy estimator alike."""
from __future__ import annotations

import numpy as np
import pytest

from materials import get_preset
from materials.optics import optical_value, untextured, with_overrides
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame

GAP = 0.6e-3  # the slab's thickness [m]: more than the colon's 0.4 mm connective layer, so both layers count


def _slab(optics):
    """Two facing quads GAP apart: the top one's inward thickness rays hit the bottom one at T = GAP."""
    s = 0.1
    top = np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])
    bottom = top - [0.0, 0.0, GAP]
    return [RenderObject(points=top, triangles=np.array([[0, 1, 2], [0, 2, 3]]),
                         normals=np.tile([0.0, 0.0, 1.0], (4, 1)), uv=None, material="colon_mucosa", optics=optics),
            RenderObject(points=bottom, triangles=np.array([[0, 2, 1], [0, 3, 2]]),
                         normals=np.tile([0.0, 0.0, -1.0], (4, 1)), uv=None, material="colon_mucosa", optics=optics)]


def _render(optics, fused=True):
    cam = Camera((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 0.01, 5.0, 24, 18)
    light = AreaLight(size=(0.02, 0.02), radiance=(2000.0,) * 3, attach="world", position=(0.0, 0.0, 0.25),
                      normal=(0, 0, -1), samples=4)
    return render_frame(_slab(optics), cam, light,
                        RenderSettings(sss=True, shadows=True, seed=3, fused=fused, ray_backend="numba")).hdr


def _colon(**layer):
    # untextured: a uniform albedo; no coat absorption: the light under the coat is white, so the subsurface
    # term's colour is all the pixels' colour differences carry
    return with_overrides(untextured(get_preset("colon_mucosa").optics), {"coat_absorption": [0.0, 0.0, 0.0], **layer})


def test_connective_sss_colour_moves_the_subsurface_chromaticity_as_the_layer_weights_predict():
    base = _colon()
    green = _colon(connective_sss_colour=[0.2, 0.8, 0.2], connective_sigma=[300.0, 300.0, 300.0])
    # the model written out (not through the code under test): colon connective layer d = 0.4 mm with
    # absorption (250, 900, 1300) /m, e = exp(-2 a d) its round trip; C = c3 (1 - e) + c4 e, c4 the preset's
    # sss_colour; transmittance over T = GAP: exp(-s3 d - s4 (T - d)) with s4 the preset's sigma
    d, a = 0.4e-3, np.array([250.0, 900.0, 1300.0])
    e = np.exp(-2.0 * a * d)
    c4, s4 = np.array([0.85, 0.3, 0.25]), np.array([500.0, 1800.0, 2600.0])
    C_new = np.array([0.2, 0.8, 0.2]) * (1.0 - e) + c4 * e
    t_new = np.exp(-300.0 * d - s4 * (GAP - d))
    t_old = np.exp(-s4 * GAP)
    assert optical_value(base, "connective_sss_colour") == base.sss_colour  # unset: the material's value
    np.testing.assert_allclose(green.subsurface_colour, C_new, rtol=1e-14)
    a_img, b_img = _render(base), _render(green)
    # only k_sss C t / pi changed, times a light transport that is the same in every channel; the difference
    # image's chromaticity is that of C_new t_new - C_old t_old
    diff = (b_img - a_img).reshape(-1, 3).sum(axis=0)
    predicted = C_new * t_new - c4 * t_old
    assert predicted[1] > 0.0 > predicted[0]  # the model says: more green, less red
    # float32 HDR sums of ~400 pixels (relative 400 x 2^-24 ~ 2.4e-5 each) and the thickness rays' offsets
    # (1e-6 x scene extent ~ 2e-7 m, times sigma <= 2600 /m: 5e-4 relative): 2e-3 on the ratios
    np.testing.assert_allclose(diff / diff[1], predicted / predicted[1], rtol=2e-3, atol=2e-3)
    # and the numba pass agrees with the NumPy estimator on the per-layer term (the same samples summed in
    # another order into float32: 4 samples x ~10 terms ~ 40 roundings of 2^-24, ~2.4e-6 relative)
    np.testing.assert_allclose(_render(green), _render(green, fused=False), rtol=1e-5, atol=1e-6 * float(b_img.max()))


def test_a_connective_layer_of_zero_thickness_has_no_effect():
    thin = _colon(connective_thickness=0.0)
    other = _colon(connective_thickness=0.0, connective_sss_colour=[0.1, 0.9, 0.1],
                   connective_sigma=[10.0, 10.0, 10.0], connective_colour=[0.1, 0.9, 0.9])
    assert other.subsurface_colour == thin.subsurface_colour == thin.sss_colour
    np.testing.assert_array_equal(_render(other), _render(thin))


@pytest.mark.parametrize("name", ["liver", "colon_mucosa", "fat"])
def test_presets_without_layer_values_keep_the_single_layer_term_to_the_bit(name):
    """The defaults (None: the material's sss_colour and sigma) leave the shipped presets' pixels unchanged:
    the layered form with depth 0 is ``exp(-sigma T)`` exactly (``sigma_upper min(T, 0) = 0``)."""
    optics = untextured(get_preset(name).optics)
    assert optics.subsurface_colour == optics.sss_colour
    assert optics.subsurface_attenuation() == (optics.sigma, optics.sigma, 0.0)


def test_layer_subsurface_keys_are_editable_from_a_scene_and_lookdev(tmp_path, scene_dict, write_scene):
    import json

    from tissuerender.cli import main
    from tissuerender.render_inputs import optics_for
    from tissuerender.scene import load_scene

    scene_dict["objects"][0]["optics"] = {"submucosa_sss_colour": [0.3, 0.6, 0.1], "submucosa_sigma": [900.0] * 3}
    spec = load_scene(write_scene(scene_dict)).objects[0]  # the minimal scene's liver block
    optics = optics_for(spec)
    liver = get_preset("liver").optics
    assert optics.subsurface_attenuation() == (liver.sigma, (900.0,) * 3, liver.layers.connective_thickness)
    assert optics.subsurface_colour[1] > liver.subsurface_colour[1]  # the deep layer's green shows through e
    out = tmp_path / "sheet.png"
    assert main(["lookdev", "colon_mucosa", "--sweep", "connective_sss_colour=[[0.9, 0.2, 0.2], [0.2, 0.9, 0.2]]",
                 "--resolution", "16x12", "--samples", "1", "-q", "-o", str(out)]) == 0
    cells = json.loads(out.with_suffix(".json").read_text())["cells"]
    assert [c["overrides"]["connective_sss_colour"] for c in cells] == [[0.9, 0.2, 0.2], [0.2, 0.9, 0.2]]
