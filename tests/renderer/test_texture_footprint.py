"""The texture lookup's footprint is measured in UV units (issue 19): a mesh whose UVs are not metres (a user's
surface with UVs in [0, 1]) is mip-mapped at the level its own UV scale asks for."""
from __future__ import annotations

import numpy as np

from materials import get_preset
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings, render_frame
from tissuerender.renderer import gbuffer
from tissuerender.renderer.gbuffer import uv_per_metre


def _plane(side, uv_per_m, z=0.0):
    """A square of ``side`` [m] in the plane z, its UVs ``uv_per_m`` times its metres (4 x 4 quads: 32 triangles)."""
    g = np.linspace(-0.5 * side, 0.5 * side, 5)
    x, y = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    points = np.column_stack([x, y, np.full(x.size, z)])
    i, j = (a.ravel() for a in np.meshgrid(np.arange(4), np.arange(4), indexing="ij"))
    a, b, c, d = i * 5 + j, (i + 1) * 5 + j, (i + 1) * 5 + j + 1, i * 5 + j + 1
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return RenderObject(points=points, triangles=triangles, normals=np.tile([0.0, 0.0, 1.0], (x.size, 1)),
                        uv=(points[:, :2] - points[0, :2]) * uv_per_m, material="colon_mucosa")


def _render(obj, distance, width=32):
    cam = Camera((0.0, 0.0, distance), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 0.01, 10.0, width, width)
    return render_frame([obj], cam, AreaLight(samples=1), RenderSettings())


def test_uv_per_metre_is_the_linear_scale_of_the_uv_map():
    for scale in (1.0, 10.0, 37.5):
        obj = _plane(0.2, scale)
        # sqrt of an area ratio of axis-aligned right triangles: a few ulps of the scale
        np.testing.assert_allclose(uv_per_metre(obj.points, obj.triangles, obj.uv), scale, rtol=1e-13)
    flat = np.zeros((3, 2))  # a degenerate UV map: no scale to take, metres assumed
    assert uv_per_metre(np.eye(3), np.array([[0, 1, 2]]), flat)[0] == 1.0


def test_uvs_scaled_by_ten_pick_the_mip_level_log2_10_coarser(monkeypatch):
    seen = []
    real = gbuffer.sample_mipmapped

    def spy(chain, uv, texels):  # records the footprint the renderer asks for, returns the real lookup
        seen.append(np.asarray(texels, float).copy())
        return real(chain, uv, texels)

    monkeypatch.setattr(gbuffer, "sample_mipmapped", spy)
    _render(_plane(0.2, 1.0), 0.3)
    metres = seen[0]
    seen.clear()
    _render(_plane(0.2, 10.0), 0.3)
    tenfold = seen[0]
    assert metres.size == tenfold.size > 500  # the same samples (the same geometry and camera)
    # lod = log2(texels): ten times the UVs per metre is log2(10) = 3.32 levels up, at every sample (the ratio's
    # rounding: a few ulps in uv_per_metre's square root)
    np.testing.assert_allclose(np.log2(tenfold) - np.log2(metres), np.log2(10.0), rtol=0, atol=1e-12)


def test_far_plane_with_uvs_not_in_metres_reads_the_textures_mean():
    """A plane 0.4 m wide with UVs of 100 per metre (a [0, 40] map), 0.3 m away, filling a 32-pixel 30-degree view:
    one pixel covers 0.3 x 2 tan(15 deg) / 32 = 5 mm = 0.5 UV units = 17 tiles of the colon texture (period 0.03,
    256 texels): 4,300 texels, past the chain's last level (8, the 1 x 1 mean), so every lookup is the texture's
    mean. The old footprint, taken as metres, was 43 texels (level 5.4): the texture's pattern, 100 x too fine."""
    layers = get_preset("colon_mucosa").optics.layers
    mean = layers.baked_albedo().reshape(-1, 3).mean(axis=0)
    res = _render(_plane(0.4, 100.0), 0.3)
    albedo = res.gbuffer["albedo"]
    assert albedo.shape[0] > 900  # the plane fills the view
    # the 1 x 1 level is the mean of 4^8 texels by 8 exact-in-binary 0.25 box steps: ~1e-16 from the float mean
    np.testing.assert_allclose(albedo, np.broadcast_to(mean, albedo.shape), rtol=0, atol=1e-12)
    # the same plane with its UVs in metres shows the texture (its footprint is 100 x smaller: level 5.4, the bake's
    # pattern on 8 x 8 cells of 32 texels; measured standard deviation 0.006 in red), 1e9 x the deviation above
    assert _render(_plane(0.4, 1.0), 0.3).gbuffer["albedo"].std(axis=0).max() > 1e-3
