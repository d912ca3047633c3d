"""A render's frames as Dask tasks (``tissuerender render SCENE --workers N`` or ``--scheduler ADDR``).

The client (this process) runs the simulation once and writes every frame's state to ``OUT/states``
(``tissuerender.states``); each remaining frame is then one task, ``render_frame_task``, which rebuilds the
scene's bodies once per worker, loads its frame's state (and the previous one for the velocity channel) and
renders and writes the frame's files through ``pipeline.render_frame_files``, exactly as the serial loop does,
so the files are byte-identical. The client records each frame in ``manifest.json`` as its task completes, so
a worker lost mid-render loses only the frames it had not finished; Dask reruns them on the other workers,
and ``--resume`` completes whatever a failed run left (reusing the states when all exist for this scene file).
See docs/dask.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import pickle
import threading
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np

from tissuerender import pipeline
from tissuerender.errors import UserError
from tissuerender.files import one_writer, output_folder, remove_temporaries
from tissuerender.manifest import frame_ranges
from tissuerender.plan import make_plan
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder
from tissuerender.states import apply_state, read_state, states_complete, write_state
from tissuerender.world import advance, build_world


def add_dask_options(p: argparse.ArgumentParser, what: str) -> None:
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help=f"render the {what} as Dask tasks on a local cluster of N worker processes (docs/dask.md)")
    where.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                       help=f"render the {what} as Dask tasks on the cluster of this scheduler (docs/dask.md)")


def worker_threads(n_workers: int, cpus: int | None = None) -> int:
    """Numba threads per local worker: the machine's cores shared out, so N workers never run more numba
    threads than there are cores (at least one each)."""
    return max(1, (cpus or os.cpu_count() or 1) // max(1, n_workers))


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, announce=print):
    """A ``distributed.Client``: on a new ``LocalCluster`` of ``workers`` single-threaded worker processes,
    or connected to the scheduler at ``scheduler``. Closes what it started."""
    import dask
    from distributed import Client, LocalCluster

    cluster = None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as e:
            raise UserError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler there ({e})") from None
    else:
        threads = worker_threads(workers)
        # NUMBA_NUM_THREADS is read when numba is imported: set before each worker process starts (a spawned
        # process imports the parent's __main__, and with it numba, before the nanny's ``env`` applies).
        # MALLOC_TRIM_THRESHOLD_ (Dask's default 65536) is dropped: any glibc threshold set by the environment
        # turns off glibc's adaptive mmap threshold, so every NumPy temporary over 128 KB is mmap'ed and
        # unmapped again; a 640x480 frame then takes 12x the page faults and +45 % CPU (docs/dask.md, "Per-frame
        # overhead"). None unsets a key (distributed.nanny._get_env_variables); a value in our own environment
        # is still passed on.
        spawn_env = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), "MALLOC_TRIM_THRESHOLD_": None,
                     "NUMBA_NUM_THREADS": str(threads)}
        with dask.config.set({"distributed.nanny.pre-spawn-environ": spawn_env}):
            saved = dict(os.environ)
            try:
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                                       env={"NUMBA_NUM_THREADS": str(threads)}, silence_logs=logging.ERROR)
            finally:  # the nanny sets them in this process's environment too: put it back as it was
                for name in set(os.environ) - set(saved):
                    del os.environ[name]
                os.environ.update(saved)
        client = Client(cluster)
    try:
        n = len(client.scheduler_info().get("workers", {}))
        announce(f"dask: {n} worker(s) at {client.scheduler.address}; dashboard: {dashboard(client)}")
        yield client
    finally:
        client.close()
        if cluster is not None:
            # its nannies warn when a busy worker takes over 4 s to stop and is killed: expected at shut-down
            nanny_log = logging.getLogger("distributed.nanny")
            level = nanny_log.level
            nanny_log.setLevel(logging.ERROR)
            try:
                cluster.close(timeout=30)
            except TimeoutError:  # the render's files are complete; only the shut-down was slow
                announce("dask: the local cluster took over 30 s to stop; its worker processes were killed")
            finally:
                nanny_log.setLevel(level)


def dashboard(client) -> str:
    """The dashboard's address, or why there is none (it needs bokeh, an optional package)."""
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return "not served (pip install 'bokeh>=3.1' to get one)"
    return client.dashboard_link


