"""The simulated world of one render: bodies with their integrators and states, static surfaces, tools,
built once from the scene and advanced one frame interval at a time."""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim import integrators  # called through the module, so tests can replace make_integrator
from sim.cutting.surface import cut_surfaces
from sim.errors import SimulationDiverged
from sim.model import State
from sim.probe import Probe
from tissuerender import instruments
from tissuerender.contacts import GroupStepper, add_contact_loads, attach_contacts, contact_names, mesh_tool_probe
from tissuerender.bodies import Body, StaticSurface, build_body, build_static_surface
from tissuerender.errors import UserError
from tissuerender.files import write_atomic
from tissuerender.plan import Plan
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder


class SimulationFailed(UserError):
    """The integrator diverged; reported instead of writing NaN frames."""


@dataclass
class World:
    """Everything built once per render: bodies with their integrators and states, static surfaces."""

    bodies: list[Body]
    surfaces: list[StaticSurface]
    integrators: list = field(default_factory=list)
    states: list = field(default_factory=list)
    frames_advanced: int = 0  # frame intervals simulated so far: the states are at time frames_advanced / fps
    # (tools, 6): force [N] and torque [N m] about its centre the tissue exerted on each tool, mean over the last frame
    # interval, summed over bodies; NaN where a body's integrator reports no contact forces (only xpbd does)
    tool_loads: np.ndarray | None = None
    # then one row per body with a floor (objects.floor, ``floor_names``): force and torque about its point on it
    # body index -> the faces a cut exposed (sim.cutting.surface), drawn with the body's cut_material; the body's own
    # render surface is then the rest of its tets' boundary (update_cut_surfaces)
    cut_faces: dict = field(default_factory=dict)


def build_world(scene: Scene, plan: Plan, recorder: StageRecorder) -> World:
    bodies, surfaces = [], []
    if "mesh" in plan:
        with recorder.run("mesh"):
            bodies = [build_body(o, i, scene) for i, o in enumerate(scene.objects) if o.kind == "body"]
    if "load_surface" in plan:
        with recorder.run("load_surface"):
            surfaces = [build_static_surface(o, i, scene) for i, o in enumerate(scene.objects) if o.kind == "surface"]
    world = World(bodies, surfaces)
    if "contact" in plan:
        world.tool_loads = np.zeros((len(scene.tools) + len(floor_names(scene)) + len(scene.contacts), 6))
    if "simulate" in plan:
        probes = [make_probe(t) for t in scene.tools] if "contact" in plan else []
        sim = scene.simulation
        settings = dict(getattr(sim, sim.integrator).model_dump())
        settings.update(substeps=sim.substeps, iterations=sim.iterations)
        grasps = [g.to_sim(k, t.radius) for k, t in enumerate(scene.tools) for g in t.grasp] if probes else []
        for body in bodies:
            body.model.probes = list(probes)
            body.model.grasps = list(grasps)  # sim.contact, xpbd only (interaction_schema.check_interaction)
            body.model.contact_planes = [] if body.spec.floor is None else [body.spec.floor.to_sim()]
            body.model.cuts = [c.to_sim(k, t.kind) for k, t in enumerate(scene.tools) for c in t.cut] if probes else []
        if scene.contacts and any(t.cut for t in scene.tools):
            # a cut rebuilds one body's tets; a contact group steps several bodies as one merged model
            raise UserError(f"{scene.path}: tools[{next(k for k, t in enumerate(scene.tools) if t.cut)}].cut: cutting "
                            "is not supported together with [[contacts]] between bodies; remove one of them")
        # [[contacts]]: bodies touching each other stepped as one model by their first member (tissuerender.contacts)
        try:
            groups, contact_rows = attach_contacts(scene, bodies, surfaces, len(scene.tools) + len(floor_names(scene)))
        except ValueError as e:
            raise UserError(f"{scene.path}: contacts: {e}") from None
        first_of = {g.members[0]: g for g in groups}
        grouped = {i for g in groups for i in g.members}
        floor_row = dict(zip([i for i, b in enumerate(bodies) if b.spec.floor is not None],
                             range(len(scene.tools), len(scene.tools) + len(floor_names(scene)))))
        for i, body in enumerate(bodies):
            group = first_of.get(i)
            integrator = None
            if group is not None or i not in grouped:
                try:
                    integrator = integrators.make_integrator(sim.integrator, group.group.model if group else body.model,
                                                             settings)
                except (NotImplementedError, ValueError) as e:
                    raise UserError(f"{scene.path}: [simulation.{sim.integrator}] for object {body.spec.name!r}: {e}") from None
                if group is not None:
                    group.floor_rows = [(floor_row[m], k) for k, m in enumerate(m for m in group.members if m in floor_row)]
                    integrator = GroupStepper(world, group, integrator)
                elif contact_rows.get(i):
                    integrator.contact_rows = contact_rows[i]
            world.integrators.append(integrator)  # None: stepped with its contact group's first member
            world.states.append(State.at_rest(body.model))
    return world


