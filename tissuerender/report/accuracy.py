"""``tissuerender report accuracy -o DIR [--quick] [--cases a,b]``: what accuracy costs in time, on the
simulation cases of Zhang's thesis (``cases.py``), with the thesis's claims beside ours (``claims.py``).

Writes ``DIR/report.json`` (every number, the sweep settings, package versions, the machine),
``DIR/report.html`` (one self-contained file, ``html.py``) and ``DIR/cases/<case>.json``, each finished
case stored atomically as soon as it is done. A rerun into the same folder reuses a stored case when its
key matches: the case's sweep settings, the package versions and a hash of the source of ``sim/`` and of
this package; any mismatch recomputes it. Reused cases are marked ``"cached": true``.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import time
from pathlib import Path

import numba
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
    TimeRemainingColumn

import sim
from tissuerender.distributed import add_dask_options, dask_client
from tissuerender.errors import UserError
from tissuerender.files import one_writer, output_folder, write_atomic, write_json
from tissuerender.manifest import package_versions
from tissuerender.report import cases as case_runs
from tissuerender.report import scene as scene_report
from tissuerender.report import render_sweeps, stage_costs
from tissuerender.report.claims import CLAIMS, claims_table
from tissuerender.report.html import render_html
from tissuerender.report.warmup import warm_kernels as warmup_kernels
from tissuerender.scene import load_scene

KIND = "tissuerender.report.accuracy"
FORMAT = 1  # bump when the stored case layout changes


def finite_json(value):
    """``value`` with NumPy scalars made Python ones and non-finite floats made None (JSON has no NaN), so
    report.json round-trips to the same dict."""
    if isinstance(value, dict):
        return {str(k): finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def code_hash() -> str:
    """SHA-256 of the source of ``sim/`` and of this package: a stored case is reused only by the same code."""
    h = hashlib.sha256()
    for root in (Path(sim.__file__).parent, Path(__file__).parent):
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def render_code_hash() -> str:
    """SHA-256 of the source of every package a render runs (``tissuerender``, ``sim``, ``postfx``,
    ``materials``): a stored scene sweep or stage cost is reused only by the same code."""
    import materials
    import postfx
    import tissuerender

    h = hashlib.sha256()
    for package in (tissuerender, sim, postfx, materials):
        root = Path(package.__file__).parent
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def machine() -> dict:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {"platform": platform.platform(), "machine": platform.machine(), "processor": platform.processor(),
            "cpus": os.cpu_count(), "numba_threads": numba.get_num_threads(), "load_average_at_start": load}


def parse_cases(text: str | None, quick: bool) -> list[str]:
    """The ``--cases`` list (comma-separated), or the default set; a user error naming any unknown case."""
    if text is None:
        return list(case_runs.QUICK_CASES if quick else case_runs.CASES)
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in case_runs.CASES]
    if unknown or not names:
        raise UserError(f"--cases: unknown case {', '.join(unknown) or '(none given)'}; expected a comma-separated "
                        f"list of {', '.join(case_runs.CASES)}")
    return list(dict.fromkeys(names))


def _stored(path: Path, key: dict) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("kind") == KIND and data.get("key") == key else None


class _Bar:
    """A rich progress bar with the elapsed time and an estimate of the rest, when asked for; it advances per
    swept setting (``cases.work_units``), so the estimate moves within a long case."""

    def __init__(self, enabled: bool, total: int):
        self.progress = None
        if enabled:
            self.progress = Progress(TextColumn("accuracy report {task.description}"), BarColumn(),
                                     MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
            self.progress.start()
            self.task = self.progress.add_task("", total=total)

    def show(self, text: str) -> None:
        if self.progress is not None:
            self.progress.update(self.task, description=text)

    def advance(self, units: int = 1) -> None:
        if self.progress is not None:
            self.progress.advance(self.task, units)

    def close(self) -> None:
        if self.progress is not None:
            self.progress.stop()


def _cached(path: Path, key: dict, compute) -> tuple[dict, bool, float]:
    """The result stored at ``path`` under ``key``, or ``compute()`` stored there: (result, cached, wall s)."""
    stored = _stored(path, key)
    if stored is not None:
        return stored["result"], True, stored["wall_s"]
    t0 = time.perf_counter()
    result = finite_json(compute())
    wall = time.perf_counter() - t0
    write_json(path, {"kind": KIND, "key": key, "wall_s": wall, "result": result})
    return result, False, wall


def run_report(out, quick: bool = False, cases: list[str] | None = None, level: str | None = None,
               progress: bool = False, scene=None, budget: dict | None = None, stages: bool | None = None,
               workers: int | None = None, scheduler: str | None = None, client=None,
               warmup: bool | None = None) -> dict:
    """Run (or reuse) every case, write the JSON and HTML; returns the report dict. ``level`` is the sweep
    size: "full", "quick" (``--quick``) or "tiny" (the test suite's); it defaults from ``quick``. With a
    ``scene`` (``scene.py``) the report is that scene's, and runs the cases only when ``cases`` names them.
    ``stages``: the per-stage costs of the shipped scenes (``stage_costs.py``) and the rendering sweeps
    (``render_sweeps.py``); by default with the default cases. With ``workers`` / ``scheduler`` / ``client``
    the cases to compute run as Dask tasks (docs/dask.md). ``warmup``: first compile the kernels of the cases and
    stages still to compute in one process per core (``warmup.py``); by default at the "quick" and "full" levels, on
    this machine (not with a scheduler or client, whose workers may be elsewhere)."""
    out = output_folder(out)
    level = level or ("quick" if quick else "full")
    names = cases if cases is not None else [] if scene is not None else parse_cases(None, quick)
    versions, code = package_versions(), code_hash()
    render_code = render_code_hash()  # once: cases that build scenes, the stages and the warm-up's marker use it
    results, timings, todo = {}, {}, {}
    units = {name: case_runs.work_units(name, case_runs.sweep_for(name, level)) for name in names}
    scene_sweep = scene_report.SCENE_SWEEPS[level]
    stages = (scene is None and cases is None) if stages is None else stages
    stage_sweep = stage_costs.STAGE_SWEEPS[level]
    shipped = stage_costs.shipped_scenes() if stages else []
    budget = scene_report.parse_budget(None) if budget is None else budget
    render_sweep = render_sweeps.RENDER_SWEEPS[level]
    render_units = render_sweeps.work_units(render_sweep) if stages else 0
    bar = _Bar(progress, sum(units.values()) + (scene_report.work_units(scene, scene_sweep) if scene else 0)
               + len(shipped) + render_units)
    start = time.perf_counter()
    scene_result = costs = sweeps = None
    warmup_done = None
    try:
        if level != "tiny" and scheduler is None and client is None and (warmup is None or warmup):
            cold = [n for n in names if not _all_stored(n, case_runs.sweep_for(n, level), versions,
                                                      render_code, code, out)]
            cold_stages = stages and not (_stored(out / "cases" / "stage_costs.json", _stage_key(
                shipped, stage_sweep, versions, render_code)) and _stored(out / "cases" / "render_sweeps.json", {
                    **_stage_key(shipped, stage_sweep, versions, render_code), "sweep": render_sweep,
                    "part": "render_sweeps"}))
            if cold or cold_stages:
                bar.show("compiling kernels")
                warmup_done = warmup_kernels(cold, cold_stages, render_code, show=bar.show)
        if scene is not None:
            bar.show(scene.name)

            def part(name, compute):
                key = finite_json({"scene": scene.sha256, "part": name, "sweep": scene_sweep, "versions": versions,
                                   "code": render_code, "format": FORMAT})
                result, cached, wall = _cached(out / "cases" / f"scene_{scene.name}_{name}.json", key, compute)
                if cached:
                    bar.advance(scene_report.part_units(scene, scene_sweep, name))
                return {**result, "cached": cached, "computed_wall_s": wall}

            scene_result = scene_report.run_scene_parts(scene, budget, scene_sweep, part, bar.advance)
        on_dask = workers is not None or scheduler is not None or client is not None
        split = {}  # a split case's units: {case: {unit id: (result, cached, wall s)}}
        for name in names:
            bar.show(name)
            sweep = case_runs.sweep_for(name, level)
            # cases that build scenes or render depend on all of tissuerender, not only sim/ and this package
            case_code = render_code if name in case_runs.SCENE_CASES else code
            if name in case_runs.SPLIT:
                split[name] = {}
                for unit, key, path in _split_units(name, sweep, versions, case_code, out):
                    unit_id = case_runs.SPLIT[name][1](unit)
                    if on_dask and _stored(path, key) is None:
                        todo[(name, unit_id)] = ((name, None, unit), key, path, 1)
                        continue
                    split[name][unit_id] = _cached(path, key, lambda: case_runs.SPLIT[name][2](unit))
                    bar.advance(1)
                continue
            key = _case_key(name, sweep, versions, case_code)
            path = out / "cases" / f"{name}.json"
            stored = _stored(path, key)
            if stored is None and on_dask:
                todo[(name, None)] = ((name, sweep, None), key, path, units[name])  # run below, as Dask tasks
                continue
            result, cached, wall = _cached(path, key, lambda: case_runs.run_case(name, sweep, bar.advance))
            if cached:
                bar.advance(units[name])
            results[name] = {**result, "cached": cached, "computed_wall_s": wall}
        if todo:
            for (name, unit_id), (result, wall) in _run_on_dask(todo, bar, workers, scheduler, client).items():
                if unit_id is None:
                    results[name] = {**result, "cached": False, "computed_wall_s": wall}
                else:
                    split[name][unit_id] = (result, False, wall)
        for name, parts in split.items():
            results[name] = _combined(name, case_runs.sweep_for(name, level), parts)
        results = {name: results[name] for name in names}
        timings = {name: results[name]["computed_wall_s"] for name in names}
        if stages:
            bar.show("per-stage costs")
            key = _stage_key(shipped, stage_sweep, versions, render_code)
            result, cached, wall = _cached(out / "cases" / "stage_costs.json", key,
                                           lambda: stage_costs.run_stage_costs(stage_sweep, shipped, bar.advance))
            if cached:
                bar.advance(len(shipped))
            costs = {**result, "cached": cached, "computed_wall_s": wall}
            bar.show("rendering sweeps")
            key = {**key, "sweep": render_sweep, "part": "render_sweeps"}
            result, cached, wall = _cached(out / "cases" / "render_sweeps.json", key,
                                           lambda: render_sweeps.run_render_sweeps(render_sweep, tick=bar.advance))
            if cached:
                bar.advance(render_units)
            sweeps = {**result, "cached": cached, "computed_wall_s": wall}
    finally:
        bar.close()
    report = {"kind": KIND, "format": FORMAT, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "command": "tissuerender report accuracy" + (f" {scene.path}" if scene is not None else "")
              + (" --quick" if quick else "")
              + (f" --cases {','.join(names)}" if cases is not None else ""),
              "level": level, "sweeps": {n: case_runs.sweep_for(n, level) for n in names},
              "versions": versions, "code_sha256": code, "machine": machine(),
              "wall_s": time.perf_counter() - start, "case_wall_s": timings, "warmup": warmup_done,
              "part_wall_s": {**timings, **{name: part["computed_wall_s"] for name, part in
                                            (("stage_costs", costs), ("render_sweeps", sweeps)) if part}},
              "cases": results, "scene": scene_result, "stage_costs": costs, "render_sweeps": sweeps,
              "claims": claims_table({**results, **({"render_sweeps": sweeps} if sweeps else {})}),
              "claims_listed": [c.id for c in CLAIMS],
              "not_covered": NOT_COVERED}
    report = finite_json(report)
    write_json(out / "report.json", report)
    html = render_html(report)
    write_atomic(out / "report.html", lambda tmp: Path(tmp).write_text(html, encoding="utf-8"))
    return report


def _stage_key(shipped: list[Path], sweep: dict, versions: dict, code: str) -> dict:
    """The cache key of the per-stage costs (and, with the rendering sweep and part added, of the sweeps)."""
    return finite_json({"scenes": {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in shipped},
                        "sweep": sweep, "versions": versions, "code": code, "format": FORMAT,
                        "numba_threads": numba.get_num_threads()})


def _all_stored(name: str, sweep: dict, versions: dict, render_code: str, code: str, out: Path) -> bool:
    """Whether case ``name`` (every unit of a split case) is stored in ``out`` under its current key."""
    case_code = render_code if name in case_runs.SCENE_CASES else code
    if name in case_runs.SPLIT:
        return all(_stored(path, key) is not None for _, key, path in _split_units(name, sweep, versions, case_code,
                                                                                   out))
    return _stored(out / "cases" / f"{name}.json", _case_key(name, sweep, versions, case_code)) is not None


def _case_key(name: str, sweep: dict, versions: dict, code: str) -> dict:
    """The cache key of a (not split) case's file ``cases/<case>.json``."""
    return finite_json({"case": name, "sweep": sweep, "versions": versions, "code": code, "format": FORMAT})


def _split_units(name: str, sweep: dict, versions: dict, code: str, out: Path) -> list[tuple[dict, dict, Path]]:
    """A split case's units (``cases.SPLIT``), each with its cache key and file ``cases/<case>/<unit id>.json``. The
    key holds the unit (which carries the settings it runs with), not the whole sweep: a level added to or dropped
    from the sweep leaves the other levels' files valid."""
    units_of, unit_id, _, _ = case_runs.SPLIT[name]
    return [(unit, finite_json({"case": name, "unit": unit, "versions": versions, "code": code, "format": FORMAT}),
             out / "cases" / name / f"{unit_id(unit)}.json") for unit in units_of(sweep)]


def _combined(name: str, sweep: dict, parts: dict[str, tuple[dict, bool, float]]) -> dict:
    """A split case's result from its units' (result, cached, wall s), in the order ``units`` lists them whatever
    the order they finished in: "cached" when every unit was, and each unit's own marker and wall time."""
    units_of, unit_id, _, combine = case_runs.SPLIT[name]
    ids = [unit_id(unit) for unit in units_of(sweep)]
    result = finite_json(combine(sweep, {i: parts[i][0] for i in ids}))
    return {**result, "cached": all(parts[i][1] for i in ids), "computed_wall_s": sum(parts[i][2] for i in ids),
            "units": {i: {"cached": parts[i][1], "computed_wall_s": parts[i][2]} for i in ids}}


def _case_task(name: str, sweep: dict | None, unit: dict | None) -> tuple[dict, float]:
    """One case, or one unit of a split case, as a Dask task: (its result, its wall time on the worker)."""
    t0 = time.perf_counter()
    result = finite_json(case_runs.run_case(name, sweep) if unit is None else case_runs.SPLIT[name][2](unit))
    return result, time.perf_counter() - t0


def _run_on_dask(todo: dict, bar, workers, scheduler, client) -> dict:
    """The tasks of ``todo`` ({(case, unit id or None): ((case, sweep, unit), key, path, bar units)}) on Dask, each
    cached as it completes (a lost worker loses only its unfinished task; rerunning the command reuses the
    others): {(case, unit id or None): (result, wall s)}. Split cases' units go first, most refined first
    (``units``'s order), so the longest solves do not start last. Tasks that run side by side share the machine:
    their wall times are those of a loaded machine."""
    from contextlib import nullcontext

    from distributed import as_completed

    done = {}
    opened = nullcontext(client) if client is not None else dask_client(workers, scheduler, lambda line: None)
    with opened as c:
        futures = {c.submit(_case_task, *args, pure=False, priority=1 if task[1] is not None else 0,
                            key=f"tissuerender-case-{task[0]}-{task[1] or 'all'}-{time.time()!r}"): task
                   for task, (args, _, _, _) in todo.items()}
        for future in as_completed(list(futures)):
            task = futures[future]
            result, wall = future.result()
            _, key, path, units = todo[task]
            write_json(path, {"kind": KIND, "key": key, "wall_s": wall, "result": result})
            done[task] = (result, wall)
            bar.advance(units)
    return done


# what issue 17 asks of the simulation cases that the report does not measure yet
NOT_COVERED: list[str] = []


def _cmd_accuracy(args) -> int:
    names = parse_cases(args.cases, args.quick)
    budget = scene_report.parse_budget(args.budget)
    if args.budget is not None and args.scene is None:
        raise UserError("--budget: applies to a scene's report; name the scene: tissuerender report accuracy "
                        "SCENE -o DIR --budget ...")
    scene = load_scene(args.scene) if args.scene is not None else None
    out = output_folder(args.out)
    with one_writer(out):  # a second report into the folder would take over its cases mid-write
        report = run_report(out, quick=args.quick, cases=names if args.cases else None, progress=not args.quiet,
                            scene=scene, budget=budget, workers=args.workers, scheduler=args.scheduler,
                            warmup=None if args.warmup else False)
    if not args.quiet and scene is not None:
        for part in ("simulation", "rendering"):
            done = report["scene"][part]
            print(f"{scene.name} {part}: " + (f"not measured: {done['skipped']}" if "skipped" in done else
                                              f"cheapest within the budget: {done['cheapest']['text']}"))
    if not args.quiet and (report["cases"] or report["render_sweeps"]):
        verdicts = [row["verdict"] for row in report["claims"]]
        cached = sum(1 for c in report["cases"].values() if c["cached"])
        print(f"wrote {out / 'report.html'} and report.json: {len(report['cases'])} case(s) ({cached} cached), "
              f"claims: {verdicts.count('reproduced')} reproduced, {verdicts.count('not reproduced')} not "
              f"reproduced, {verdicts.count('not comparable')} not comparable")
    elif not args.quiet:
        print(f"wrote {out / 'report.html'} and report.json")
    return 0


def add_cli(subparsers) -> None:
    report = subparsers.add_parser("report", help="accuracy and cost reports")
    sub = report.add_subparsers(dest="report_command", required=True)
    p = sub.add_parser("accuracy", help="error against converged references versus wall time, and the theses' claims")
    p.add_argument("scene", nargs="?", default=None, help="a scene file: report on its own settings (docs/report.md)")
    p.add_argument("-o", "--out", required=True, help="output folder (report.html, report.json, cases/)")
    p.add_argument("--budget", default=None, help="with a scene: error budget, e.g. sim=1%%,flip=0.002[,rmse=0.05]")
    p.add_argument("--quick", action="store_true",
                   help="coarser meshes, fewer settings and cases (under 5 minutes on 2 cores, a first run included)")
    p.add_argument("--cases", default=None, help=f"comma-separated subset of {', '.join(case_runs.CASES)}")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    p.add_argument("--no-warmup", dest="warmup", action="store_false",
                   help="do not compile the kernels in one process per core first (docs/report.md)")
    add_dask_options(p, "cases")
    p.set_defaults(func=_cmd_accuracy)
