"""Field colour maps beyond displacement (issue 19): the von Mises stress of the body's constitutive model on its
render surface, and the signed displacement components, with their units in the manifest's colour bar."""
from __future__ import annotations

import numpy as np
import pytest

import tissuerender
from tissuerender.bodies import build_body
from tissuerender.field_colours import frame_range, legends, vertex_albedo, vertex_field
from tissuerender.scene.field_schema import FieldColours


def _block(scene_dict, write_scene, material, field="von_mises"):
    """The minimal scene's 10 x 10 x 4 cm block (its render surface subdivided once: vertices inside the boundary
    triangles, embedded with fractional barycentrics), with a field colour map."""
    scene_dict["objects"][0].update(material=material, render_subdivision=1, field_colours={"field": field})
    scene = tissuerender.load_scene(write_scene(scene_dict))
    return scene, build_body(scene.objects[0], 0, scene)


def _stretched(body, stretch):
    """Node positions under the homogeneous uniaxial stretch F = diag(stretch, 1, 1)."""
    return body.model.X * [stretch, 1.0, 1.0]


@pytest.mark.parametrize("material,closed_form", [
    # neo_hookean (Zhang 5.35): sigma = mu J^(-5/3) dev(B) + kappa (J - 1) I; B = diag(l^2, 1, 1), J = l:
    # von Mises = sqrt(3/2) mu J^(-5/3) |dev B| = mu l^(-5/3) (l^2 - 1)
    ("plastic", lambda mu, l: mu * l ** (-5.0 / 3.0) * (l * l - 1.0)),
    # stable Neo-Hookean (Macklin & Mueller 2021): sigma = (mu / J) B + lam (J - gamma) I: von Mises = mu (l^2 - 1) / l
    ("liver", lambda mu, l: mu * (l * l - 1.0) / l),
])
def test_uniform_stretch_gives_the_models_von_mises_stress_at_every_vertex(scene_dict, write_scene, material,
                                                                           closed_form):
    scene, body = _block(scene_dict, write_scene, material)
    mu = float(body.model.mu[0])
    spec = scene.objects[0].field_colours
    for stretch in (1.2, 1.0 + 1e-4):
        x = _stretched(body, stretch)
        vm = vertex_field(spec, body, x, body.surface_points(x))
        assert vm.shape == (body.surface.points.shape[0],)
        # every tet carries the same stress, so every average and interpolation returns it: the rounding of
        # F = Ds Dm^-1 (entries ~1, relative 1e-16 per operation, ~50 operations to sigma) on a stress of
        # mu (l^2 - 1) / l >= 2e-4 mu, amplified by the volumetric term cancelling in the deviator (kappa / mu
        # = 2 (1 + nu) / (3 (1 - 2 nu)) ~ 33 at nu = 0.49): 50 x 33 x 1.1e-16 / 2e-4 = 1e-9
        np.testing.assert_allclose(vm, closed_form(mu, stretch), rtol=1e-9)
    # the small-strain limit: linear elasticity's von Mises stress of uniaxial strain, |sigma_xx - sigma_yy| =
    # 2 mu eps, within the models' first-order terms (7/6 eps and 1/2 eps relative at strain eps = 1e-4)
    eps = 1e-4
    x = _stretched(body, 1.0 + eps)
    np.testing.assert_allclose(vertex_field(spec, body, x, body.surface_points(x)), 2.0 * mu * eps, rtol=2.0 * eps)


def test_a_rigid_rotation_has_no_stress_and_the_colour_bar_is_in_pascal(scene_dict, write_scene):
    scene, body = _block(scene_dict, write_scene, "liver")
    c, s = np.cos(0.5), np.sin(0.5)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    x = body.model.X @ R.T + [0.3, -0.1, 0.2]
    vm = vertex_field(scene.objects[0].field_colours, body, x, body.surface_points(x))
    # F = R to rounding: the deviator of (mu / J) R R^T is ~1e-16 mu per entry, against the stretch test's mu
    assert vm.max() < 1e-12 * float(body.model.mu[0])
    bar = legends(scene)["field_colours"][scene.objects[0].name]
    assert bar["field"] == "von_mises" and bar["unit"] == "Pa"


def test_signed_displacement_component_maps_negative_to_positive(scene_dict, write_scene):
    scene, body = _block(scene_dict, write_scene, "liver", field="displacement_x")
    x = body.model.X.copy()
    x[:, 0] += 0.5 * (body.model.X[:, 0] - 0.05)  # x moves away from the block's centre plane x = 5 cm
    points = body.surface_points(x)
    values = vertex_field(scene.objects[0].field_colours, body, x, points)
    np.testing.assert_allclose(values, 0.5 * (body.surface.points[:, 0] - 0.05), atol=1e-15)
    assert frame_range(values) == (values.min(), values.max()) and values.min() < 0.0 < values.max()
    albedo = vertex_albedo(scene.objects[0].field_colours, body, x, points)
    # the colormap's ends at the two extremes: viridis runs from dark blue (low) to yellow (high)
    assert albedo[np.argmin(values), 2] > albedo[np.argmin(values), 0]
    assert albedo[np.argmax(values), 0] > albedo[np.argmax(values), 2]
    assert legends(scene)["field_colours"][scene.objects[0].name]["unit"] == "m"
    with pytest.raises(ValueError):
        FieldColours(field="pressure")