def floor_names(scene: Scene) -> list[str]:
    """The rows of the bodies' floors in the tool-force log, after the tools': ``floor:<object>``."""
    return [f"floor:{o.name}" for o in scene.objects if o.kind == "body" and o.floor is not None]


def make_probe(tool) -> Probe:
    """The simulation's rigid probe for a scene tool (its keyframed path)."""
    if tool.kind in instruments.INSTRUMENT_KINDS:
        return instruments.InstrumentProbe(tool)
    if tool.kind == "mesh":
        return mesh_tool_probe(tool)
    times = np.array([k.t for k in tool.keyframes], dtype=np.float64)
    positions = np.array([k.position for k in tool.keyframes], dtype=np.float64)
    return Probe(kind=tool.kind, radius=tool.radius, times=times, positions=positions,
                 axis=np.asarray(tool.axis, dtype=np.float64), length=tool.length)


def advance(world: World, scene: Scene, recorder: StageRecorder) -> None:
    """Advance every body by one frame interval, from ``f / fps`` to ``(f + 1) / fps`` (f = frames advanced so far):
    ``steps_per_frame`` steps of ``simulation.dt``, which divides the interval (``load_scene`` checks it). Each step
    starts at its own time ``f / fps + j dt``, computed rather than summed, and the interval ends on ``(f + 1) / fps``
    bitwise, the time the renderer draws the tools at (frame k shows ``(k - 1) / fps``), so a probe drawn at the
    frame time sits where the simulation pushed the tissue with it."""
    dt = scene.simulation.dt
    fps = scene.output.fps
    f = world.frames_advanced
    n = scene.steps_per_frame
    loads = None if world.tool_loads is None else np.zeros_like(world.tool_loads)
    floor_row = len(scene.tools)
    with recorder.run("simulate"):
        for i, integrator in enumerate(world.integrators):
            has_floor = world.bodies[i].spec.floor is not None
            name = world.bodies[i].spec.name
            if integrator is None:  # stepped with its contact group (tissuerender.contacts.GroupStepper)
                floor_row += has_floor
                continue
            for j in range(n):
                state = world.states[i]
                state.t = f / fps + j * dt
                try:
                    state = integrator.step(state, dt)
                except SimulationDiverged as e:
                    raise SimulationFailed(
                        f"{scene.path}: frame {f + 2}, object {name!r}, stage simulate: {scene.simulation.integrator} "
                        f"diverged at t = {state.t:.4g} s: {e}. Try a smaller simulation.dt or more substeps."
                    ) from None
                state.t = (f + 1) / fps if j == n - 1 else f / fps + (j + 1) * dt
                world.states[i] = state
                if loads is not None:
                    step_loads = getattr(integrator, "tool_loads", None)
                    loads[:len(scene.tools)] += np.nan if step_loads is None else step_loads / n
                    for row, plane in getattr(integrator, "floor_rows", None) or ([(floor_row, 0)] if has_floor else []):
                        loads[row] += integrator.plane_loads[plane] / n
                    add_contact_loads(loads, integrator, n)
                bad = ~np.isfinite(state.x).all(axis=1)
                if bad.any():
                    raise SimulationFailed(
                        f"{scene.path}: frame {f + 2}, object {name!r}, stage simulate: {scene.simulation.integrator} "
                        f"produced non-finite positions at {int(bad.sum())} of {bad.size} nodes (first: node "
                        f"{int(np.flatnonzero(bad)[0])}) at t = {state.t:.4g} s. Try a smaller simulation.dt or more substeps.")
            floor_row += has_floor
            update_cut_surfaces(world, i)
    world.frames_advanced = f + 1
    if loads is not None:
        world.tool_loads = loads


