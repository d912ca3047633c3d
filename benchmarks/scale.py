"""Frames per second of a sequence rendered serially against two local Dask workers, and the per-frame
overhead of the Dask path (task, transfer, state files) as a fraction of a frame's render time.

Usage: .venv/bin/python benchmarks/scale.py [--quick]
Scene: scenes/liver_probe.toml (xpbd, a probe, 640x480), 48 frames; --quick: 6 frames at 160x120;
--overhead-only: only ``dask_overhead_fraction`` (and its walls), at the chosen resolution.
- ``fps_serial``: ``tissuerender render`` in one process with every core's numba threads;
  ``fps_dask_2``: ``render --workers 2`` (one numba thread per worker), cluster started and workers warmed
  (first frame compiled / loaded from the numba cache) before timing, the simulation included in both.
- ``dask_overhead_fraction``: frame by frame, in interleaved rounds (serial frame k, Dask frame k, serial
  frame k + 1, ...), one numba thread on both sides: the serial frame is ``pipeline.render_frame_files`` on
  the client's world put in frame k's state; the Dask frame is a ``render_frame_task`` submitted to a
  one-worker local cluster and waited for (task pickling, scheduling, the worker reading the state file,
  rendering, writing, the result's transfer), plus the client's ``write_state`` of that frame. The figure is
  the median over the frames of dask / serial - 1: what the Dask path adds to a frame, robust to a machine
  whose load changes during the run (each pair runs back to back).
- ``state_bytes_per_frame`` (the .npz on disk), ``task_bytes`` (pickled task: the scene and four scalars)
  and ``result_bytes`` (pickled result: file names and stage timings): what moves per frame (docs/dask.md).
Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pickle
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

# benchmarks/postfx.py would shadow the postfx package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

import numba  # noqa: E402

from tissuerender import load_scene, pipeline, render  # noqa: E402
from tissuerender.distributed import dask_client, render_distributed, render_frame_task  # noqa: E402
from tissuerender.stages import StageRecorder  # noqa: E402
from tissuerender.states import apply_state, read_state, write_state  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "liver_probe.toml"


def benchmark_scene(frames: int, resolution: list[int]):
    scene = load_scene(SCENE)
    return dataclasses.replace(scene, output=scene.output.model_copy(update={"frames": frames,
                                                                             "resolution": resolution}))


def _timed(function) -> float:
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def overhead_rounds(scene, root: Path, frames: int, rounds: int) -> dict:
    """Per-frame walls of the serial path and the Dask path, interleaved (see the module docstring)."""
    states = root / "overhead_states"
    with dask_client(1, announce=lambda line: None) as client:
        render_distributed(scene, states, progress=False, client=client)  # the states, and a warm worker
        seq = pipeline.start_sequence(scene, root / "overhead_serial")
        world, plan = seq.world, seq.plan
        task_scene = dataclasses.replace(scene, path=scene.path.resolve())
        serial, dask_path = [], []
        for _ in range(rounds):
            for k in range(1, frames + 1):
                state = read_state(states, k, scene, len(world.bodies))
                apply_state(world, state)
                serial.append(_timed(lambda: pipeline.render_frame_files(seq.out, k, world, scene, plan,
                                                                         StageRecorder())))
                write = _timed(lambda: write_state(root / "overhead_written", k, world, scene))
                future = [None]
                wall = _timed(lambda: future.__setitem__(0, client.submit(
                    render_frame_task, task_scene, str(states.resolve()), k, time.time(), 1, pure=False).result()))
                if "error" in future[0] or future[0]["again"]:
                    raise RuntimeError(f"frame {k}: the task did not render ({future[0]})")
                dask_path.append(wall + write)
    ratios = [d / s for d, s in zip(dask_path, serial)]
    return {"dask_overhead_fraction": round(statistics.median(ratios) - 1.0, 4),
            "overhead_rounds": rounds, "overhead_frames": frames,
            "serial_frame_s_median": round(statistics.median(serial), 4),
            "dask_frame_s_median": round(statistics.median(dask_path), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="6 frames at 160x120")
    parser.add_argument("--overhead-only", action="store_true", help="only the per-frame Dask overhead")
    args = parser.parse_args()
    frames, resolution = (6, [160, 120]) if args.quick else (48, [640, 480])
    scene = benchmark_scene(frames, resolution)
    warm = benchmark_scene(1, resolution)
    result: dict = {"frames": frames, "resolution": resolution}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        render(warm, root / "warm", progress=False)  # compile / load the kernels in this process
        threads = numba.config.NUMBA_NUM_THREADS
        numba.set_num_threads(1)
        overhead_frames = 3 if args.quick else 8
        result.update(overhead_rounds(benchmark_scene(overhead_frames, resolution), root, overhead_frames,
                                      2 if args.quick else 3))
        if args.overhead_only:
            print(json.dumps(result))
            return
        numba.set_num_threads(threads)
        serial = _timed(lambda: render(scene, root / "serial", progress=False))
        with dask_client(2, announce=lambda line: None) as client:
            # every worker renders a frame of the same scene before timing (imports, numba cache, the
            # bodies built once per worker): one warm-up task pinned to each worker
            render_distributed(warm, root / "states2", progress=False, client=client)
            client.gather([client.submit(render_frame_task, scene, str(root / "states2"), 1, time.time(),
                                         None, workers=[address], allow_other_workers=False, pure=False)
                           for address in client.scheduler_info()["workers"]])
            wall = _timed(lambda: render_distributed(scene, root / "dask2", progress=False, client=client))
        result.update(fps_dask_2=round(frames / wall, 3), wall_dask_2_s=round(wall, 3),
                      fps_serial=round(frames / serial, 3), wall_serial_s=round(serial, 3),
                      serial_numba_threads=threads)
        result["speedup_2_workers"] = round(serial / result["wall_dask_2_s"], 3)
        states = sorted((root / "dask2" / "states").glob("state_*.npz"))
        result["state_bytes_per_frame"] = round(sum(p.stat().st_size for p in states) / len(states))
        result["task_bytes"] = len(pickle.dumps((scene, str(root / "dask2"), 1, time.time(), 1)))
        manifest = json.loads((root / "dask2" / "manifest.json").read_text())
        example = {"frame": 1, "written": [str(root / "dask2" / "frame_0001.png")], "backend": "numpy",
                   "calls": {k: v["calls"] for k, v in manifest["executed"].items()},
                   "seconds": {k: v["seconds"] for k, v in manifest["executed"].items()}, "again": False}
        result["result_bytes"] = len(pickle.dumps(example))
        for name in ("write_state", "read_state"):  # the state files' share of the Dask path, per frame
            result[f"{name}_s_per_frame"] = round(manifest["executed"][name]["seconds"] / frames, 4)
        render_stages = sum(v["seconds"] for k, v in manifest["executed"].items()
                            if k not in ("simulate", "write_state", "read_state", "mesh", "load_surface"))
        result["render_s_per_frame_dask_2"] = round(render_stages / frames, 4)
    result["machine"] = f"{platform.machine()} {os.cpu_count()} cpus"
    print(f"serial {result['fps_serial']} fps, 2 workers {result['fps_dask_2']} fps; Dask overhead "
          f"{100 * result['dask_overhead_fraction']:.1f} % of a frame; state {result['state_bytes_per_frame']} B/frame")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
