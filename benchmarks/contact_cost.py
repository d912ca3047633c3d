"""What contact and grasping cost (issue 21, "Performance": at most 20 % of a step of ``liver_probe``): the liver of
scenes/liver_probe.toml and a 4 x 4 x 1.5 cm slab of fat dropped onto it from just above its top, stepped by xpbd as
one model, with the capsule probe pushing, a grasp of that probe (closing at 0.25 s, 3 cm, holding to the end) and
contact (``[[contacts]]``: liver and slab, friction 0.8; liver and the static peritoneum wall, 0.3), against the same
model stepped with none of these (the slab then falls through the liver) and with the probe alone.

Usage: .venv/bin/python benchmarks/contact_cost.py [--quick]
The three variants step the same model from rest over the scene's first steps in interleaved rounds (off, probe, on,
off, ...) after one warm-up each (every run from rest with the jaws open), so a machine that slows down or speeds up
affects all alike; figures are medians over the rounds. ``--quick``: 2 rounds of 6 steps, to check the script works.
Last line: one JSON object with ``seconds_step_off``, ``seconds_step_probe`` (the probe's contact alone, liver_probe
as shipped), ``seconds_step_on`` (per step), ``fraction`` = (on - off) / on, the share of a step with contact and
grasping that they take, ``fraction_beyond_probe`` = (on - probe) / on, the grasp's and the contacts' share, the same
in CPU time (``cpu_seconds_step_*``, ``cpu_fraction``: one thread, so the process's own time, which other jobs on a
shared machine disturb less than the wall clock), and
``grasped_nodes``, ``slab_liver_contacts``, ``wall_contacts`` (nodes in contact in the last substep: how much they did).
The same is measured on liver_probe's own bodies, without the slab (the liver alone, its probe, the grasp and the
liver-wall contact, against the liver stepped with none of them): ``seconds_step_liver_off``, ``seconds_step_liver_on``,
``fraction_liver``, ``cpu_fraction_liver``, interleaved with the others. There the wall touches no node (the liver's
base is held 4 cm above it); so, last, the liver *resting* on the wall (not held, the wall raised ``REST_LIFT`` to
meet its underside, gravity settles it onto the wall's folds): ``seconds_step_rest_off`` (falling freely, no contact),
``seconds_step_rest_on``, ``fraction_resting``, ``cpu_fraction_resting``, ``resting_wall_contacts``.
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import statistics
import sys
import time
import tomllib
from pathlib import Path

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numpy as np  # noqa: E402

from sim.contact import GraspState  # noqa: E402
from sim.integrators import make_integrator  # noqa: E402
from sim.model import State  # noqa: E402
from tissuerender.checks import check_scene  # noqa: E402
from tissuerender.scene.load import scene_from_data  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "liver_probe.toml"


# how far the resting variant raises the wall: its highest point under the liver's footprint (z = -0.0419 m as
# shipped) then meets the liver's underside (z = 0)
REST_LIFT = 0.0419


def scene_with_contact(slab: bool = True, resting: bool = False):
    """liver_probe with a grasp on its probe and the liver-wall contact, and (``slab``) the fat slab on the liver; or
    (``resting``) the liver not held but lying on the wall under gravity, the wall raised to meet its underside."""
    data = tomllib.loads(SCENE.read_text())
    # the capsule's lower end, not its path point, reaches the liver: a 3 cm grasp radius takes the nodes it presses
    data["tools"][0]["grasp"] = [{"t_close": 0.25, "t_release": 1.0, "radius": 0.03}]
    if resting:  # the organ on the abdominal wall: about a hundred nodes in contact once it has settled
        del data["objects"][0]["fixed"]
        x, y, z = data["objects"][1]["position"]
        data["objects"][1]["position"] = [x, y, z + REST_LIFT]
        data["contacts"] = [{"bodies": ["liver", "wall"], "friction": 0.3}]
        return scene_from_data(data, SCENE, "benchmark")
    if not slab:  # the scene's own bodies: the probe, its grasp and the liver-wall contact
        data["contacts"] = [{"bodies": ["liver", "wall"], "friction": 0.3}]
        return scene_from_data(data, SCENE, "benchmark")
    # on the liver's top (its highest node is at (0.045, 0.038, 0.097)); friction 0.8 holds it on the slope
    data["objects"].insert(1, {"name": "slab", "shape": "box", "size": [0.04, 0.04, 0.015], "cell_size": 0.01,
                               "material": "fat", "position": [0.025, 0.018, 0.099]})
    data["contacts"] = [{"bodies": ["liver", "slab"], "friction": 0.8}, {"bodies": ["liver", "wall"], "friction": 0.3}]
    return scene_from_data(data, SCENE, "benchmark")


def run(integrator, model, steps: int, dt: float) -> tuple[float, float]:
    """Wall and CPU time per step (one thread: the CPU time is this run's alone, steadier on a shared machine)."""
    state = State.at_rest(model)
    # every run from rest with open jaws: a grasp left closed by the previous run would hold its nodes from t = 0
    integrator.grasps = [GraspState(g.grasp, g.probe) for g in getattr(integrator, "grasps", ())]
    start, start_cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        state = integrator.step(state, dt)
    return (time.perf_counter() - start) / steps, (time.process_time() - start_cpu) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 rounds of 6 steps: checks the script works")
    args = parser.parse_args()
    scene = scene_with_contact()
    checked = check_scene(scene)
    world = checked.world
    stepper = world.integrators[0]  # tissuerender.contacts.GroupStepper: liver and slab as one model
    on_model = stepper.group.group.model
    off_model = copy.copy(on_model)  # the same body without probes, grasps or contacts
    off_model.probes, off_model.grasps, off_model.contacts, off_model.contact_planes = [], [], [], []
    probe_model = copy.copy(off_model)  # liver_probe as shipped: its probe pushes, no grasp, no wall contact
    probe_model.probes = list(on_model.probes)
    settings = dict(scene.simulation.xpbd.model_dump(), substeps=scene.simulation.substeps,
                    iterations=scene.simulation.iterations)
    variants = {"off": (make_integrator("xpbd", off_model, settings), off_model),
                "probe": (make_integrator("xpbd", probe_model, settings), probe_model),
                "on": (stepper.integrator, on_model)}
    # liver_probe's own bodies (no slab): the liver alone, without and with the probe, grasp and wall contact
    scene_on = check_scene(scene_with_contact(slab=False)).world.integrators[0]
    liver_model = scene_on.model
    liver_off = copy.copy(liver_model)
    liver_off.probes, liver_off.grasps, liver_off.contacts, liver_off.contact_planes = [], [], [], []
    variants["liver_off"] = (make_integrator("xpbd", liver_off, settings), liver_off)
    variants["liver_on"] = (scene_on, liver_model)
    # the liver resting on the wall (not held): the wall contact does work at every substep
    rest_on = check_scene(scene_with_contact(slab=False, resting=True)).world.integrators[0]
    rest_model = rest_on.model
    rest_off = copy.copy(rest_model)  # falls freely: the same elastic work per step
    rest_off.probes, rest_off.grasps, rest_off.contacts, rest_off.contact_planes = [], [], [], []
    variants["rest_off"] = (make_integrator("xpbd", rest_off, settings), rest_off)
    variants["rest_on"] = (rest_on, rest_model)
    dt = scene.simulation.dt
    steps = 6 if args.quick else round(0.5 / dt)  # the probe's whole path: it reaches the liver at 0.25 s
    rounds = 2 if args.quick else 5
    for integrator, model in variants.values():
        run(integrator, model, 2, dt)  # warm-up: compilation, caches
    seconds = {name: [] for name in variants}
    cpu = {name: [] for name in variants}
    for _ in range(rounds):
        for name, (integrator, model) in variants.items():
            wall, used = run(integrator, model, steps, dt)
            seconds[name].append(wall)
            cpu[name].append(used)
    med = {name: statistics.median(v) for name, v in seconds.items()}
    med_cpu = {name: statistics.median(v) for name, v in cpu.items()}
    on = stepper.integrator
    result = {"seconds_step_off": round(med["off"], 5), "seconds_step_probe": round(med["probe"], 5),
              "seconds_step_on": round(med["on"], 5), "fraction": round((med["on"] - med["off"]) / med["on"], 4),
              "fraction_beyond_probe": round((med["on"] - med["probe"]) / med["on"], 4),
              "cpu_seconds_step_off": round(med_cpu["off"], 5), "cpu_seconds_step_probe": round(med_cpu["probe"], 5),
              "cpu_seconds_step_on": round(med_cpu["on"], 5),
              "cpu_fraction": round((med_cpu["on"] - med_cpu["off"]) / med_cpu["on"], 4),
              "seconds_step_liver_off": round(med["liver_off"], 5), "seconds_step_liver_on": round(med["liver_on"], 5),
              "fraction_liver": round((med["liver_on"] - med["liver_off"]) / med["liver_on"], 4),
              "cpu_fraction_liver": round((med_cpu["liver_on"] - med_cpu["liver_off"]) / med_cpu["liver_on"], 4),
              "seconds_step_rest_off": round(med["rest_off"], 5), "seconds_step_rest_on": round(med["rest_on"], 5),
              "fraction_resting": round((med["rest_on"] - med["rest_off"]) / med["rest_on"], 4),
              "cpu_fraction_resting": round((med_cpu["rest_on"] - med_cpu["rest_off"]) / med_cpu["rest_on"], 4),
              "resting_wall_contacts": int(np.count_nonzero(rest_on.contacts[0].lam_n)),
              "grasped_nodes": int(on.grasps[0].nodes.size) if on.grasps else 0,
              "slab_liver_contacts": int(sum(np.count_nonzero(c.lam_n) for c in on.contacts[:2])),
              "wall_contacts": int(np.count_nonzero(on.contacts[2].lam_n)),
              "nodes": int(on_model.n_nodes), "tets": int(on_model.n_tets), "steps": steps, "rounds": rounds,
              "machine": f"{platform.machine()} {os.cpu_count()} cpus"}
    print(f"liver_probe liver and slab ({on_model.n_nodes} nodes, {on_model.n_tets} tets), {steps} steps of {dt:.4g} s, "
          f"median of {rounds} interleaved rounds:")
    print(f"  without contact and grasp {med['off'] * 1e3:8.2f} ms/step")
    print(f"  probe only (as shipped)   {med['probe'] * 1e3:8.2f} ms/step")
    print(f"  with probe, grasp, contact {med['on'] * 1e3:8.2f} ms/step  ({100 * result['fraction']:.1f} % of the step)")
    print(f"liver_probe's own bodies (liver {liver_model.n_nodes} nodes, no slab): without {med['liver_off'] * 1e3:.2f}, "
          f"with probe, grasp and wall contact {med['liver_on'] * 1e3:.2f} ms/step "
          f"({100 * result['fraction_liver']:.1f} % of the step)")
    print(f"liver_probe's liver resting on the wall (not held): without {med['rest_off'] * 1e3:.2f}, with probe, "
          f"grasp and wall contact {med['rest_on'] * 1e3:.2f} ms/step ({100 * result['fraction_resting']:.1f} % of the "
          f"step, {result['resting_wall_contacts']} nodes on the wall)")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