def update_cut_surfaces(world: World, i: int) -> None:
    """After body ``i``'s integrator removed tets (``sim.cutting``): its mesh, render surface and embedding become
    the remaining tets and the original part of their boundary, ``world.cut_faces[i]`` the faces the cut exposed."""
    cutter = getattr(world.integrators[i], "cutter", None)
    if cutter is None or cutter.revision in (0, world.cut_faces.get(i, (None, 0))[1]):
        return
    body = world.bodies[i]
    body.mesh, body.surface, body.embedding, faces = cut_surfaces(cutter.topology, body.model.X, body.mesh.source)
    world.cut_faces[i] = (faces, cutter.revision)


TOOL_FORCES_CSV = "tool_forces.csv"
TOOL_FORCE_COLUMNS = ("frame", "time", "tool", "fx", "fy", "fz", "tx", "ty", "tz")


def _finite(values) -> list:
    """JSON numbers, None for NaN (JSON has no NaN)."""
    return [float(v) if np.isfinite(v) else None for v in values]


class ToolForceLog:
    """Per frame and tool, the force [N] and torque [N m] (about the tool's centre) the tissue exerts on it: the mean
    over the frame interval ending at the frame's time (frame 1, t = 0: nothing simulated yet, zero). Kept in memory
    and written whole, atomically, after every frame to ``OUT/tool_forces.csv``; the simulation runs through the
    frames a resumed render skips, so their rows are recomputed and the file is complete after a resume too.
    Integrators other than xpbd resolve no tool contact forces: NaN."""

    def __init__(self, scene: Scene):
        self.names = [t.name for t in scene.tools] + floor_names(scene) + contact_names(scene)
        self.rows: dict[int, tuple[float, np.ndarray]] = {}

    def record(self, frame: int, t: float, world: World) -> None:
        loads = np.zeros((len(self.names), 6)) if frame == 1 else world.tool_loads
        self.rows[frame] = (t, np.array(loads, dtype=np.float64))

    def write(self, out: Path) -> None:
        text = io.StringIO()
        text.write(",".join(TOOL_FORCE_COLUMNS) + "\n")
        for frame in sorted(self.rows):
            t, loads = self.rows[frame]
            for name, load in zip(self.names, loads):
                text.write(f"{frame},{t!r},{name}," + ",".join(repr(float(v)) for v in load) + "\n")
        data = text.getvalue().encode()
        write_atomic(out / TOOL_FORCES_CSV, lambda tmp: Path(tmp).write_bytes(data))

    def summary(self) -> dict:
        """For the manifest: the file, sign and units, and per tool the last frame's and the peak force."""
        tools = {}
        for k, name in enumerate(self.names):
            frames = sorted(self.rows)
            if not frames:
                continue
            force = {f: self.rows[f][1][k] for f in frames}
            magnitude = {f: float(np.linalg.norm(force[f][:3])) for f in frames}
            finite = [f for f in frames if np.isfinite(magnitude[f])]
            peak = max(finite, key=lambda f: magnitude[f]) if finite else frames[-1]
            tools[name] = {"last_frame": frames[-1], "last_force_N": _finite(force[frames[-1]][:3]),
                           "last_torque_Nm": _finite(force[frames[-1]][3:]),
                           "peak_frame": peak, "peak_force_N": _finite([magnitude[peak]])[0]}
        return {"file": TOOL_FORCES_CSV, "columns": list(TOOL_FORCE_COLUMNS),
                "meaning": "force [N] and torque [N m] about the tool's centre that the tissue exerts on the tool, "
                           "mean over the frame interval ending at the frame's time; NaN: the integrator resolves no "
                           "contact forces", "tools": tools}
