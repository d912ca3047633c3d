"""Render a batch: every sequence's resolved scene into ``DIR/seq_NNNN/`` (scene.toml, its frames and
manifest.json) and the batch manifest ``DIR/batch.json``, rewritten as each sequence finishes. Sequences
render serially in this process, or each as one Dask task (``--workers`` / ``--scheduler``). ``--resume``
keeps the sequences whose manifests say complete and resumes the others frame by frame
(``pipeline.render(resume=True)``). A sequence that fails (a user error: a randomised material the integrator
cannot simulate) is recorded with its message; the others go on, and the batch exits 2 naming it."""
from __future__ import annotations

import json
import time
from contextlib import nullcontext
from pathlib import Path

from tissuerender import pipeline
from tissuerender.batch.resolve import scene_text, sequence_name
from tissuerender.batch.spec import BatchSpec
from tissuerender.errors import UserError
from tissuerender.files import output_folder, write_atomic, write_json
from tissuerender.manifest import KIND as RENDER_KIND
from tissuerender.plan import make_plan
from tissuerender.scene import load_scene

KIND = "tissuerender.batch"


def render_sequence_task(scene_path: str, resume: bool, numba_threads: int | None = None) -> dict:
    """Render one sequence (a Dask task, or called in this process): its scene file's frames into its folder."""
    if numba_threads:
        import numba

        numba.set_num_threads(min(numba_threads, numba.config.NUMBA_NUM_THREADS))
    try:
        scene = load_scene(scene_path)
        result = pipeline.render(scene, Path(scene_path).parent, resume=resume, progress=False)
    except UserError as e:
        return {"error": str(e)}
    return {"frames_done": result.manifest["frames_done"], "complete": result.manifest["complete"]}


def _finished(folder: Path, scene) -> bool:
    """Whether the sequence's manifest says this scene's render finished every frame and every frame's files
    exist (otherwise ``render --resume`` completes it)."""
    try:
        data = json.loads((folder / "manifest.json").read_text())
    except (OSError, ValueError):
        return False
    if not (isinstance(data, dict) and data.get("kind") == RENDER_KIND and data.get("complete") is True
            and data.get("scene_sha256") == scene.sha256 and data.get("frames_done") == scene.output.frames):
        return False
    plan = make_plan(scene)
    bodies = [o.name for o in scene.objects if o.kind == "body"]
    return all(p.exists() for k in range(1, scene.output.frames + 1)
               for p in pipeline.frame_files(folder, k, plan, bodies))


def _check_resumable(path: Path, spec: BatchSpec) -> None:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return
    except (OSError, ValueError) as e:
        raise UserError(f"{path}: --resume: cannot read the batch manifest ({e})") from None
    if not isinstance(data, dict) or data.get("kind") != KIND:
        raise UserError(f"{path}: --resume: not a tissuerender batch manifest (expected \"kind\": \"{KIND}\")")
    if data.get("spec_sha256") != spec.sha256:
        raise UserError(f"{path}: --resume refused: the batch was made from another version of {spec.path}; "
                        "run without --resume to start over, or into another folder")


def run_batch(spec: BatchSpec, out_dir, resume: bool = False, progress: bool = True, workers: int | None = None,
              scheduler: str | None = None, client=None, announce=print) -> dict:
    """Make and render every sequence of ``spec`` in ``out_dir``; returns the batch manifest (also written to
    ``batch.json``). A UserError after the others finish when a sequence failed."""
    start = time.perf_counter()
    out = output_folder(out_dir).resolve()  # absolute: Dask workers may run in another folder
    if resume:
        _check_resumable(out / "batch.json", spec)
    entries, scenes = [], []
    for i in range(spec.batch.sequences):
        folder = out / sequence_name(i)
        path = folder / "scene.toml"
        text = scene_text(spec, i)
        if not (path.is_file() and path.read_text() == text):  # a resumed batch keeps its identical scene files
            write_atomic(path, lambda tmp, text=text: Path(tmp).write_text(text))
        scene = load_scene(path)
        scenes.append(scene)
        done = resume and _finished(folder, scene)
        entries.append({"index": i, "folder": folder.name, "scene_sha256": scene.sha256, "seed": scene.seed,
                        "frames": scene.output.frames, "status": "complete" if done else "pending"})

    def record() -> dict:
        data = {"kind": KIND, "spec": str(spec.path), "spec_sha256": spec.sha256, "base_scene": str(spec.base.path),
                "seed": spec.batch.seed, "sequences_total": len(entries),
                "sequences_complete": sum(e["status"] == "complete" for e in entries),
                "complete": all(e["status"] == "complete" for e in entries),
                "wall_seconds": round(time.perf_counter() - start, 3), "sequences": entries}
        write_json(out / "batch.json", data)
        return data

    record()
    bar = pipeline._progress(progress, sum(e["frames"] for e in entries), f"batch {spec.path.name}")
    for e in entries:
        if e["status"] == "complete":
            for _ in range(e["frames"]):
                bar.advance()
    pending = [e for e in entries if e["status"] != "complete"]

    def finished(entry: dict, result: dict) -> None:
        entry["status"] = "failed" if "error" in result else "complete"
        if "error" in result:
            entry["error"] = result["error"]
        record()

    try:
        if workers is None and scheduler is None and client is None:
            for e in pending:
                scene = scenes[e["index"]]
                try:
                    pipeline.render(scene, out / e["folder"], resume=resume, progress=False, on_frame=bar.advance)
                    finished(e, {})
                except UserError as err:
                    finished(e, {"error": str(err)})
        else:
            _run_on_dask(pending, out, resume, workers, scheduler, client, announce, bar, finished)
    finally:
        bar.close()
    data = record()
    failed = [e for e in entries if e["status"] == "failed"]
    if failed:
        raise UserError(f"{out / 'batch.json'}: {len(failed)} sequence(s) failed, first {failed[0]['folder']}: "
                        f"{failed[0]['error']}")
    return data


def _run_on_dask(pending, out, resume, workers, scheduler, client, announce, bar, finished) -> None:
    """Each pending sequence as one task; the bar advances by a sequence's frames when it finishes."""
    from distributed import as_completed

    from tissuerender.distributed import dask_client, worker_threads

    threads = worker_threads(workers) if workers else None
    opened = nullcontext(client) if client is not None else dask_client(workers, scheduler, announce)
    with opened as c:
        futures = {c.submit(render_sequence_task, str(out / e["folder"] / "scene.toml"), resume, threads,
                            pure=False, key=f"tissuerender-sequence-{e['folder']}-{time.time()!r}"): e for e in pending}
        try:
            for future in as_completed(list(futures)):
                entry = futures[future]
                try:
                    result = future.result()
                except Exception as err:  # KilledWorker or a crash: the sequence's finished frames are kept
                    result = {"error": f"{type(err).__name__}: {err}; rerun with --resume"}
                future.release()
                finished(entry, result)
                for _ in range(entry["frames"]):
                    bar.advance()
        except BaseException:
            for future in futures:
                future.cancel()
            raise
