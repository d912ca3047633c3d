"""One render, frame by frame: simulate -> embed -> raster -> shade -> post-effects -> write.

Each stage runs only when the plan lists it (``tissuerender.plan``) and is timed by the
:class:`~tissuerender.stages.StageRecorder`; ``out/manifest.json`` records both. Frames are written
atomically (``tissuerender.files``), so an interrupted render never leaves a half-written frame, and
``resume=True`` skips the frames already on disk (the simulation still advances through them, so the
remaining frames are identical to an uninterrupted run).
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

import postfx
from sim.output import write_vtu
from tissuerender.errors import UserError
from tissuerender.finite import NonFiniteError, frame_at
from tissuerender.files import output_folder, write_atomic, write_json, write_npy, write_png
from tissuerender.manifest import manifest
from tissuerender.plan import Plan, make_plan
from tissuerender.renderer import render_frame
from tissuerender.render_inputs import camera_for, light_for, render_objects, settings_for
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder, recorder_or_new
from tissuerender.world import World, advance, build_world


def frame_name(index: int, ext: str = "png") -> str:
    return f"frame_{index:04d}.{ext}"


def render_hdr(world: World, scene: Scene, plan: Plan, recorder: StageRecorder, t: float, seed: int,
               width: int | None = None, height: int | None = None, previous=None):
    """Raster and shade one frame: (FrameResult, surface positions by body name)."""
    objects, positions = render_objects(world, scene, t, plan, recorder, previous)
    try:
        result = render_frame(objects, camera_for(scene, width, height), light_for(scene),
                              settings_for(scene, seed), recorder=recorder)
    except NotImplementedError as e:
        raise UserError(f"{scene.path}: [effects] asks for something this renderer cannot do: {e}") from None
    except NonFiniteError as e:
        raise e.located(scene.path, frame_at(t, scene.output.fps), [o.name for o in objects]) from None
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


def render(scene: Scene, out_dir, resume: bool = False, progress: bool = True, frames: int | None = None) -> RunResult:
    """Render the scene's image sequence into ``out_dir`` (frames, optional HDR/VTU, manifest.json)."""
    start = time.perf_counter()
    out = output_folder(out_dir)
    plan = make_plan(scene)
    recorder = StageRecorder()
    world = build_world(scene, plan, recorder)
    n_frames = scene.output.frames if frames is None else min(frames, scene.output.frames)
    written, skipped = [], []
    previous = None
    backend_used = None
    bar = _progress(progress, n_frames, scene.name)
    try:
        for k in range(1, n_frames + 1):
            if k > 1 and "simulate" in plan:
                advance(world, scene, recorder)
            wanted = _frame_files(out, k, plan)
            if resume and wanted and all(p.exists() for p in wanted):
                skipped.append(out / frame_name(k))
                bar.advance()
                continue
            t = (k - 1) / scene.output.fps
            seed = frame_seed(scene, k)
            result, previous = render_hdr(world, scene, plan, recorder, t, seed, previous=previous)
            image, backend_used = postprocess(scene, result.hdr, result.depth, recorder, seed, frame=k)
            written += _write_frame(out, k, plan, recorder, world, image, result.hdr)
            write_json(out / "manifest.json", manifest(scene, plan, recorder, k, time.perf_counter() - start,
                                                       {"postfx_backend": backend_used, "complete": False}))
            bar.advance()
    finally:
        bar.close()
    final = manifest(scene, plan, recorder, n_frames, time.perf_counter() - start,
                     {"postfx_backend": backend_used, "complete": True,
                      "written": [p.name for p in written], "resumed_skipped": [p.name for p in skipped]})
    write_json(out / "manifest.json", final)
    return RunResult(out, written, skipped, plan, recorder, final)


def _frame_files(out: Path, k: int, plan: Plan) -> list[Path]:
    """The image files frame ``k`` writes; ``resume`` keeps a frame when all of them exist."""
    wanted = [out / frame_name(k)] if "write_png" in plan else []
    wanted += [out / frame_name(k, "npy")] if "write_hdr" in plan else []
    return wanted


def _write_frame(out: Path, k: int, plan: Plan, recorder: StageRecorder, world: World, image: np.ndarray,
                 hdr: np.ndarray) -> list[Path]:
    """Write frame ``k``'s planned outputs (display PNG, linear HDR, one .vtu per body); returns the images."""
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
                write_atomic(out / f"{body.spec.name}_{k:04d}.vtu", lambda tmp: write_vtu(tmp, body.model, state))
    return written


def render_image(scene: Scene, seed: int | None = None, frame: int = 1, resolution: tuple[int, int] | None = None,
                 recorder: StageRecorder | None = None) -> np.ndarray:
    """One frame as display-referred uint8 RGB (H, W, 3), for golden-image checks and lookdev."""
    return render_frame_arrays(scene, seed, frame, resolution, recorder)[0]


def render_frame_arrays(scene: Scene, seed: int | None = None, frame: int = 1,
                        resolution: tuple[int, int] | None = None, recorder: StageRecorder | None = None):
    """One frame: (display uint8 RGB (H, W, 3), the renderer's ``FrameResult``: linear HDR, view depth and
    the G-buffer, as the post-effects receive them)."""
    plan = make_plan(scene)
    recorder = recorder_or_new(recorder)
    world = build_world(scene, plan, recorder)
    for _ in range(1, frame):
        if "simulate" in plan:
            advance(world, scene, recorder)
    w, h = resolution if resolution is not None else (None, None)
    s = frame_seed(scene, frame, seed)
    result, _ = render_hdr(world, scene, plan, recorder, (frame - 1) / scene.output.fps, s, w, h)
    image, _ = postprocess(scene, result.hdr, result.depth, recorder, s, w, h, frame)
    return postfx.to_uint8(image), result


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
