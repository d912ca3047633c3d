"""Mesh tools that turn, in a scene (tissuerender.contacts.mesh_tool_probe, render_inputs.tool_surface;
docs/interaction.md "Mesh tools"): keyframe orientations are accepted, the tool is drawn turned, and a tool that
turns while grasping is refused by name."""
from __future__ import annotations

import numpy as np
import pytest

from tests.sim.test_mesh_tool_turning import _about_z, _cube

CENTRE = [0.05, 0.05, 0.1]  # above the minimal scene's block (top at z = 0.04)


def _write_cube(tmp_path, half: float) -> str:
    points, faces = _cube(half)
    lines = [f"v {float(p[0])!r} {float(p[1])!r} {float(p[2])!r}" for p in points] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    (tmp_path / "cube.obj").write_text("\n".join(lines) + "\n")
    return "cube.obj"


def _tool_mask(scene_dict, write_scene, tmp_path, orientation):
    """The pixels of a 4 cm cube tool seen straight down from 15 cm above its top (segmentation pass)."""
    from tissuerender import load_scene
    from tissuerender.pipeline import render_hdr
    from tissuerender.plan import make_plan
    from tissuerender.stages import StageRecorder
    from tissuerender.world import build_world

    keyframe = {"t": 0.0, "position": CENTRE}
    if orientation is not None:
        keyframe["orientation"] = list(orientation)
    scene_dict["tools"] = [{"name": "cube", "kind": "mesh", "mesh": _write_cube(tmp_path, 0.02), "keyframes": [keyframe]}]
    scene_dict["camera"] = {"position": [0.05, 0.05, 0.27], "look_at": [0.05, 0.05, 0.0], "up": [0.0, 1.0, 0.0],
                            "fov_deg": 60.0}
    scene_dict["output"]["resolution"] = [64, 64]
    scene = load_scene(write_scene(scene_dict))
    plan = make_plan(scene)
    recorder = StageRecorder()
    world = build_world(scene, plan, recorder)
    result, _ = render_hdr(world, scene, plan, recorder, 0.0, seed=3, passes=("segmentation",))
    ids = result.passes["segmentation"]  # 0 background, 1 the block, 2 the tool
    return ids == 2, ids.shape


def test_a_mesh_tool_turned_45_degrees_is_drawn_as_a_diamond(scene_dict, write_scene, tmp_path):
    square, shape = _tool_mask(scene_dict, write_scene, tmp_path, None)
    diamond, _ = _tool_mask(scene_dict, write_scene, tmp_path, _about_z(45.0))
    # the same cube seen from straight above, its top face (4 cm) 15 cm from the camera: side = 0.04 / (2 0.15 tan 30)
    # x 64 = 14.8 pixels. Both silhouettes cover its area side^2, to the pixels their outline crosses (a pixel
    # counts when its centre is inside: at most half the perimeter's 59 pixels off); their extents along the image
    # axes are side and sqrt(2) side (to two pixels: one at each end), and the square's corners are empty
    side = 0.04 / (2.0 * 0.15 * np.tan(np.radians(30.0))) * shape[1]
    for mask in (square, diamond):
        assert abs(mask.sum() - side * side) <= 2.0 * side
    rows, cols = np.nonzero(square)
    d_rows, d_cols = np.nonzero(diamond)
    for extent, factor in ((np.ptp(cols), 1.0), (np.ptp(rows), 1.0), (np.ptp(d_cols), np.sqrt(2.0)),
                           (np.ptp(d_rows), np.sqrt(2.0))):
        assert abs(extent + 1 - factor * side) <= 2.0
    for r in (rows.min() + 1, rows.max() - 1):
        for c in (cols.min() + 1, cols.max() - 1):
            assert square[r, c] and not diamond[r, c]


def test_a_mesh_tool_that_turns_while_grasping_is_refused(scene_dict, write_scene, tmp_path):
    from tissuerender import load_scene
    from tissuerender.errors import SceneError

    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1 / 48}
    keyframes = [{"t": 0.0, "position": CENTRE, "orientation": [1.0, 0.0, 0.0, 0.0]},
                 {"t": 0.5, "position": CENTRE, "orientation": list(_about_z(30.0))}]
    scene_dict["tools"] = [{"name": "cube", "kind": "mesh", "mesh": _write_cube(tmp_path, 0.02), "keyframes": keyframes,
                            "grasp": [{"t_close": 0.1, "t_release": 0.4, "radius": 0.03}]}]
    with pytest.raises(SceneError) as error:
        load_scene(write_scene(scene_dict))
    assert "tools[0]" in str(error.value) and "cannot grasp" in str(error.value)
    # turned but not turning (one orientation at every keyframe): grasped nodes follow it exactly, accepted
    keyframes[1]["orientation"] = [-1.0, 0.0, 0.0, 0.0]  # the same rotation as the first
    assert load_scene(write_scene(scene_dict)).tools[0].grasp
