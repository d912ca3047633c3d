"""What a cut costs (issue 21, "Performance": a cut's topology update on a 30k-tet body takes at most one frame's
simulation time).

The body: a clamped 20 x 10 x 5 cm box of 40 x 25 x 5 cells (30,000 tets), liver-like (E = 4.6 kPa, nu = 0.47), XPBD
with the scene defaults (dt = 1/72 s, 10 substeps, 10 iterations; 3 steps per frame at 24 fps). Three timings:

- ``frame``: one frame's simulation (3 steps), nothing cut;
- ``update``: one cut's whole topology update, a capsule blade (radius 1 mm) swept in one substep through the full
  depth across the body's width (about 1,000 tets removed at once): the blade test over every tet, the removal
  with the manifold rule and the masses summed again, XPBD's constraints updated and the per-tet data filtered
  (``sim.integrators.xpbd.removal``) and the render surfaces built (``sim.cutting.surface.cut_surfaces``);
- ``cutting_frame``: one frame's simulation while a blade is drawn across the body during it (tets removed in most
  substeps, each removal followed by the update above, less the surface, which the renderer builds once a frame).

The variants run in interleaved rounds (frame, update, cutting_frame, frame, ...) after a warm-up of each, on a
fresh body each round (its construction not timed), so a machine that slows down or speeds up affects all alike;
figures are medians over the rounds. ``--quick``: a 6,000-tet body and two rounds, to check the script works.

Usage: .venv/bin/python benchmarks/cut_cost.py [--quick] [--rounds N]
Last line: one JSON object with ``tets``, ``seconds_frame``, ``seconds_update``, ``seconds_cutting_frame``,
``tets_removed_update``, ``ratio_update`` (update / frame: the issue's figure, at most 1), ``ratio_cutting_frame``
(the medians' ratio) and ``ratio_cutting_frame_rounds`` (the median of each round's cutting frame / frame: on a
machine whose speed drifts, the steadier figure).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numba  # noqa: E402
import numpy as np  # noqa: E402

from sim.cutting import Cut  # noqa: E402
from sim.cutting.surface import cut_surfaces  # noqa: E402
from sim.integrators.xpbd.solver import XPBD  # noqa: E402
from sim.mesh import procedural  # noqa: E402
from sim.model import Model, State  # noqa: E402
from sim.probe import Probe  # noqa: E402

SIZE = (0.2, 0.1, 0.05)
DT, STEPS_PER_FRAME = 1.0 / 72.0, 3


def body(cells, blade: Probe | None, t_start: float, t_end: float):
    """A fresh clamped box with a blade (or none) cutting from ``t_start`` to ``t_end``: (model, integrator, state)."""
    mesh = procedural.box(SIZE, cells)
    model = Model.from_mesh(mesh, E=4600.0, nu=0.47, density=1060.0, gravity=np.array([0.0, 0.0, -9.81]))
    model.fixed[mesh.points[:, 2] < 1e-9] = True
    model.probes = [] if blade is None else [blade]
    model.cuts = [] if blade is None else [Cut(probe=0, t_start=t_start, t_end=t_end)]
    integrator = XPBD(model, {"substeps": 10, "iterations": 10})
    return model, integrator, State.at_rest(model)


def blade(y0: float, y1: float, duration: float) -> Probe:
    """A 1 mm capsule along z through the whole depth at x = 10.1 cm, drawn from y0 to y1 over ``duration``."""
    return Probe(kind="capsule", radius=0.001, times=[0.0, duration],
                 positions=[[0.101, y0, 0.025], [0.101, y1, 0.025]], axis=[0.0, 0.0, 1.0], length=0.1)


def simulate_frame(integrator, state) -> float:
    start = time.perf_counter()
    for j in range(STEPS_PER_FRAME):
        state.t = j * DT
        state = integrator.step(state, DT)
    return time.perf_counter() - start


def one_update(cells) -> tuple[float, int]:
    """A blade swept across the whole width within the first substep: the update's wall time and tets removed."""
    h = DT / 10
    model, integrator, state = body(cells, blade(-0.01, 0.11, h), 0.0, h)
    cutter = integrator.cutter
    start = time.perf_counter()
    removed = cutter.sweep(state.x, 0.0, h)
    integrator.removal.remove(removed)
    integrator.removal.compact()
    cut_surfaces(cutter.topology, model.X, "box")
    return time.perf_counter() - start, int(removed.size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="6,000 tets and two rounds: check the script works")
    parser.add_argument("--rounds", type=int, default=None, help="timed rounds (default 5; 2 with --quick)")
    args = parser.parse_args()
    cells = (20, 10, 5) if args.quick else (40, 25, 5)
    rounds = args.rounds if args.rounds is not None else 2 if args.quick else 5
    frame_s, update_s, cutting_s, removed = [], [], [], 0
    for r in range(rounds + 1):  # round 0 warms up (compiles, caches)
        _, integrator, state = body(cells, None, 0.0, 0.0)
        t_frame = simulate_frame(integrator, state)
        t_update, removed = one_update(cells)
        _, integrator, state = body(cells, blade(-0.01, 0.11, STEPS_PER_FRAME * DT), 0.0, 1.0)
        t_cutting = simulate_frame(integrator, state)
        if r:
            frame_s.append(t_frame)
            update_s.append(t_update)
            cutting_s.append(t_cutting)
        print(f"round {r}: frame {t_frame:.3f} s, update {t_update:.3f} s ({removed} tets), "
              f"cutting frame {t_cutting:.3f} s", flush=True)
    frame, update, cutting = (statistics.median(v) for v in (frame_s, update_s, cutting_s))
    print(json.dumps({"tets": int(6 * np.prod(cells)), "rounds": rounds, "seconds_frame": frame,
                      "seconds_update": update, "seconds_cutting_frame": cutting, "tets_removed_update": removed,
                      "ratio_update": update / frame, "ratio_cutting_frame": cutting / frame,
                      "ratio_cutting_frame_rounds": statistics.median(c / f for c, f in zip(cutting_s, frame_s)),
                      "numba_threads": numba.get_num_threads(), "machine": platform.machine()}))


if __name__ == "__main__":
    main()
