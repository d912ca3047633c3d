"""Degenerate but valid geometry renders finite values: zero-area triangles (collinear corners, a repeated
corner), a vertex whose normal is the zero vector, a plane seen exactly edge-on, a light at grazing
incidence. ``render_frame`` checks its stages (``tissuerender.finite``): a NaN anywhere would raise."""
from __future__ import annotations

import numpy as np
import pytest

from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame

FULL = RenderSettings(shadows=True, sss=True, ao=True, ambient=(0.2, 0.2, 0.2), supersampling=2)


def _plane_with_degenerate_triangles(material: str) -> RenderObject:
    """A 0.2 m square at z = 0 (two triangles) plus zero-area triangles: collinear corners along its
    diagonal, a repeated corner, and one whose three corners coincide at a vertex used by no other
    triangle (its area-weighted normal is the zero vector)."""
    p = np.array([[-0.1, -0.1, 0.0], [0.1, -0.1, 0.0], [0.1, 0.1, 0.0], [-0.1, 0.1, 0.0],
                  [0.0, 0.0, 0.0], [0.03, 0.02, 0.0]])
    t = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 2], [1, 1, 3], [5, 5, 5]])
    return RenderObject(points=p, triangles=t, normals=None, uv=None, material=material)


@pytest.mark.parametrize("material", ["liver", "colon_mucosa", "plastic"])
def test_zero_area_triangles_render_the_plane_finite_and_lit(material):
    camera = Camera((0.0, -0.15, 0.25), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 60.0, 0.01, 5.0, 48, 36)
    light = AreaLight(size=(0.02, 0.02), radiance=(3000.0,) * 3, attach="camera", samples=4)
    result = render_frame([_plane_with_degenerate_triangles(material)], camera, light, FULL)
    covered = np.isfinite(result.depth)
    assert np.isfinite(result.hdr).all() and result.hdr.min() >= 0.0
    assert covered.mean() > 0.3 and result.hdr[covered].sum(axis=-1).min() > 0.0  # every covered pixel lit


def test_a_plane_seen_edge_on_and_lit_at_grazing_incidence_stays_finite():
    """The camera lies in the plane z = 0 and the light's centre too, its normal along the plane: every
    cosine is 0 (or a rounding away from it) and the plane projects onto one image row."""
    quad = RenderObject(points=np.array([[-0.1, 0.05, 0.0], [0.1, 0.05, 0.0], [0.1, 0.25, 0.0], [-0.1, 0.25, 0.0]]),
                        triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=None, material="liver")
    box = RenderObject(points=np.array([[-0.05, 0.1, -0.05], [0.05, 0.1, -0.05], [0.05, 0.2, -0.05],
                                        [-0.05, 0.2, -0.05]]),
                       triangles=np.array([[0, 1, 2], [0, 2, 3]]), normals=None, uv=None, material="colon_mucosa")
    camera = Camera((0.0, -0.2, 0.0), (0.0, 0.2, 0.0), (0.0, 0.0, 1.0), 60.0, 0.01, 5.0, 40, 30)
    grazing = AreaLight(size=(0.02, 0.02), radiance=(3000.0,) * 3, attach="world", position=(0.0, 0.0, 0.0),
                        normal=(0.0, 1.0, 0.0), up=(0.0, 0.0, 1.0), samples=4)
    for settings in (FULL, RenderSettings(sss=True, sss_thickness="pixel", shadows=True)):
        result = render_frame([quad, box], camera, grazing, settings)
        assert np.isfinite(result.hdr).all() and result.hdr.min() >= 0.0
        assert np.isfinite(result.depth).any()  # the box below the plane is in view
