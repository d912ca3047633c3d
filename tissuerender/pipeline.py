"""One render, frame by frame: simulate -> embed -> raster -> shade -> post-effects -> write.

Each stage runs only when the plan lists it (``tissuerender.plan``) and is timed by the
:class:`~tissuerender.stages.StageRecorder`; ``out/manifest.json`` records both. Frames are written
atomically (``tissuerender.files``), so an interrupted render never leaves a half-written frame, and
``resume=True`` skips the frames the manifest records as finished (the simulation still advances through
them, so the remaining frames are identical to an uninterrupted run).
"""
from __future__ import annotations

import hashlib
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

import postfx
from sim.output import write_vtu
from tissuerender import groundtruth
from tissuerender.checks import check_scene
from tissuerender.errors import UserError
from tissuerender.finite import NonFiniteError, frame_at
from tissuerender.groundtruth import formats as gt_formats
from tissuerender.files import (one_writer, output_folder, remove_temporaries, write_atomic, write_json, write_npy,
                               write_png)
from tissuerender.manifest import manifest, read_resumable
from tissuerender.plan import Plan, make_plan
from tissuerender.renderer import render_frame
from tissuerender.render_inputs import camera_for, lens_for, light_for, render_objects, settings_for
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder, recorder_or_new
from tissuerender.world import ToolForceLog, World, advance


def frame_name(index: int, ext: str = "png") -> str:
    return f"frame_{index:04d}.{ext}"


def render_hdr(world: World, scene: Scene, plan: Plan, recorder: StageRecorder, t: float, seed: int,
               width: int | None = None, height: int | None = None, previous=None, passes=None):
    """Raster and shade one frame: (FrameResult, surface positions by body name); ``result.passes`` holds the
    ground-truth ``passes`` (default: the scene's ``output.passes``)."""
    objects, positions = render_objects(world, scene, t, plan, recorder, previous)
    camera = camera_for(scene, width, height, t)
    lens = lens_for(scene, camera)  # None: a pinhole; else the frame is rendered by a wider pinhole and remapped
    view = camera if lens is None else lens.pinhole
    try:
        result = render_frame(objects, view, light_for(scene), settings_for(scene, seed), recorder=recorder)
    except NotImplementedError as e:
        raise UserError(f"{scene.path}: [effects] asks for something this renderer cannot do: {e}") from None
    except NonFiniteError as e:
        raise e.located(scene.path, frame_at(t, scene.output.fps), [o.name for o in objects]) from None
    wanted = scene.output.passes if passes is None else passes
    if wanted:
        result.passes = groundtruth.ground_truth(objects, groundtruth.rest_positions(world, objects), view, wanted,
                                                 recorder)
        if any(name in groundtruth.MOTION_PASSES for name in wanted):
            result.geometry = groundtruth.frame_geometry(objects, camera, None if lens is None else lens.k)  # write_geometry
    if lens is not None:
        with recorder.run("lens"):  # colour bilinear (then vignetting, before the post-effects), passes nearest
            lens.apply(result)
    if wanted:  # the pixels the laparoscope mask blacks out, in the output's pixels
        groundtruth.mark_scope_mask(result.passes, scene, groundtruth.scope_mask_id(scene))
    return result, positions


def postprocess(scene: Scene, hdr: np.ndarray, depth: np.ndarray, recorder: StageRecorder, seed: int,
                width: int | None = None, height: int | None = None, frame: int | None = None):
    """Post-effects of the scene's chain; returns display-referred float32 RGB in [0, 1] (a user error
    naming the ``frame`` and the effect where one gives a non-finite value)."""
    chain = scene.effect_chain()
    c = scene.camera
    lens = postfx.Lens(fov_deg=c.fov_deg, width=width or scene.width, height=height or scene.height)
    try:
        out = postfx.apply_chain(hdr, depth, chain, lens, backend=scene.effects.backend, seed=seed)
    except postfx.OSMesaUnavailable as e:
        raise UserError(f"{scene.path}: effects.backend = \"osmesa\": {e}") from None
    except postfx.NonFiniteOutput as e:
        stage = f"postfx.{e.effect}" if e.effect else "postfx"
        raise NonFiniteError(stage, "display values", e.count, e.first, e.value, frame=frame, scene_path=scene.path,
                             pixels=True) from None
    for name, seconds in out.seconds.items():
        recorder.calls[f"postfx.{name}"] = recorder.calls.get(f"postfx.{name}", 0) + 1
        recorder.seconds[f"postfx.{name}"] = recorder.seconds.get(f"postfx.{name}", 0.0) + seconds
    return out.image, out.backend_used