# Per worker thread: the bodies of the scene it last rendered, so a worker builds them once per scene, not once
# per frame; thread-local because a frame task sets the world's states (a worker may run several threads).
_worlds = threading.local()


def _world_for(scene: Scene, recorder: StageRecorder):
    key = pickle.dumps(scene)  # the whole scene (a few KB), not just its file's sha256: an API caller may vary it
    if getattr(_worlds, "key", None) != key:
        plan = make_plan(scene)
        _worlds.key, _worlds.value = key, (plan, build_world(scene, plan, recorder))
    return _worlds.value


def _written_since(path: Path, since: float) -> bool:
    try:
        return path.stat().st_mtime >= since
    except FileNotFoundError:
        return False


def render_frame_task(scene: Scene, out: str, k: int, run_start: float, numba_threads: int | None = None) -> dict:
    """Render frame ``k`` of ``scene`` into ``out`` from its state file and write its files (a Dask task).

    Returns what the client records: the files, the post-effects backend and the stage timings; or
    ``{"error": message}`` for a user error (the client reports it as the serial render would). A frame whose
    files all exist and were written since ``run_start`` (the run's start) was finished by an attempt whose
    result was lost with its worker: it is not written again."""
    if numba_threads:
        import numba

        numba.set_num_threads(min(numba_threads, numba.config.NUMBA_NUM_THREADS))
    out = Path(out)
    recorder = StageRecorder()
    try:
        plan, world = _world_for(scene, recorder)
        files = pipeline._frame_files(out, k, plan, world)
        if files and all(_written_since(p, run_start) for p in files):
            return {"frame": k, "written": [str(p) for p in files], "backend": None, "calls": {}, "seconds": {},
                    "again": True}
        previous = None
        if "simulate" in plan:
            with recorder.run("read_state"):
                apply_state(world, read_state(out, k, scene, len(world.bodies)))
                wants_previous = "velocity_channel" in plan and k > 1
                before = read_state(out, k - 1, scene, len(world.bodies)) if wants_previous else None
            if before is not None:
                previous = {body.spec.name: body.surface_points(x) for body, x in zip(world.bodies, before.x)}
        written, _, backend = pipeline.render_frame_files(out, k, world, scene, plan, recorder, previous)
    except UserError as e:  # returned, not raised: the client need not unpickle the exception's own class
        return {"frame": k, "error": str(e)}
    return {"frame": k, "written": [str(p) for p in written], "backend": backend, "calls": recorder.calls,
            "seconds": recorder.seconds, "again": False}


def _ensure_states(seq: pipeline.Sequence, resume: bool) -> str:
    """Write ``OUT/states`` for frames 1 ... n (the simulation run once, here); a resumed render reuses them
    when every one exists and comes from this scene file. Returns what happened, for the manifest."""
    if "simulate" not in seq.plan:
        return "not simulated"
    if resume and states_complete(seq.out, seq.scene, seq.n_frames):
        if seq.tool_forces is not None:  # the forces the simulation found, kept in the states
            for k in range(1, seq.n_frames + 1):
                state = read_state(seq.out, k, seq.scene, len(seq.world.bodies))
                seq.tool_forces.rows[k] = (state.t, np.array(state.tool_loads, dtype=np.float64))
            seq.tool_forces.write(seq.out)
        return "reused"
    for k in range(1, seq.n_frames + 1):
        if k > 1:
            advance(seq.world, seq.scene, seq.recorder)
        if seq.tool_forces is not None:
            seq.tool_forces.record(k, (k - 1) / seq.scene.output.fps, seq.world)
            seq.tool_forces.write(seq.out)
        with seq.recorder.run("write_state"):
            write_state(seq.out, k, seq.world, seq.scene)
    return "simulated"


def _merge(recorder: StageRecorder, calls: dict, seconds: dict) -> None:
    for name, n in calls.items():
        recorder.calls[name] = recorder.calls.get(name, 0) + n
        recorder.seconds[name] = recorder.seconds.get(name, 0.0) + seconds.get(name, 0.0)


