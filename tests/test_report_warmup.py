"""The accuracy report's warm-up (``tissuerender.report.warmup``, issue 17 "Speed"): the kernels of the cases still
to compute are compiled in spawned processes, into numba's on-disk cache, before the report times anything.

Each check runs in fresh interpreters with their own ``NUMBA_CACHE_DIR``: a report process after the warm-up
compiles nothing for the case (numba's ``numba:compile`` event fires only for a real compilation, not a cache load),
while the same process against an empty cache does compile (so the count can fail)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

from tissuerender.report import cases, render_sweeps, stage_costs, warmup

CASE = "cnn_cube"  # a case with numba kernels of its own that compiles in seconds

COUNT = f"""
import json, numba.core.event as ev
import tissuerender
from tissuerender.report import cases
n = []
class Count(ev.Listener):
    def on_start(self, event): n.append(1)
    def on_end(self, event): pass
ev.register("numba:compile", Count())
cases.run_case({CASE!r}, cases.sweep_for({CASE!r}, "quick"))
print(json.dumps(len(n)))
"""

WARM = f"""
import json
from tissuerender.report import warmup
from tissuerender.report.accuracy import render_code_hash
if __name__ == "__main__":
    code = render_code_hash()
    first = warmup.warm_kernels([{CASE!r}], False, code, processes=2)
    second = warmup.warm_kernels([{CASE!r}], False, code, processes=2)
    print(json.dumps([first, second, str(warmup.marker_path([{CASE!r}], False, code))]))
"""


def _run(code: str, cache) -> object:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_after_the_warmup_the_report_process_compiles_nothing(tmp_path):
    cold = _run(COUNT, tmp_path / "empty")
    assert cold > 0  # the case does compile kernels of its own

    first, second, marker = _run(WARM, tmp_path / "warm")
    assert first["processes"] == 2
    assert [task for task, _, _ in first["tasks"]] == [["case", CASE]]
    assert [error for _, _, error in first["tasks"]] == [None]
    assert os.path.isfile(marker) and marker.startswith(str(tmp_path / "warm"))
    assert "already compiled" in second["skipped"]  # the marker: a warm cache is not warmed again

    assert _run(COUNT, tmp_path / "warm") == 0


def test_tasks_cover_every_case_unit_and_scene_alternating():
    names = list(cases.QUICK_CASES)
    todo = warmup.tasks(names, stages=True)
    assert len(todo) == len(set(map(repr, todo)))
    split = [n for n in names if n in cases.SPLIT]
    assert {t[1] for t in todo if t[0] == "case"} == set(names) - set(split)
    for name in split:
        units = cases.SPLIT[name][0](cases.sweep_for(name, warmup.LEVEL))
        assert [t[2] for t in todo if t[0] == "unit" and t[1] == name] == units
    assert [t[1] for t in todo if t[0] == "render"] == list(render_sweeps.SWEEP_SCENES)
    assert sorted(t[1] for t in todo if t[0] == "stage") == sorted(map(str, stage_costs.shipped_scenes()))
    kinds = ["render" if t[0] in ("render", "stage") else "sim" for t in todo]
    assert kinds[:6] == ["render", "sim"] * 3  # the two processes start on different kernels
    assert todo[1] == ("case", warmup.HEAVY_FIRST[0])
    assert warmup.tasks(names, stages=False) == [t for t in todo if t[0] in ("case", "unit")]


def test_one_core_is_skipped():
    assert "one core" in warmup.warm_kernels(["msd"], False, "code", processes=1)["skipped"]


def test_the_report_warms_only_what_it_still_has_to_compute(tmp_path):
    from tissuerender.report import accuracy

    first = accuracy.run_report(tmp_path, cases=[CASE], level="quick", stages=False)
    done = first["warmup"]
    assert done.get("skipped", "").startswith("kernels already compiled") or \
        [task for task, _, _ in done["tasks"]] == [["case", CASE]]
    assert first["cases"][CASE]["cached"] is False
    again = accuracy.run_report(tmp_path, cases=[CASE], level="quick", stages=False)
    assert again["cases"][CASE]["cached"] is True and again["warmup"] is None  # nothing left to compile
    assert accuracy.run_report(tmp_path, cases=[CASE], level="quick", stages=False, warmup=False)["warmup"] is None


def test_ctrl_c_stops_the_warmup_and_its_processes_at_once(tmp_path):
    """SIGINT to the process group (Ctrl-C in a terminal) while the pool compiles: the command ends within seconds
    (the pool's own exit would wait for every queued task) and no process of the group is left."""
    import signal
    import time

    code = ("from tissuerender.report import warmup\nif __name__ == '__main__':\n"
            "    warmup.warm_kernels(['cylinder_extension', 'viscoelastic_cube', 'rates'], False, 'code', processes=2)\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    run = subprocess.Popen([sys.executable, "-c", code], env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    time.sleep(10)  # imports, then the two processes start compiling (the three cases take minutes cold)
    assert run.poll() is None
    os.killpg(run.pid, signal.SIGINT)
    t0 = time.perf_counter()
    _, err = run.communicate(timeout=60)
    assert time.perf_counter() - t0 < 10, err[-2000:]
    assert run.returncode != 0 and "KeyboardInterrupt" in err
    left = True
    for _ in range(50):  # the terminated processes and multiprocessing's resource tracker exit within moments
        try:
            os.killpg(run.pid, 0)
        except ProcessLookupError:
            left = False
            break
        time.sleep(0.1)
    assert not left, subprocess.run(["ps", "-o", "pid,stat,cmd", "-g", str(run.pid)], capture_output=True,
                                    text=True).stdout
