"""The motion passes of a sequence, from the render geometry each frame leaves in ``passes/``
(``output.write_geometry``): written once the frames exist (``finish_sequence``), or asked for between any two
frames afterwards (``flow_between_frames``). Frames may be rendered in any order or independently: only the
geometry files are read."""
from __future__ import annotations

from pathlib import Path

from tissuerender.groundtruth.cameras import labels
from tissuerender.groundtruth.motion import flow_between, neighbour_flows, visible_surface
from tissuerender.groundtruth.output import geometry_path, pass_path, read_geometry, write_array
from tissuerender.groundtruth.tracks import compute_tracks, write_tracks
from tissuerender.errors import UserError
from tissuerender.stages import StageRecorder, recorder_or_new

MOTION_PASSES = ("flow", "scene_flow", "tracks")  # computed from the geometry of several frames
FLOW_FILES = {"flow": ("flow_forward", "flow_backward", "occluded_forward", "occluded_backward"),
              "scene_flow": ("scene_flow_forward", "scene_flow_backward")}


def frame_pass_files(out: Path, index: int, passes) -> list[Path]:
    """The files frame ``index`` writes for the ``passes`` named (a frame counts as finished only when they
    exist): ``passes/<pass>_NNNN.npy`` per single-frame pass, the frame's geometry for the motion passes."""
    files = [pass_path(out, name, index) for name in passes if name not in MOTION_PASSES]
    if any(name in MOTION_PASSES for name in passes):
        files.append(geometry_path(out, index))
    return files


def flow_between_frames(out_dir, t: int, t2: int):
    """(flow (H, W, 2) float32 pixels, occluded (H, W) bool, scene_flow (H, W, 3) float32 metres) of frame
    ``t``'s pixels to frame ``t2`` (frame numbers from 1, any two), from the geometry files in ``out_dir``."""
    return flow_between(read_geometry(out_dir, t), read_geometry(out_dir, t2))


def finish_sequence(out: Path, scene, finished, frames: int | None = None,
                    recorder: StageRecorder | None = None) -> list[Path]:
    """Write the motion passes ``scene.output.passes`` asks for, for the ``finished`` frames (their geometry
    exists) of a render of ``frames`` frames (default the scene's): per frame ``k`` the forward and backward
    flow, occlusion and scene flow when both neighbours are finished (a neighbour outside ``1..frames`` gives
    NaN), and ``tracks.npz`` with its TAP-Vid layouts when every frame is finished. Returns the paths written.
    Timed under ``passes.flow`` / ``passes.scene_flow`` and ``passes.tracks``."""
    rec = recorder_or_new(recorder)
    wanted = [p for p in scene.output.passes if p in MOTION_PASSES]
    frames = scene.output.frames if frames is None else int(frames)
    finished = set(finished)
    written = []
    flow_names = [name for p in ("flow", "scene_flow") if p in wanted for name in FLOW_FILES[p]]
    if flow_names:
        stage = "passes.flow" if "flow" in wanted else "passes.scene_flow"
        cache: dict = {}

        def geometry(k):
            if k not in cache:
                cache[k] = read_geometry(out, k)
            return cache[k]

        visible: dict = {}
        for k in sorted(finished):
            neighbours = [j for j in (k - 1, k + 1) if 1 <= j <= frames]
            if any(j not in finished for j in neighbours):
                continue
            with rec.run(stage):
                previous = geometry(k - 1) if k - 1 >= 1 else None
                following = geometry(k + 1) if k + 1 <= frames else None
                for j, g in ((k - 1, previous), (k + 1, following)):
                    if g is not None and j not in visible:
                        visible[j] = visible_surface(g)
                arrays = neighbour_flows(geometry(k), previous, following, visible.get(k - 1), visible.get(k + 1))
            for name in flow_names:
                written.append(write_array(pass_path(out, name, k), arrays[name]))
            for j in [j for j in cache if j < k]:  # frames are visited in order: earlier ones are done with
                cache.pop(j)
                visible.pop(j, None)
    if "tracks" in wanted and all(k in finished for k in range(1, frames + 1)):
        with rec.run("passes.tracks"):
            geometries = [read_geometry(out, k) for k in range(1, frames + 1)]
            bodies = [entry["id"] - 1 for entry in labels(scene) if entry["kind"] == "body"]
            try:
                tracks = compute_tracks(geometries, bodies, scene.output.track_points, scene.seed,
                                        scene.output.track_queries)
            except ValueError as e:
                raise UserError(f"{scene.path}: output.{e}") from None
            written += write_tracks(out, tracks, geometries, scene.name)
    return written
