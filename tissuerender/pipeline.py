"""One render, frame by frame: simulate -> embed -> raster -> shade -> post-effects -> write.

Each stage runs only when the plan lists it (``tissuerender.plan``) and is timed by the
:class:`~tissuerender.stages.StageRecorder`; ``out/manifest.json`` records both. Frames are written
atomically (a temporary file in the same folder, then ``os.replace``), so an interrupted render never
leaves a half-written frame, and ``resume=True`` skips the frames already on disk (the simulation
still advances through them, so the remaining frames are identical to an uninterrupted run).
"""
from __future__ import annotations

import hashlib
import importlib
import json
import os
import platform
import tempfile
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np

from tissuerender.bodies import Body, StaticSurface, build_body, build_static_surface
from tissuerender.errors import UserError
from tissuerender.plan import Plan, make_plan
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder

PACKAGES = ("tissuerender", "numpy", "numba", "scipy", "vtk", "pyvista", "meshio", "trimesh", "pillow", "pydantic")


class SimulationFailed(UserError):
    """The integrator diverged; reported instead of writing NaN frames."""


def frame_name(index: int, ext: str = "png") -> str:
    return f"frame_{index:04d}.{ext}"


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` then rename onto ``path``: readers never see a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix + ".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


@dataclass
class World:
    """Everything built once per render: bodies with their integrators and states, static surfaces."""

    bodies: list[Body]
    surfaces: list[StaticSurface]
    integrators: list = field(default_factory=list)
    states: list = field(default_factory=list)


def build_world(scene: Scene, plan: Plan, recorder: StageRecorder) -> World:
    bodies, surfaces = [], []
    if "mesh" in plan:
        with recorder.run("mesh"):
            bodies = [build_body(o, i, scene) for i, o in enumerate(scene.objects) if o.kind == "body"]
    if "load_surface" in plan:
        with recorder.run("load_surface"):
            surfaces = [build_static_surface(o, i, scene) for i, o in enumerate(scene.objects) if o.kind == "surface"]
    world = World(bodies, surfaces)
    if "simulate" in plan:
        from sim.integrators import make_integrator
        from sim.model import State

        probes = [make_probe(t) for t in scene.tools] if "contact" in plan else []
        sim = scene.simulation
        settings = dict(getattr(sim, sim.integrator).model_dump())
        settings.update(substeps=sim.substeps, iterations=sim.iterations)
        for body in bodies:
            body.model.probes = list(probes)
            try:
                world.integrators.append(make_integrator(sim.integrator, body.model, settings))
            except (NotImplementedError, ValueError) as e:
                raise UserError(f"{scene.path}: [simulation.{sim.integrator}] for object {body.spec.name!r}: {e}") from None
            world.states.append(State.at_rest(body.model))
    return world


def make_probe(tool):
    from sim.probe import Probe

    times = np.array([k.t for k in tool.keyframes], dtype=np.float64)
    positions = np.array([k.position for k in tool.keyframes], dtype=np.float64)
    return Probe(kind=tool.kind, radius=tool.radius, times=times, positions=positions,
                 axis=np.asarray(tool.axis, dtype=np.float64), length=tool.length)


def advance(world: World, scene: Scene, recorder: StageRecorder) -> None:
    """Advance every body by one frame interval (``steps_per_frame`` steps of ``simulation.dt``)."""
    from sim.errors import SimulationDiverged

    dt = scene.simulation.dt
    with recorder.run("simulate"):
        for i, integrator in enumerate(world.integrators):
            for _ in range(scene.steps_per_frame):
                try:
                    world.states[i] = integrator.step(world.states[i], dt)
                except SimulationDiverged as e:
                    raise SimulationFailed(
                        f"{scene.path}: simulation of {world.bodies[i].spec.name!r} with "
                        f"{scene.simulation.integrator} diverged at t = {world.states[i].t:.4g} s: {e}. "
                        "Try a smaller simulation.dt or more substeps."
                    ) from None
                if not np.all(np.isfinite(world.states[i].x)):
                    raise SimulationFailed(f"{scene.path}: simulation of {world.bodies[i].spec.name!r} "
                                           f"produced non-finite positions at t = {world.states[i].t:.4g} s")


def renderer():
    """The deferred renderer module (``tissuerender.renderer``)."""
    return importlib.import_module("tissuerender.renderer")


def camera_for(scene: Scene, width: int | None = None, height: int | None = None):
    Camera = renderer().Camera

    c = scene.camera
    return Camera(position=c.position, look_at=c.look_at, up=c.up, fov_deg=c.fov_deg, near=c.near, far=c.far,
                  width=width or scene.width, height=height or scene.height,
                  focus_distance=c.focus_distance, aperture=c.aperture)


def light_for(scene: Scene):
    AreaLight = renderer().AreaLight

    lt = scene.light
    return AreaLight(size=tuple(lt.size), radiance=tuple(lt.radiance), attach=lt.attach,
                     position=lt.position, normal=lt.normal, up=lt.up, offset=tuple(lt.offset),
                     importance=tuple((tuple(k.centre), k.radius, k.multiplier) for k in lt.importance),
                     reflection_cone=lt.reflection_cone, cone_samples=lt.cone_samples,
                     sampling=lt.sampling, samples=lt.samples, pattern=lt.pattern, estimator=lt.estimator,
                     penumbra_samples=lt.penumbra_samples)


def settings_for(scene: Scene, seed: int):
    RenderSettings = renderer().RenderSettings

    e = scene.effects
    return RenderSettings(shadows=e.shadows, sss=e.sss, sss_thickness=e.sss_thickness, ao=e.ao, mucus_reflection=e.mucus_reflection,
                          supersampling=scene.output.supersampling,
                          jitter=scene.output.jitter,
                          seed=seed, motion=e.motion, ambient=tuple(e.ambient), ao_distance=e.ao_distance,
                          ao_samples=e.ao_samples, environment_up=tuple(e.environment_up),
                          environment_down=tuple(e.environment_down), environment_axis=tuple(e.environment_axis))


def tool_surface(tool, t: float):
    """A triangle mesh of a visible tool at time ``t`` (sphere or capsule along its axis)."""
    import trimesh

    from sim.probe import Probe  # noqa: F401  (the probe's own path interpolation)

    probe = make_probe(tool)
    centre = np.asarray(probe.position(t), dtype=np.float64)
    if tool.kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=tool.radius)
    else:
        m = trimesh.creation.capsule(height=tool.length, radius=tool.radius, count=[24, 24])
        axis = np.asarray(tool.axis, dtype=np.float64)
        m.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], axis / np.linalg.norm(axis)))
    return np.asarray(m.vertices) + centre, np.asarray(m.faces, dtype=np.int32), np.asarray(m.vertex_normals)


def optics_for(spec):
    """The object's optics when its scene overrides some (``[objects.optics]``), else None (the preset's)."""
    if spec.optics is None:
        return None
    import materials
    from materials.optics import with_overrides

    return with_overrides(materials.get_preset(spec.material).optics, spec.optics.values())


def render_objects(world: World, scene: Scene, t: float, plan: Plan, recorder: StageRecorder, previous=None):
    from sim.mesh.surface import vertex_normals

    RenderObject = renderer().RenderObject

    objects = []
    positions = {}
    oid = 0
    for i, body in enumerate(world.bodies):
        if "embed" in plan:
            with recorder.run("embed"):
                pts = body.surface_points(world.states[i].x)
                normals = vertex_normals(pts, body.surface.triangles)
        else:
            pts, normals = body.surface.points, body.surface.normals
        velocity = None
        if "velocity_channel" in plan:
            prev = previous.get(body.spec.name, pts) if previous else pts
            velocity = (pts - prev) * scene.output.fps
        positions[body.spec.name] = pts
        objects.append(RenderObject(points=pts, triangles=body.surface.triangles, normals=normals,
                                    uv=body.surface.uv, material=body.spec.material, object_id=oid,
                                    velocity=velocity, optics=optics_for(body.spec)))
        oid += 1
    for s in world.surfaces:
        vel = np.zeros_like(s.surface.points) if "velocity_channel" in plan else None
        objects.append(RenderObject(points=s.surface.points, triangles=s.surface.triangles,
                                    normals=s.surface.normals, uv=s.surface.uv, material=s.spec.material,
                                    object_id=oid, velocity=vel, optics=optics_for(s.spec)))
        oid += 1
    for tool in scene.tools:
        if tool.visible:
            pts, tris, normals = tool_surface(tool, t)
            vel = np.zeros_like(pts) if "velocity_channel" in plan else None
            objects.append(RenderObject(points=pts, triangles=tris, normals=normals, uv=None,
                                        material="plastic", object_id=oid, velocity=vel))
            oid += 1
    return objects, positions


def render_hdr(world: World, scene: Scene, plan: Plan, recorder: StageRecorder, t: float, seed: int,
               width: int | None = None, height: int | None = None, previous=None):
    """Raster and shade one frame: (FrameResult, surface positions by body name)."""
    render_frame = renderer().render_frame
    objects, positions = render_objects(world, scene, t, plan, recorder, previous)
    try:
        result = render_frame(objects, camera_for(scene, width, height), light_for(scene),
                              settings_for(scene, seed), recorder=recorder)
    except NotImplementedError as e:
        raise UserError(f"{scene.path}: [effects] asks for something this renderer cannot do: {e}") from None
    return result, positions


def postprocess(scene: Scene, hdr: np.ndarray, depth: np.ndarray, recorder: StageRecorder, seed: int,
                width: int | None = None, height: int | None = None):
    """Post-effects of the scene's chain; returns display-referred float32 RGB in [0, 1]."""
    import postfx

    chain = scene.effect_chain()
    c = scene.camera
    lens = postfx.Lens(fov_deg=c.fov_deg, width=width or scene.width, height=height or scene.height)
    try:
        out = postfx.apply_chain(hdr, depth, chain, lens, backend=scene.effects.backend, seed=seed)
    except postfx.OSMesaUnavailable as e:
        raise UserError(f"{scene.path}: effects.backend = \"osmesa\": {e}") from None
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


def _manifest(scene: Scene, plan: Plan, recorder: StageRecorder, frames_done: int, wall: float, extra: dict) -> dict:
    return {
        "scene": str(scene.path),
        "scene_name": scene.name,
        "scene_sha256": scene.sha256,
        "seed": scene.seed,
        "versions": package_versions(),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "plan": plan.as_dict(),
        "executed": recorder.summary(),
        "frames_total": scene.output.frames,
        "frames_done": frames_done,
        "wall_seconds": round(wall, 3),
        **extra,
    }


def _write_json(path: Path, data: dict) -> None:
    write_atomic(path, lambda tmp: Path(tmp).write_text(json.dumps(data, indent=2, sort_keys=False) + "\n"))


def _write_png(path: Path, image01: np.ndarray) -> None:
    from PIL import Image

    import postfx

    rgb = postfx.to_uint8(image01)
    write_atomic(path, lambda tmp: Image.fromarray(rgb).save(tmp, format="PNG"))


def _write_npy(path: Path, hdr: np.ndarray) -> None:
    def write(tmp):
        with open(tmp, "wb") as f:
            np.save(f, hdr.astype(np.float32))

    write_atomic(path, write)


def render(scene: Scene, out_dir, resume: bool = False, progress: bool = True, frames: int | None = None) -> RunResult:
    """Render the scene's image sequence into ``out_dir`` (frames, optional HDR/VTU, manifest.json)."""
    start = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
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
            png = out / frame_name(k)
            wanted = [png] if "write_png" in plan else []
            wanted += [out / frame_name(k, "npy")] if "write_hdr" in plan else []
            if resume and wanted and all(p.exists() for p in wanted):
                skipped.append(png)
                bar.advance()
                continue
            t = (k - 1) / scene.output.fps
            seed = frame_seed(scene, k)
            result, previous = render_hdr(world, scene, plan, recorder, t, seed, previous=previous)
            image, backend_used = postprocess(scene, result.hdr, result.depth, recorder, seed)
            if "write_png" in plan:
                with recorder.run("write_png"):
                    _write_png(png, image)
                written.append(png)
            if "write_hdr" in plan:
                with recorder.run("write_hdr"):
                    _write_npy(out / frame_name(k, "npy"), result.hdr)
                written.append(out / frame_name(k, "npy"))
            if "write_vtu" in plan:
                from sim.output import write_vtu

                with recorder.run("write_vtu"):
                    for i, body in enumerate(world.bodies):
                        write_vtu(out / f"{body.spec.name}_{k:04d}.vtu", body.model, world.states[i])
            _write_json(out / "manifest.json", _manifest(scene, plan, recorder, k, time.perf_counter() - start,
                                                         {"postfx_backend": backend_used, "complete": False}))
            bar.advance()
    finally:
        bar.close()
    manifest = _manifest(scene, plan, recorder, n_frames, time.perf_counter() - start,
                         {"postfx_backend": backend_used, "complete": True,
                          "written": [p.name for p in written], "resumed_skipped": [p.name for p in skipped]})
    _write_json(out / "manifest.json", manifest)
    return RunResult(out, written, skipped, plan, recorder, manifest)


def render_image(scene: Scene, seed: int | None = None, frame: int = 1, resolution: tuple[int, int] | None = None,
                 recorder: StageRecorder | None = None) -> np.ndarray:
    """One frame as display-referred uint8 RGB (H, W, 3), for golden-image checks and lookdev."""
    return render_frame_arrays(scene, seed, frame, resolution, recorder)[0]


def render_frame_arrays(scene: Scene, seed: int | None = None, frame: int = 1,
                        resolution: tuple[int, int] | None = None, recorder: StageRecorder | None = None):
    """One frame: (display uint8 RGB (H, W, 3), the renderer's ``FrameResult``: linear HDR, view depth and
    the G-buffer, as the post-effects receive them)."""
    import postfx

    plan = make_plan(scene)
    recorder = recorder if recorder is not None else StageRecorder()
    world = build_world(scene, plan, recorder)
    for _ in range(1, frame):
        if "simulate" in plan:
            advance(world, scene, recorder)
    w, h = resolution if resolution is not None else (None, None)
    s = frame_seed(scene, frame, seed)
    result, _ = render_hdr(world, scene, plan, recorder, (frame - 1) / scene.output.fps, s, w, h)
    image, _ = postprocess(scene, result.hdr, result.depth, recorder, s, w, h)
    return postfx.to_uint8(image), result


class _progress:
    """A rich progress bar when asked for and attached to a terminal or CI log; otherwise silent."""

    def __init__(self, enabled: bool, total: int, name: str):
        self._progress = None
        if enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

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
