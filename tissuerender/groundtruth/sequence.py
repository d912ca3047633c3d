"""The motion passes of a sequence, from the render geometry each frame leaves in ``passes/``
(``output.write_geometry``): written once the frames exist (``finish_sequence``), or asked for between any two
frames afterwards (``flow_between_frames``). Frames may be rendered in any order or independently: only the
geometry files are read."""
from __future__ import annotations

from pathlib import Path

from tissuerender.groundtruth.cameras import labels
from tissuerender.groundtruth.motion import flow_between, frame_raster, neighbour_flows
from tissuerender.groundtruth.output import geometry_path, pass_path, read_geometry, write_array
from tissuerender.groundtruth.tracks import Tracks, write_tracks
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

    One pass over the frames in order: each frame is re-rasterised once (``motion.frame_raster``, carrying its
    neighbours' vertex positions when its flows are asked) and that raster serves its flows, its neighbours'
    flows towards it and its column of the tracks; at most three frames' rasters (and the tracks' query
    frames') are held at a time. Timed under ``passes.flow`` / ``passes.scene_flow`` (the rasters, the flows
    and their files) and ``passes.tracks`` (the tracks and their files; the rasters too when no flow is asked)."""
    rec = recorder_or_new(recorder)
    wanted = [p for p in scene.output.passes if p in MOTION_PASSES]
    frames = scene.output.frames if frames is None else int(frames)
    finished = set(finished)
    flow_names = [name for p in ("flow", "scene_flow") if p in wanted for name in FLOW_FILES[p]]
    flow_frames = set()
    if flow_names:
        flow_frames = {k for k in finished if all(j in finished for j in (k - 1, k + 1) if 1 <= j <= frames)}
    tracking = "tracks" in wanted and all(k in finished for k in range(1, frames + 1))
    needed = flow_frames | {j for k in flow_frames for j in (k - 1, k + 1) if 1 <= j <= frames}
    if tracking:
        needed |= set(range(1, frames + 1))
    stage = ("passes.flow" if "flow" in wanted else "passes.scene_flow") if flow_frames else "passes.tracks"
    geometries: dict = {}
    rasters: dict = {}

    def geometry(k):
        if k not in geometries:
            geometries[k] = read_geometry(out, k)
        return geometries[k]

    def raster(k):  # frame k's raster, carrying the neighbours that exist when its flows are asked
        if k not in rasters:
            with rec.run(stage):
                targets = [geometry(j).points for j in (k - 1, k + 1) if 1 <= j <= frames] if k in flow_frames else []
                rasters[k] = frame_raster(geometry(k), targets)
        return rasters[k]

    tracks = None
    if tracking:
        bodies = [entry["id"] - 1 for entry in labels(scene) if entry["kind"] == "body"]
        try:
            tracks = Tracks(frames, lambda t: raster(t + 1), bodies, scene.output.track_points, scene.seed,
                            scene.output.track_queries)
        except ValueError as e:
            raise UserError(f"{scene.path}: output.{e}") from None
    queried = set(rasters)  # the query frames' rasters stay for every column of the tracks
    written = []
    for k in sorted(needed):
        current = raster(k)
        if tracks is not None:
            with rec.run("passes.tracks"):
                tracks.add_frame(k - 1, current)
        for j in (k - 1, k):  # a frame's flows once its following frame's raster exists
            if j in flow_frames and (j + 1 > frames or j + 1 in rasters):
                with rec.run(stage):
                    arrays = neighbour_flows(rasters[j], rasters[j - 1] if j > 1 else None,
                                             rasters[j + 1] if j < frames else None)
                    for name in flow_names:
                        written.append(write_array(pass_path(out, name, j), arrays[name]))
                flow_frames.discard(j)
        for j in [j for j in rasters if j < k - 1 and j not in queried]:  # no flow needs them any more
            rasters.pop(j)
            if tracks is None:  # write_tracks reads every frame's camera
                geometries.pop(j, None)
    if tracks is not None:
        with rec.run("passes.tracks"):
            written += write_tracks(out, tracks.arrays(), [geometry(k) for k in range(1, frames + 1)], scene.name)
    return written
