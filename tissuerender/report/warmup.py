"""Compile the report's numba kernels in parallel processes before anything is timed.

With an empty numba cache most of a ``--quick`` report is compilation (docs/report.md, "What the first run
costs"), one kernel after another in one process, while the second core waits. :func:`warm_kernels` runs the
report's work at the test suite's "tiny" sweeps (which call every kernel with the signatures of the larger sweeps:
a ``--quick`` report after it compiles nothing) as tasks on a pool of spawned processes, one per core, before the
report starts; each process writes the kernels it compiles to numba's on-disk cache, and the report then loads them.
Nothing they compute is kept, and nothing is timed while they run, so the report's timings are those of an idle
machine as before.

Once done for the current code, numba and CPU, a marker file beside numba's cache of the ``sim`` kernels says so and
later reports skip the warm-up (a warm cache would only repeat the tiny sweeps' own computation). Any change to a
source file changes the marker's name (the code hash the report passes); deleting numba's cache deletes the marker with
it. A task that fails is left to the report itself, which runs the same code and reports the error properly.
"""
from __future__ import annotations

import hashlib
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

# cases the report runs, most compilation first (docs/report.md, "What the first run costs"): the pool hands out
# tasks in this order, so the long ones do not start last; cases not listed go after them
HEAVY_FIRST = ("cylinder_extension", "indentation", "viscoelastic_cube", "liver_variational", "rates",
               "cylinder_compression", "cylinder_buckling")
LEVEL = "tiny"


def tasks(names: list[str], stages: bool) -> list[tuple]:
    """The warm-up's tasks for the report's cases ``names`` (and, with ``stages``, its per-stage costs and rendering
    sweeps): ("stage", scene file), ("render", scene name), ("case", name) and ("unit", case, unit), in the order the
    pool should start them. Renderer and simulation tasks alternate, so the two processes mostly compile different
    kernels rather than the same ones side by side."""
    from tissuerender.report import cases, render_sweeps, stage_costs

    ordered = [n for n in HEAVY_FIRST if n in names] + [n for n in names if n not in HEAVY_FIRST]
    sim = []
    for name in ordered:
        if name in cases.SPLIT:
            units_of = cases.SPLIT[name][0]
            sim += [("unit", name, unit) for unit in units_of(cases.sweep_for(name, LEVEL))]
        else:
            sim.append(("case", name))
    render = []
    if stages:
        render = [("render", n) for n in render_sweeps.SWEEP_SCENES]
        render += [("stage", str(p)) for p in stage_costs.shipped_scenes()]
    out = []
    for i in range(max(len(sim), len(render))):
        out += [group[i] for group in (render, sim) if i < len(group)]
    return out


def run_task(task: tuple) -> tuple[tuple, float, str | None]:
    """One task in a warm-up process: (the task, its wall seconds, the first line of its error or None)."""
    from tissuerender.report import cases, render_sweeps, stage_costs

    t0 = time.perf_counter()
    try:
        kind = task[0]
        if kind == "case":
            cases.run_case(task[1], cases.sweep_for(task[1], LEVEL))
        elif kind == "unit":
            cases.SPLIT[task[1]][2](task[2])
        elif kind == "render":
            render_sweeps.run_render_sweeps(render_sweeps.RENDER_SWEEPS[LEVEL], names=(task[1],))
        elif kind == "stage":
            stage_costs.run_stage_costs(stage_costs.STAGE_SWEEPS[LEVEL], [Path(task[1])])
        else:
            raise ValueError(f"unknown warm-up task {task!r}")
    except Exception as e:  # noqa: BLE001 - the report reruns this code and reports the error itself
        return task, time.perf_counter() - t0, (str(e).splitlines() or [type(e).__name__])[0]
    return task, time.perf_counter() - t0, None


def _child_start(threads: int) -> None:
    # the report's thread count, not one per process: code paths choose kernels by it (a parallel count of inverted
    # tets with more than one thread, a serial one with one), and the warm-up must compile the report's
    import numba

    numba.set_num_threads(threads)


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def marker_path(names: list[str], stages: bool, code: str) -> Path:
    """The file that says the warm-up ran for this code (``code``: a hash of every source file,
    ``accuracy.render_code_hash``), numba, CPU and set of cases, in the folder numba caches the ``sim`` kernels in
    (where ``NUMBA_CACHE_DIR`` or numba's own rules put it)."""
    import llvmlite.binding as llvm
    import numba

    from sim.integrators.xpbd.energy import energy_sweeps

    key = "\n".join([code, numba.__version__, llvm.get_host_cpu_name(),
                     llvm.get_host_cpu_features().flatten(), ",".join(sorted(names)), str(stages)])
    folder = Path(energy_sweeps._cache._cache_path)
    return folder / f"tissuerender-report-warm-{hashlib.sha256(key.encode()).hexdigest()[:20]}"


def warm_kernels(names: list[str], stages: bool, code: str, processes: int | None = None,
                 show=lambda text: None) -> dict:
    """Compile the kernels of the report's cases ``names`` (and its stages; ``code`` as ``marker_path``'s) on
    ``processes`` spawned processes (by default one per usable core; fewer than two: nothing to gain, skipped). Returns what it did: {"skipped": reason}
    or {"processes", "wall_s", "tasks": [[task, wall s, error or None], ...]}."""
    import numba

    processes = usable_cores() if processes is None else processes
    if processes < 2:
        return {"skipped": "one core: compiling beside the report gains nothing"}
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return {"skipped": "NUMBA_DISABLE_JIT is set"}
    marker = marker_path(names, stages, code)
    if marker.is_file():
        return {"skipped": f"kernels already compiled ({marker.name})"}
    todo = tasks(names, stages)
    t0 = time.perf_counter()
    done = []
    pool = ProcessPoolExecutor(max_workers=processes, mp_context=get_context("spawn"), initializer=_child_start,
                               initargs=(numba.get_num_threads(),))
    try:
        futures = [pool.submit(run_task, task) for task in todo]
        for future in as_completed(futures):
            task, wall, error = future.result()
            done.append([list(task), wall, error])
            show(f"compiling kernels ({len(done)}/{len(todo)} tasks, {processes} processes)")
    except BaseException:
        # Ctrl-C or a lost process: stop at once (the pool's own exit would wait for every queued task); what the
        # processes compiled so far stays in the cache
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    if not any(error for _, _, error in done):
        try:
            marker.parent.mkdir(parents=True, exist_ok=True)
            marker.write_text("tissuerender report warm-up done\n")
        except OSError:
            pass  # a read-only cache folder: numba cannot cache there either; the next report compiles again
    return {"processes": processes, "wall_s": time.perf_counter() - t0, "tasks": done}