def render_distributed(scene: Scene, out_dir, resume: bool = False, progress: bool = True, frames: int | None = None,
                       workers: int | None = None, scheduler: str | None = None, client=None, on_frame=None,
                       announce=print) -> pipeline.RunResult:
    """``pipeline.render`` with the frames rendered as Dask tasks: on ``client`` when given, else on a new
    local cluster of ``workers`` processes or the scheduler at ``scheduler``. ``on_frame(k, client)`` is called
    after frame ``k`` is recorded. A frame that cannot be rendered because its workers died is reported, after
    every other frame is finished, as a UserError naming the missing frames (``--resume`` renders them). The only
    client writing into the folder (``files.one_writer``)."""
    with one_writer(output_folder(out_dir)):
        return _render_distributed(scene, out_dir, resume, progress, frames, workers, scheduler, client, on_frame,
                                   announce)


def _render_distributed(scene, out_dir, resume, progress, frames, workers, scheduler, client, on_frame,
                        announce) -> pipeline.RunResult:
    run_start = time.time()
    cutting = [i for i, t in enumerate(scene.tools) if t.cut]
    if cutting:  # a frame task rebuilds the world from a state file, which holds positions, not the cut topology
        raise UserError(f"{scene.path}: tools[{cutting[0]}].cut: frames rendered as Dask tasks (--workers, --scheduler) "
                        "do not follow a cut yet; render this scene without them")
    seq = pipeline.start_sequence(scene, out_dir, resume, frames)
    seq.extra = {"executor": {"kind": "dask", "scheduler": scheduler or ("client" if client else "local"),
                              "workers": workers}}
    seq.extra["states"] = _ensure_states(seq, resume)
    seq.skipped = [seq.out / pipeline.frame_name(k) for k in range(1, seq.n_frames + 1) if k in seq.done]
    todo = [k for k in range(1, seq.n_frames + 1) if k not in seq.done]
    threads = worker_threads(workers) if workers else None
    bar = pipeline._progress(progress, seq.n_frames, scene.name)
    for _ in seq.skipped:
        bar.advance()
    missing: dict[int, str] = {}
    futures = []
    opened = nullcontext(client) if client is not None else dask_client(workers, scheduler, announce)
    try:
        with opened as c:
            from distributed import as_completed

            # absolute paths: a worker's working folder is not the client's (on a cluster, not even its machine)
            task_scene = dataclasses.replace(scene, path=scene.path.resolve())
            futures = [c.submit(render_frame_task, task_scene, str(seq.out.resolve()), k, run_start, threads,
                                pure=False, key=f"tissuerender-frame-{k:04d}-{os.getpid()}-{run_start!r}")
                       for k in todo]
            frame_of = {future.key: k for future, k in zip(futures, todo)}
            for future in as_completed(futures):
                k = frame_of[future.key]
                try:
                    result = future.result()
                except Exception as e:  # KilledWorker, a worker's crash: the frame is reported missing
                    missing[k] = f"{type(e).__name__}: {e}"
                    continue
                finally:
                    future.release()  # its result is here: the scheduler need not keep it (nor recompute it)
                if "error" in result:
                    raise UserError(result["error"])
                _merge(seq.recorder, result["calls"], result["seconds"])
                seq.frame_finished(k, [Path(p) for p in result["written"]], result["backend"])
                bar.advance()
                if on_frame is not None:
                    on_frame(k, c)
            futures = []
    except BaseException:
        for future in futures:
            future.cancel()
        remove_temporaries(seq.out)  # a local cluster's workers are gone; the folder keeps only complete files
        raise
    finally:
        bar.close()
    # every task has ended: a temporary left in the folder is a killed worker's, whose writer will never finish it
    remove_temporaries(seq.out)
    if (seq.out / "passes").is_dir():
        remove_temporaries(seq.out / "passes")
    if missing:
        seq.record({"complete": False})
        first = missing[min(missing)]
        raise UserError(f"{seq.out}: frames {frame_ranges(set(missing))} were not rendered (their workers were "
                        f"lost: {first}); the other frames are finished; rerun with --resume to render the rest")
    return pipeline.finish_sequence(seq)
