"""The simulated world of one render: bodies with their integrators and states, static surfaces, tools,
built once from the scene and advanced one frame interval at a time."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim import integrators  # called through the module, so tests can replace make_integrator
from sim.errors import SimulationDiverged
from sim.model import State
from sim.probe import Probe
from tissuerender.bodies import Body, StaticSurface, build_body, build_static_surface
from tissuerender.errors import UserError
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
        probes = [make_probe(t) for t in scene.tools] if "contact" in plan else []
        sim = scene.simulation
        settings = dict(getattr(sim, sim.integrator).model_dump())
        settings.update(substeps=sim.substeps, iterations=sim.iterations)
        for body in bodies:
            body.model.probes = list(probes)
            try:
                world.integrators.append(integrators.make_integrator(sim.integrator, body.model, settings))
            except (NotImplementedError, ValueError) as e:
                raise UserError(f"{scene.path}: [simulation.{sim.integrator}] for object {body.spec.name!r}: {e}") from None
            world.states.append(State.at_rest(body.model))
    return world


def make_probe(tool) -> Probe:
    """The simulation's rigid probe for a scene tool (its keyframed path)."""
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
    with recorder.run("simulate"):
        for i, integrator in enumerate(world.integrators):
            name = world.bodies[i].spec.name
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
                bad = ~np.isfinite(state.x).all(axis=1)
                if bad.any():
                    raise SimulationFailed(
                        f"{scene.path}: frame {f + 2}, object {name!r}, stage simulate: {scene.simulation.integrator} "
                        f"produced non-finite positions at {int(bad.sum())} of {bad.size} nodes (first: node "
                        f"{int(np.flatnonzero(bad)[0])}) at t = {state.t:.4g} s. Try a smaller simulation.dt or more substeps.")
    world.frames_advanced = f + 1
