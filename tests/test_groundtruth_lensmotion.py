"""Flow, occlusion and tracks through the laparoscope's lens (issue 18; docs/ground-truth.md, "Flow, scene flow
and tracks" and "Lens"): every 2D motion value in the distorted image's pixels.

The scenes are ``test_groundtruth_motion``'s ``STRETCH`` (the textured slab whose colour travels with the
tissue) and ``PROBE`` (a sphere sweeping over static tissue), each seen through a Kannala-Brandt lens with
``k1 = -1`` for ``STRETCH`` (-0.3 for ``PROBE``'s wider field; about 7 % barrel compression at the image's edge, some pixels of displacement: enough that a
pinhole projection misses by far more than the tolerances below). Also: query points given in the scene
(``[output] track_queries``) and the scope mask as a segmentation class.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import tomli_w
from PIL import Image

from postfx.laparoscope_mask import LaparoscopeMask, laparoscope_mask

from tests.test_groundtruth_motion import PROBE, STRETCH, TISSUE, TOOL, _pass, _render, _warp_violations
from tissuerender import load_scene, make_plan
from tissuerender.errors import SceneError
from tissuerender.groundtruth.lens import FisheyeLens, fisheye_lens
from tissuerender.renderer.camera import Camera

LENS_K = [-1.0, 0.0, 0.0, 0.0]


def _with_lens(data, fov_deg, coefficients=LENS_K):
    scene = copy.deepcopy(data)
    scene["camera"]["fov_deg"] = fov_deg
    scene["camera"]["lens"] = {"coefficients": coefficients}
    return scene


@pytest.fixture(scope="module")
def stretch_lens(tmp_path_factory):
    return _render(tmp_path_factory, _with_lens(STRETCH, 24.0), "stretch_lens")


@pytest.fixture(scope="module")
def probe_lens(tmp_path_factory):
    return _render(tmp_path_factory, _with_lens(PROBE, 45.0, [-0.3, 0.0, 0.0, 0.0]), "probe_lens")


def _lens(out) -> FisheyeLens:
    doc = json.loads((out / "cameras.json").read_text())
    assert doc["distortion"] == {"model": "kannala_brandt", "coefficients": LENS_K}
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0), fov_deg=24.0, near=0.001, far=1.0,
                    width=doc["width"], height=doc["height"])
    lens = fisheye_lens(camera, LENS_K)
    np.testing.assert_allclose(lens.K, np.array(doc["K"]), rtol=1e-15)
    return lens


def test_a_track_through_the_lens_is_the_lens_projection_of_its_3d_point(stretch_lens):
    doc = json.loads((stretch_lens / "cameras.json").read_text())
    lens = _lens(stretch_lens)
    with np.load(stretch_lens / "tracks.npz") as tracks:
        t = {name: tracks[name] for name in tracks}
    assert len(t["query_points"]) == 40 and not t["occluded"][:, 0].any()
    pinhole_misses = []
    for k in range(3):
        T = np.array(doc["frames"][k]["world_to_camera"])
        cam = t["points_3d"][:, k].astype(float) @ T[:3, :3].T + T[:3, 3]
        # float32 storage of points_2d (2^-24 x 64 px) and of points_3d: far below 0.01 px
        np.testing.assert_allclose(t["points_2d"][:, k], lens.project(cam), atol=0.01)
        K = np.array(doc["K"])
        pinhole_misses.append(np.abs((cam @ K.T)[:, :2] / cam[:, 2:] - t["points_2d"][:, k]).max())
    assert max(pinhole_misses) > 0.5  # the lens matters: a pinhole through K would miss
    # frame 1: the query pixel's point lies within the nearest remap's reach of the pixel centre (half a pinhole
    # pixel, magnified by at most 1 / (1 - 3 |k1| theta^2) < 1.2 through the distortion at theta < 15 deg)
    query_xy = t["query_points"][:, [2, 1]]
    assert np.abs(t["points_2d"][:, 0] - query_xy).max() <= 0.5 * np.sqrt(2) * 1.2
    with np.load(stretch_lens / "tracks_tapvid3d.npz") as tv:
        np.testing.assert_array_equal(tv["fisheye_k1_k4"], LENS_K)
        np.testing.assert_allclose(tv["fx_fy_cx_cy"], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
        assert "fisheye" in str(tv["lens_note"])


def test_warping_through_the_lens_by_the_forward_flow_reproduces_frame_t(stretch_lens):
    for k in (1, 2):
        flow = _pass(stretch_lens, "flow_forward", k)
        assert np.nanmax(np.abs(flow)) > 1.0
        bad, checked = _warp_violations(stretch_lens, k, flow)
        assert checked > 0.85 * 64 * 48 and bad == 0, (bad, checked)
        assert _warp_violations(stretch_lens, k, np.zeros_like(flow))[0] > 0.3 * checked


def test_occlusion_through_the_lens_flags_exactly_the_tissue_the_probe_covers(probe_lens):
    for k in (1, 2):
        seg, nxt = _pass(probe_lens, "segmentation", k), _pass(probe_lens, "segmentation", k + 1)
        tissue = seg == TISSUE
        covered = tissue & (nxt == TOOL)
        assert covered.sum() > 20
        np.testing.assert_array_equal(_pass(probe_lens, "occluded_forward", k)[tissue], covered[tissue])


def test_a_query_given_in_the_scene_starts_at_its_pixel_and_follows_the_flow(tmp_path_factory):
    scene = copy.deepcopy(STRETCH)
    del scene["output"]["track_points"]
    scene["output"]["track_queries"] = [[0, 10, 20], [1, 30, 40], [2, 5, 60]]
    out = _render(tmp_path_factory, scene, "queries")
    with np.load(out / "tracks.npz") as tracks:
        query, points_2d = tracks["query_points"], tracks["points_2d"]
    np.testing.assert_array_equal(query, np.float32(scene["output"]["track_queries"]))
    for i, (t, y, x) in enumerate(scene["output"]["track_queries"]):
        # a pinhole: the query pixel's point projects onto its centre (float64 rounding of the projection)
        np.testing.assert_allclose(points_2d[i, t], [x, y], atol=1e-4)
    # from the query's frame on, the track moves with the forward flow at its pixel (float32 flows and points)
    np.testing.assert_allclose(points_2d[1, 2] - points_2d[1, 1], _pass(out, "flow_forward", 2)[30, 40], atol=1e-4)
    np.testing.assert_allclose(points_2d[0, 1] - points_2d[0, 0], _pass(out, "flow_forward", 1)[10, 20], atol=1e-4)
    assert np.abs(points_2d[0, 1] - points_2d[0, 0]).max() > 0.1  # it moves


@pytest.mark.parametrize("output, key", [({"passes": ["depth"], "track_queries": [[0, 1, 1]]}, "output.track_queries"),
                                         ({"track_queries": [[3, 1, 1]]}, r"output.track_queries\[0\]"),
                                         ({"track_queries": [[0, 48, 1]]}, r"output.track_queries\[0\]")])
def test_track_queries_without_tracks_or_outside_the_sequence_are_refused(tmp_path, output, key):
    scene = copy.deepcopy(STRETCH)
    del scene["output"]["track_points"]
    scene["output"].update(output)
    path = tmp_path / "scene.toml"
    path.write_text(tomli_w.dumps(scene))
    with pytest.raises(SceneError, match=key):
        make_plan(load_scene(path))


def test_the_pixels_the_laparoscope_mask_blacks_out_are_the_scope_mask_class(tmp_path_factory):
    scene = copy.deepcopy(PROBE)
    mask = {"radius": 1.0, "softness": 0.1, "vignette": 0.3, "offset": [0.05, 0.0]}
    scene["effects"]["laparoscope_mask"] = mask
    scene["output"].update({"frames": 1, "formats": ["png"], "passes": ["depth", "normal", "segmentation"]})
    del scene["output"]["track_points"]
    out = _render(tmp_path_factory, scene, "scope")
    instances = json.loads((out / "labels.json").read_text())["instances"]
    assert instances[-1] == {"id": 3, "name": "scope_mask", "kind": "scope_mask", "class": "scope_mask"}
    seg = _pass(out, "segmentation", 1)
    # exactly the pixels the effect itself zeroes, run on a white image
    zeroed = (laparoscope_mask(np.ones((48, 64, 3), np.float32), LaparoscopeMask(**mask)) == 0.0).all(axis=2)
    assert 0.2 * 48 * 64 < zeroed.sum() < 0.6 * 48 * 64
    np.testing.assert_array_equal(seg == 3, zeroed)
    with Image.open(out / "frame_0001.png") as im:
        assert (np.asarray(im)[zeroed] == 0).all()
    # behind the mask the raster saw tissue or the probe (depth kept): the class replaces what was seen
    assert np.isfinite(_pass(out, "depth", 1)[zeroed]).sum() > 50
    assert {1, 2} <= set(np.unique(seg[~zeroed]).tolist())
