"""Frames at exact times: the simulation reaches each frame's time (k - 1) / fps exactly, so a tool drawn at the
frame time sits where it pushed the tissue (issue 16 item 2); and a failure of the simulation is reported with
the frame, the object and the stage."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from sim.errors import SimulationDiverged
from sim.integrators.xpbd.sweeps import FusedSweeps
from sim.probe import Probe
from tissuerender import load_scene, make_plan
from tissuerender.cli import main
from tissuerender.errors import SceneError, UserError
from tissuerender.stages import StageRecorder
from tissuerender.world import SimulationFailed, advance, build_world, make_probe

EPS = sys.float_info.epsilon


def _sliding_probe(scene_dict, dt=None):
    """A 20 x 6 x 3 cm block (1 cm cells) and a 1 cm sphere that presses 6 mm in over 0.1 s, then slides along x
    at 0.3 m/s: at frame 13 (t = 0.5 s) a simulation running at 0.8x real time would hold it 3 cm behind."""
    scene_dict["objects"][0].update(size=[0.2, 0.06, 0.03], cell_size=0.01)
    scene_dict["simulation"] = {"integrator": "xpbd", "gravity": [0.0, 0.0, 0.0], "substeps": 4, "iterations": 10}
    if dt is not None:
        scene_dict["simulation"]["dt"] = dt
    scene_dict["tools"] = [{"name": "probe", "radius": 0.01, "keyframes": [
        {"t": 0.0, "position": [0.03, 0.03, 0.045]}, {"t": 0.1, "position": [0.03, 0.03, 0.034]},
        {"t": 0.6, "position": [0.18, 0.03, 0.034]}]}]
    scene_dict["output"]["frames"] = 13
    return scene_dict


def test_drawn_probe_sits_on_the_dent_it_makes_with_the_default_dt(scene_dict, write_scene, monkeypatch):
    # no simulation.dt in the file: the default must divide the default frame interval (1/60 s did not: 2.5 steps,
    # rounded to 2, so the simulation ran at 0.8x the frame clock)
    scene = load_scene(write_scene(_sliding_probe(scene_dict)))
    seen = []
    segment = Probe.segment

    def recording_segment(self, t):
        seen.append(t)
        return segment(self, t)

    capsule_rows = Probe.capsule_rows

    def recording_rows(self, ts):  # the one-call sweeps ask for every substep's capsules of a step at once
        seen.extend(np.asarray(ts, dtype=np.float64).reshape(-1).tolist())
        return capsule_rows(self, ts)

    monkeypatch.setattr(Probe, "segment", recording_segment)
    monkeypatch.setattr(Probe, "capsule_rows", recording_rows)
    # one step's poses per call, so the last time asked is the frame's last substep's (the look-ahead gives the
    # same capsules: tests/sim/test_contact_set.py runs past it against the per-sweep loop)
    monkeypatch.setattr(FusedSweeps, "LOOKAHEAD", 1)
    world = build_world(scene, make_plan(scene), StageRecorder())
    tool = scene.tools[0]
    radius = tool.radius
    substeps = scene.simulation.substeps
    for k in range(2, scene.output.frames + 1):
        advance(world, scene, StageRecorder())
        t = (k - 1) / scene.output.fps  # the time the renderer draws frame k's tools at (pipeline.render)
        state = world.states[0]
        assert state.t == t  # bitwise: the frame's time is computed, not summed
        # the probe of the last substep: its time is the step's start plus `substeps` additions of h, each
        # rounding by at most half an ulp of a time <= t, plus the rounding of h and of the start:
        # |t_sim - t| <= (substeps + 2) eps t
        assert abs(seen[-1] - t) <= (substeps + 2) * EPS * t
        drawn = make_probe(tool).position(t)
        pushed_with = make_probe(tool).position(seen[-1])
        # speed 0.3 m/s times that time error, plus the interpolation's rounding (4 ulps of 0.2 m)
        assert np.abs(pushed_with - drawn).max() <= 0.3 * (substeps + 2) * EPS * t + 4 * EPS * 0.2
        if t >= 0.1:  # pressed in: the deepest-dented node lies under the drawn probe (within its radius;
            # measured at most 6.8 mm with 1 cm cells; a 0.8x clock would put it 0.6 (t - 0.1) / 0.8 m behind,
            # 3 cm at frame 13)
            dz = state.x[:, 2] - world.bodies[0].model.X[:, 2]
            deepest = int(np.argmin(dz))
            assert dz[deepest] < -0.003
            assert np.hypot(*(state.x[deepest, :2] - drawn[:2])) < radius
    assert world.frames_advanced == scene.output.frames - 1


def test_dt_that_does_not_divide_the_frame_interval_is_rejected_naming_the_nearest_divisors(
        scene_dict, write_scene, capsys):
    path = write_scene(_sliding_probe(scene_dict, dt=1.0 / 60.0))
    with pytest.raises(SceneError) as e:
        load_scene(path)
    msg = str(e.value)
    assert "simulation.dt" in msg and "0.016666666666666666 (2.5 steps per frame)" in msg
    assert "1/24 s = 0.041666666666666664 s" in msg
    assert "use 1/48 = 0.020833333333333332 or 1/72 = 0.013888888888888888" in msg
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "simulation.dt" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("fps, dt", [(24.0, 0.002), (30.0, 0.0125), (23.976, 0.01), (24.0, 0.1), (24.0, 0.0416)])
def test_every_suggested_dt_is_accepted_and_divides_the_interval(scene_dict, write_scene, fps, dt):
    data = _sliding_probe(scene_dict, dt=dt)
    data["output"]["fps"] = fps
    with pytest.raises(SceneError) as e:
        load_scene(write_scene(data))
    suggestions = [float(s.split(" = ")[1]) for s in str(e.value).split("use ")[1].split(" or ")]
    assert suggestions and all(s > 0 for s in suggestions)
    for s in suggestions:
        data["simulation"]["dt"] = s
        scene = load_scene(write_scene(data))
        n = scene.steps_per_frame
        assert abs(n * s - 1.0 / fps) <= 4 * n * EPS / fps
        # the suggestions bracket the rejected dt (or are the frame interval itself for a dt longer than it)
        assert min(abs(s - dt) for s in suggestions) < max(dt, 1.0 / fps)


@pytest.mark.parametrize("dt", [1.0 / 120.0, 1.0 / 24.0, 1.0 / 48.0, 1.0 / 72.0, 0.008333333333333333])
def test_dividing_steps_are_accepted(scene_dict, write_scene, dt):
    scene = load_scene(write_scene(_sliding_probe(scene_dict, dt=dt)))
    assert scene.steps_per_frame == round(1.0 / (24.0 * dt))


def _diverging_world(scene_dict, write_scene, step):
    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1.0 / 24.0, "substeps": 1, "iterations": 1}
    scene_dict["output"]["frames"] = 3
    scene = load_scene(write_scene(scene_dict))
    world = build_world(scene, make_plan(scene), StageRecorder())
    real = world.integrators[0].step
    calls = {"n": 0}

    def faulty(state, dt):  # the real step; the fault is injected on the second call
        calls["n"] += 1
        return step(real(state, dt), calls["n"])

    world.integrators[0].step = faulty
    return scene, world


def test_non_finite_positions_are_reported_with_frame_object_and_stage(scene_dict, write_scene):
    def nan_on_second(state, n):
        if n == 2:
            state.x[5, 1] = np.nan
        return state

    scene, world = _diverging_world(scene_dict, write_scene, nan_on_second)
    advance(world, scene, StageRecorder())
    with pytest.raises(SimulationFailed) as e:
        advance(world, scene, StageRecorder())
    msg = str(e.value)
    assert isinstance(e.value, UserError)  # the CLI maps it to exit 2
    assert "frame 3, object 'block', stage simulate" in msg and "node 5" in msg and "1 of" in msg


def test_a_diverged_integrator_is_reported_with_frame_object_and_stage(scene_dict, write_scene):
    def diverge_on_second(state, n):
        if n == 2:
            raise SimulationDiverged("xpbd: tet 7 inverted")
        return state

    scene, world = _diverging_world(scene_dict, write_scene, diverge_on_second)
    advance(world, scene, StageRecorder())
    with pytest.raises(SimulationFailed) as e:
        advance(world, scene, StageRecorder())
    assert "frame 3, object 'block', stage simulate: xpbd diverged at t = 0.04167 s: xpbd: tet 7 inverted" in str(e.value)
