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
    """Advance every body by one frame interval (``steps_per_frame`` steps of ``simulation.dt``)."""
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