def frame_seed(scene: Scene, frame: int, seed: int | None = None) -> int:
    """Per-frame seed derived from the scene seed, so frames differ but runs repeat exactly."""
    base = scene.seed if seed is None else seed
    digest = hashlib.sha256(f"{base}:{frame}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


@dataclass
class RunResult:
    out_dir: Path
    written: list[Path]
    skipped: list[Path]
    plan: Plan
    recorder: StageRecorder
    manifest: dict
    stale: list[Path] = field(default_factory=list)  # output-like files in the folder that are not this render's


# Every name a frame output can have (``frame_name`` and ``_frame_files``), whichever scene wrote it.
OUTPUT_NAME = re.compile(r"^frame_\d{4,}\.(png|npy|exr)$|^.+_\d{4,}\.vtu$")


@dataclass
class Sequence:
    """One render into one folder as far as it has got: what the serial loop and the Dask client
    (``tissuerender.distributed``) share. ``done`` holds the finished frames (kept or written); every change
    to it is followed by ``record`` so the manifest on disk says the same."""

    scene: Scene
    out: Path
    plan: Plan
    formats: list[str]
    recorder: StageRecorder
    world: World
    n_frames: int
    done: set[int]
    start: float
    written: list[Path] = field(default_factory=list)
    skipped: list[Path] = field(default_factory=list)
    backend_used: str | None = None
    extra: dict = field(default_factory=dict)  # manifest keys of the executor (``executor``, ``states``)
    tool_forces: ToolForceLog | None = None  # per-frame tool forces, when the plan has contact

    def record(self, extra: dict) -> dict:
        forces = {} if self.tool_forces is None else {"tool_forces": self.tool_forces.summary()}
        data = manifest(self.scene, self.plan, self.recorder, self.formats, self.n_frames, self.done,
                        time.perf_counter() - self.start,
                        {"postfx_backend": self.backend_used, **forces, **self.extra, **extra})
        write_json(self.out / "manifest.json", data)
        return data

    def frame_finished(self, k: int, written: list[Path], backend_used: str | None) -> None:
        """Frame ``k``'s files are all written: record it (cameras.json first, then the manifest)."""
        self.written += written
        self.backend_used = backend_used if backend_used is not None else self.backend_used
        self.done.add(k)
        if "write_passes" in self.plan:
            _write_cameras(self.out, self.scene, self.done)  # before the manifest records the frame as finished
        self.record({"complete": False})


def start_sequence(scene: Scene, out_dir, resume: bool = False, frames: int | None = None) -> Sequence:
    """Everything before the first frame: the folder, the plan, the frames a resumed render keeps, the checks
    and the world they build, a first manifest naming this scene, and labels.json / cameras.json."""
    start = time.perf_counter()
    out = output_folder(out_dir)
    plan = make_plan(scene)
    formats = output_formats(plan)
    recorded = _resumable(out, scene, formats) if resume else set()
    remove_temporaries(out)
    if (out / groundtruth.PASSES_FOLDER).is_dir():
        remove_temporaries(out / groundtruth.PASSES_FOLDER)
    recorder = StageRecorder()
    world = check_scene(scene, recorder).world  # the checks `validate` runs, and the world they build
    n_frames = scene.output.frames if frames is None else min(frames, scene.output.frames)
    done = {k for k in recorded if all(p.exists() for p in _frame_files(out, k, plan, world))}
    seq = Sequence(scene, out, plan, formats, recorder, world, n_frames, done, start)
    # OUT/tool_forces.csv (tissuerender.world): the forces come from the simulation, run by whoever advances it
    seq.tool_forces = ToolForceLog(scene) if "contact" in plan else None
    seq.record({"complete": False})  # from here on the folder's manifest names this scene
    if "write_passes" in plan:
        groundtruth.write_labels(out, groundtruth.labels(scene))
        _write_cameras(out, scene, done)
    return seq


def render_frame_files(out: Path, k: int, world: World, scene: Scene, plan: Plan, recorder: StageRecorder,
                       previous=None) -> tuple[list[Path], dict, str | None]:
    """Render frame ``k`` from ``world`` at the frame's time and write its planned files: (their paths, the
    bodies' surface positions (frame ``k + 1``'s ``previous``), the post-effects backend used). The serial
    loop and a Dask task (``tissuerender.distributed``) both render through it."""
    t = (k - 1) / scene.output.fps
    seed = frame_seed(scene, k)
    result, positions = render_hdr(world, scene, plan, recorder, t, seed, previous=previous)
    image, backend_used = postprocess(scene, result.hdr, result.depth, recorder, seed, frame=k)
    written = _write_frame(out, k, plan, recorder, world, image, result.hdr)
    if "write_passes" in plan:
        with recorder.run("write_passes"):
            written += groundtruth.write_passes(out, k, result.passes, _body_ids(world),
                                                groundtruth.scope_mask_id(scene))
    if "write_geometry" in plan:
        with recorder.run("write_geometry"):
            written += groundtruth.write_geometry(out, k, result.geometry, t)
    camera = camera_for(scene, t=t)
    lens = lens_for(scene, camera)
    written += gt_formats.write_frame_formats(out, k, output_formats(plan), result.hdr, result.passes,
                                              groundtruth.intrinsics(camera) if lens is None else lens.K,
                                              gt_formats.depth_png_scale(scene.camera.far), recorder, lens)
    return written, positions, backend_used


def finish_sequence(seq: Sequence) -> RunResult:
    """The end of a sequence: the files that need every frame (flows and tracks from the frames' geometry, the
    flow's other formats, the mp4 preview), then the final manifest (``complete``, what this run wrote and
    kept); cameras.json is already current (``Sequence.frame_finished``). Names the frame files in the folder
    that are not this render's."""
    out, plan, recorder, done = seq.out, seq.plan, seq.recorder, seq.done
    try:
        if "write_geometry" in plan:  # flows and tracks need every frame's geometry
            seq.written += groundtruth.finish_sequence(out, seq.scene, done, seq.n_frames, recorder)
        if "write_flow_files" in plan:  # .flo, KITTI and the EXR's flow layers, from the flow masters
            with recorder.run("write_flow_files"):
                seq.written += gt_formats.complete_from_masters(out, sorted(done), seq.formats)
        if "write_mp4" in plan and done:
            with recorder.run("write_mp4"):
                seq.written.append(gt_formats.write_preview(out, [out / frame_name(k) for k in sorted(done)],
                                                            seq.scene.output.fps))
    except BaseException:
        remove_temporaries(out)  # as the frame loop: a signal leaves only complete files
        if (out / groundtruth.PASSES_FOLDER).is_dir():
            remove_temporaries(out / groundtruth.PASSES_FOLDER)
        raise
    final = seq.record({"complete": True, "written": [p.name for p in seq.written],
                        "resumed_skipped": [p.name for p in seq.skipped]})
    ours = {p.name for k in seq.done for p in _frame_files(seq.out, k, seq.plan, seq.world)}
    stale = sorted(p for p in seq.out.iterdir() if OUTPUT_NAME.match(p.name) and p.name not in ours)
    return RunResult(seq.out, seq.written, seq.skipped, seq.plan, seq.recorder, final, stale)


def render(scene: Scene, out_dir, resume: bool = False, progress: bool = True, frames: int | None = None,
           on_frame=None) -> RunResult:
    """Render the scene's image sequence into ``out_dir`` (frames, optional HDR/VTU, manifest.json), the only
    render writing there (``files.one_writer``: another one into the same folder is a :class:`UserError`).

    ``frames`` renders only the first N of the scene's frames. ``resume`` keeps the frames that
    ``manifest.json`` records as finished by a render of the same scene file (same sha256, frame count and
    formats; anything else is a :class:`UserError`) whose files all still exist; the rest are rendered.
    Without ``resume`` the folder starts over: the manifest records no frame until this run writes it.
    See docs/design.md, "Resume and interruption". ``tissuerender.distributed.render_distributed`` renders the
    same frames as Dask tasks. ``on_frame()`` is called after each frame is finished or kept (a batch's progress).
    """
    with one_writer(output_folder(out_dir)):
        return _render(scene, out_dir, resume, progress, frames, on_frame)


def _render(scene: Scene, out_dir, resume: bool, progress: bool, frames: int | None, on_frame) -> RunResult:
    seq = start_sequence(scene, out_dir, resume, frames)
    world, plan, recorder, out = seq.world, seq.plan, seq.recorder, seq.out
    previous = None
    bar = _progress(progress, seq.n_frames, scene.name)
    if on_frame is not None:
        bar.advance = _then(bar.advance, on_frame)
    try:
        for k in range(1, seq.n_frames + 1):
            if k > 1 and "simulate" in plan:
                advance(world, scene, recorder)
            if seq.tool_forces is not None:
                seq.tool_forces.record(k, (k - 1) / scene.output.fps, world)
                seq.tool_forces.write(out)
            if k in seq.done:
                seq.skipped.append(out / frame_name(k))
                if "velocity_channel" in plan:
                    previous = _surface_positions(world, plan)
                bar.advance()
                continue
            written, previous, backend_used = render_frame_files(out, k, world, scene, plan, recorder, previous)
            seq.frame_finished(k, written, backend_used)
            bar.advance()
    except BaseException:
        # a signal (SIGINT, SIGTERM) landing between a temporary's creation and its writer's own clean-up
        # would leave it behind: the folder holds only complete files when the render stops
        remove_temporaries(out)
        raise
    finally:
        bar.close()
    return finish_sequence(seq)


def _then(first, second):
    def both():
        first()
        second()

    return both


def output_formats(plan: Plan) -> list[str]:
    """The ``output.formats`` names this render writes (as the plan decided: vtu only when simulating)."""
    return [name for name, stage in (("png", "write_png"), ("hdr_npy", "write_hdr"), ("vtu", "write_vtu"),
                                     ("exr", "write_exr"), ("depth_png", "write_depth_png"), ("mp4", "write_mp4"))
            if stage in plan]


def _resumable(out: Path, scene: Scene, formats: list[str]) -> set[int]:
    """The frames ``out``'s manifest records as finished, after checking they come from this scene; a
    folder with frame files but no manifest is refused, since nothing says which scene they show."""
    recorded = read_resumable(out / "manifest.json", scene, formats)
    if recorded is not None:
        return recorded
    outputs = sorted(p.name for p in out.iterdir() if OUTPUT_NAME.match(p.name))
    if outputs:
        raise UserError(f"{out}: --resume: the folder holds frame files ({outputs[0]}, {len(outputs)} in all) "
                        "but no manifest.json, so nothing says which scene they show; render without --resume "
                        "to overwrite them, or into another folder")
    return set()


def _frame_files(out: Path, k: int, plan: Plan, world: World) -> list[Path]:
    """Every file frame ``k`` writes (PNG, HDR, one .vtu per body); ``resume`` keeps a frame only when the
    manifest records it finished and all of them exist."""
    return frame_files(out, k, plan, [body.spec.name for body in world.bodies])


def frame_files(out: Path, k: int, plan: Plan, body_names: list[str]) -> list[Path]:
    """``_frame_files`` from the bodies' names alone (a batch checks a finished sequence without building it)."""
    wanted = [out / frame_name(k)] if "write_png" in plan else []
    wanted += [out / frame_name(k, "npy")] if "write_hdr" in plan else []
    wanted += [out / f"{name}_{k:04d}.vtu" for name in body_names] if "write_vtu" in plan else []
    wanted += groundtruth.frame_pass_files(out, k, plan_passes(plan))
    wanted += gt_formats.frame_files(out, k, output_formats(plan))
    return wanted


def plan_passes(plan: Plan) -> list[str]:
    """The ground-truth passes the plan writes."""
    return [name for name in groundtruth.ALL_PASS_NAMES if f"passes.{name}" in plan]


def _body_ids(world: World) -> list[int]:
    """Segmentation ids of the simulated bodies (drawn first: ids 1 ... n)."""
    return list(range(1, len(world.bodies) + 1))


def _write_cameras(out: Path, scene: Scene, done: set[int]) -> None:
    """``cameras.json`` with an entry for every finished frame, each with that frame's pose."""
    camera = camera_for(scene)
    times = {k: (k - 1) / scene.output.fps for k in sorted(done)}
    frames = [groundtruth.camera_entry(camera_for(scene, t=t), k, t) for k, t in times.items()]
    document = groundtruth.cameras_document(camera, frames, lens_for(scene, camera))
    if "depth_png" in scene.output.formats:
        document["depth_png_scale"] = gt_formats.depth_png_scale(scene.camera.far)  # metres per PNG unit
    groundtruth.write_cameras(out, document)


def _surface_positions(world: World, plan: Plan) -> dict[str, np.ndarray]:
    """The bodies' render-surface positions as ``render_objects`` computes them: a skipped frame's
    ``previous``, so the next frame's velocity channel matches an uninterrupted run."""
    return {body.spec.name: body.surface_points(state.x) if "embed" in plan else body.surface.points
            for body, state in zip(world.bodies, world.states)}


def _write_frame(out: Path, k: int, plan: Plan, recorder: StageRecorder, world: World, image: np.ndarray,
                 hdr: np.ndarray) -> list[Path]:
    """Write frame ``k``'s planned outputs (display PNG, linear HDR, one .vtu per body); returns their paths."""
    written = []
    if "write_png" in plan:
        with recorder.run("write_png"):
            write_png(out / frame_name(k), postfx.to_uint8(image))
        written.append(out / frame_name(k))
    if "write_hdr" in plan:
        with recorder.run("write_hdr"):
            write_npy(out / frame_name(k, "npy"), hdr.astype(np.float32))
        written.append(out / frame_name(k, "npy"))
    if "write_vtu" in plan:
        with recorder.run("write_vtu"):
            for body, state in zip(world.bodies, world.states):
                path = out / f"{body.spec.name}_{k:04d}.vtu"
                write_atomic(path, lambda tmp: write_vtu(tmp, body.model, state))
                written.append(path)
    return written


def render_image(scene: Scene, seed: int | None = None, frame: int = 1, resolution: tuple[int, int] | None = None,
                 recorder: StageRecorder | None = None) -> np.ndarray:
    """One frame as display-referred uint8 RGB (H, W, 3), for golden-image checks and lookdev."""
    return render_frame_arrays(scene, seed, frame, resolution, recorder)[0]


def render_frame_arrays(scene: Scene, seed: int | None = None, frame: int = 1,
                        resolution: tuple[int, int] | None = None, recorder: StageRecorder | None = None,
                        passes=None):
    """One frame: (display uint8 RGB (H, W, 3), the renderer's ``FrameResult``: linear HDR, view depth and
    the G-buffer, as the post-effects receive them, and the ground-truth ``passes``, default the scene's)."""
    recorder = recorder_or_new(recorder)
    checked = check_scene(scene, recorder)
    plan, world = checked.plan, checked.world
    for _ in range(1, frame):
        if "simulate" in plan:
            advance(world, scene, recorder)
    w, h = resolution if resolution is not None else (None, None)
    s = frame_seed(scene, frame, seed)
    result, _ = render_hdr(world, scene, plan, recorder, (frame - 1) / scene.output.fps, s, w, h, passes=passes)
    image, _ = postprocess(scene, result.hdr, result.depth, recorder, s, w, h, frame)
    return postfx.to_uint8(image), result


def render_passes(scene: Scene, frame: int = 1, passes=None, seed: int | None = None,
                  resolution: tuple[int, int] | None = None) -> dict:
    """One frame's colour and ground truth as arrays, without a folder (docs/ground-truth.md): ``"colour"``
    display uint8 RGB (H, W, 3), ``"hdr"`` linear float32 (H, W, 3), each of ``passes`` (default: the scene's
    ``output.passes``, or all of them when it lists none) as written to ``passes/``, ``"labels"`` (the
    ``labels.json`` instances) and ``"camera"`` (``cameras.json`` with this frame's entry)."""
    listed = [p for p in scene.output.passes if p in groundtruth.PASS_NAMES]  # motion passes need a sequence
    wanted = list(passes if passes is not None else (listed or groundtruth.PASS_NAMES))
    unknown = [p for p in wanted if p not in groundtruth.PASS_NAMES]
    if unknown:
        raise UserError(f"render_passes: passes: expected names from {', '.join(groundtruth.PASS_NAMES)}, "
                        f"found {unknown[0]!r}")
    colour, result = render_frame_arrays(scene, seed, frame, resolution, passes=wanted)
    w, h = resolution if resolution is not None else (None, None)
    t = (frame - 1) / scene.output.fps
    camera = camera_for(scene, w, h, t)
    entry = groundtruth.camera_entry(camera, frame, t)
    return {"colour": colour, "hdr": result.hdr, **result.passes,
            "labels": groundtruth.labels(scene),
            "camera": groundtruth.cameras_document(camera, [entry], lens_for(scene, camera))}


class _progress:
    """A rich progress bar when asked for and attached to a terminal or CI log; otherwise silent."""

    def __init__(self, enabled: bool, total: int, name: str):
        self._progress = None
        if enabled:
            self._progress = Progress(TextColumn(f"rendering {name}"), BarColumn(), MofNCompleteColumn(),
                                      TimeRemainingColumn(), transient=False)
            self._progress.start()
            self._task = self._progress.add_task("frames", total=total)

    def advance(self) -> None:
        if self._progress is not None:
            self._progress.advance(self._task)

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()
