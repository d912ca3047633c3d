"""Frames as Dask tasks (``tissuerender.distributed``, docs/dask.md): a real ``LocalCluster`` of two worker
processes renders a sequence byte-identical to the serial render; a worker killed mid-render loses no finished
frame and nothing is written twice; ``--resume`` reuses the state files and renders only what is missing."""
from __future__ import annotations

import json
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from tissuerender import load_scene, render
from tissuerender.cli import main
from tissuerender.distributed import dask_client, render_distributed, worker_threads
from tissuerender.errors import UserError
from tissuerender.states import apply_state, read_state, state_path, states_complete, write_state
from tissuerender.checks import check_scene
from tissuerender.stages import StageRecorder
from tissuerender.world import advance

from tests.conftest import pressed_block_scene

# Simulated (xpbd and a pressing probe: every frame's state differs), every format and two ground-truth passes,
# so every kind of file a frame task writes is compared. 64x48, 6 frames: small enough for the CI budget.
SCENE = pressed_block_scene("dask", {"samples": 64}, {
    "resolution": [64, 48], "frames": 6, "fps": 24.0, "formats": ["png", "hdr_npy", "vtu"],
    "passes": ["depth", "segmentation"]})


def _outputs(folder: Path) -> dict[str, bytes]:
    """Every file a render writes except the manifest (timings) and the state files (the Dask path's own)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "manifest.json" and p.parent.name != "states"}


def _frame_files(folder: Path, k: int) -> list[Path]:
    return [folder / f"frame_{k:04d}.png", folder / f"frame_{k:04d}.npy", folder / f"block_{k:04d}.vtu",
            folder / "passes" / f"depth_{k:04d}.npy", folder / "passes" / f"segmentation_{k:04d}.npy"]


def _identity(paths) -> dict[str, tuple[int, int]]:
    """(inode, mtime in ns) of each file: a file rewritten, even with the same bytes, gets a new inode (atomic
    rename of a new temporary)."""
    return {str(p): (p.stat().st_ino, p.stat().st_mtime_ns) for p in paths}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """The scene, its serial render, and one two-process LocalCluster shared by the tests (it starts in seconds)."""
    root = tmp_path_factory.mktemp("dask")
    scene_path = root / "scene.toml"
    scene_path.write_text(tomli_w.dumps(SCENE))
    scene = load_scene(scene_path)
    render(scene, root / "serial", progress=False)
    with dask_client(2, announce=lambda line: None) as client:
        yield root, scene_path, scene, _outputs(root / "serial"), client


def test_two_worker_processes_render_every_file_byte_identical_to_the_serial_render(setup):
    root, scene_path, _, serial, client = setup
    pids = client.run(os.getpid)
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()  # two processes, not this one
    out = root / "cli"
    assert main(["render", str(scene_path), "-o", str(out), "-q", "--scheduler", client.scheduler.address]) == 0
    assert len(serial) == 6 * 5 + 3  # png, npy, vtu, two passes per frame; cameras.json, labels.json, tool_forces.csv
    assert _outputs(out) == serial
    data = json.loads((out / "manifest.json").read_text())
    assert (data["complete"], data["frames_done_ranges"], data["states"]) == (True, "1-6", "simulated")
    assert data["executor"]["kind"] == "dask"
    assert data["executed"]["raster"]["calls"] == 6  # the workers' stage timings reach the manifest
    assert states_complete(out, load_scene(scene_path), 6)


def _done(out: Path) -> set[int]:
    from tissuerender.manifest import parse_frame_ranges

    return parse_frame_ranges(json.loads((out / "manifest.json").read_text())["frames_done_ranges"])


def test_resume_reuses_the_states_and_renders_only_the_frames_whose_files_are_missing(setup):
    root, scene_path, scene, serial, client = setup
    out = root / "resumed"
    shutil.copytree(root / "cli", out)  # a finished Dask render (first test's), then two frames' files lost
    (out / "frame_0005.png").unlink()
    (out / "passes" / "depth_0006.npy").unlink()
    states = _identity(out / "states" / f"state_{k:04d}.npz" for k in range(1, 7))
    untouched = _identity(p for k in range(1, 5) for p in _frame_files(out, k))
    assert main(["render", str(scene_path), "-o", str(out), "-q", "--resume",
                 "--scheduler", client.scheduler.address]) == 0
    data = json.loads((out / "manifest.json").read_text())
    assert data["states"] == "reused" and "simulate" not in data["executed"]  # the simulation did not run again
    assert data["resumed_skipped"] == [f"frame_{k:04d}.png" for k in range(1, 5)]
    assert _identity(map(Path, states)) == states and _identity(map(Path, untouched)) == untouched
    assert _outputs(out) == serial


def test_a_batch_on_the_cluster_writes_the_same_sequences_as_in_one_process(setup, tmp_path):
    _, _, _, _, client = setup
    from tests.test_batch import SPEC, _files, _write

    spec = _write(tmp_path, {**SPEC, "batch": {**SPEC["batch"], "sequences": 2}})
    assert main(["batch", str(spec), "-o", str(tmp_path / "serial"), "-q"]) == 0
    assert main(["batch", str(spec), "-o", str(tmp_path / "dask"), "-q", "--scheduler", client.scheduler.address]) == 0
    assert len(_files(tmp_path / "dask")) == 2 * 3 and _files(tmp_path / "dask") == _files(tmp_path / "serial")
    assert json.loads((tmp_path / "dask" / "batch.json").read_text())["complete"] is True


def test_the_accuracy_report_cases_run_as_dask_tasks_with_the_serial_errors(setup, tmp_path):
    _, _, _, _, client = setup
    from tissuerender.report import accuracy

    serial = accuracy.run_report(tmp_path / "serial", cases=["msd"], level="tiny")["cases"]["msd"]
    on_dask = accuracy.run_report(tmp_path / "dask", cases=["msd"], level="tiny", client=client)["cases"]["msd"]
    assert on_dask["cached"] is False and (tmp_path / "dask" / "cases" / "msd.json").is_file()
    assert on_dask["convergence"]["errors_m"] == serial["convergence"]["errors_m"]  # the same arithmetic, elsewhere
    assert [p["max_abs_m"] for p in on_dask["points"]] == [p["max_abs_m"] for p in serial["points"]]
    again = accuracy.run_report(tmp_path / "dask", cases=["msd"], level="tiny", client=client)["cases"]["msd"]
    assert again["cached"] is True  # a finished case is reused, not sent to the cluster again


# last of the cluster's tests: the worker its nanny restarts would start cold
def test_a_worker_killed_mid_render_loses_no_finished_frame_and_nothing_is_written_twice(setup):
    root, _, scene, serial, client = setup
    out = root / "killed"
    kept = {}

    def kill_after_two(k, c):
        if len(kept) == 0 and len(list(out.glob("frame_*.png"))) >= 2:
            finished = [j for j in range(1, 7) if j in _done(out)]
            kept.update(_identity([p for j in finished for p in _frame_files(out, j)]))
            busy = [w for w, keys in c.processing().items() if keys] or list(c.scheduler_info()["workers"])
            os.kill(c.run(os.getpid, workers=[busy[0]])[busy[0]], signal.SIGKILL)  # mid-task if it has one

    try:
        render_distributed(scene, out, progress=False, client=client, on_frame=kill_after_two)
    except UserError as e:  # every attempt at some frame died with its worker: named, then --resume finishes
        assert "were not rendered" in str(e) and "--resume" in str(e)
        render_distributed(scene, out, resume=True, progress=False, client=client)
    assert kept  # the kill happened after two frames were recorded
    assert _outputs(out) == serial
    assert _identity(Path(p) for p in kept) == kept  # the frames finished before the kill were not written again
    assert json.loads((out / "manifest.json").read_text())["frames_done_ranges"] == "1-6"


def test_a_state_file_round_trips_bit_exactly_and_refuses_another_scene_version(tmp_path, write_scene):
    scene = load_scene(write_scene(SCENE))
    world = check_scene(scene, StageRecorder()).world
    write_state(tmp_path, 1, world, scene)
    advance(world, scene, StageRecorder())
    write_state(tmp_path, 2, world, scene)
    x2 = world.states[0].x.copy()
    fresh = check_scene(scene, StageRecorder()).world
    apply_state(fresh, read_state(tmp_path, 2, scene, 1))
    assert fresh.frames_advanced == 1 and np.array_equal(fresh.states[0].x, x2)
    assert not np.array_equal(x2, world.bodies[0].mesh.points)  # the probe moved the block: a real state
    assert np.array_equal(fresh.states[0].v, world.states[0].v)
    with np.load(state_path(tmp_path, 2)) as data:
        assert np.allclose(data["tool_0"], [0.05, 0.05, 0.07 - 0.05 * (1 / 24) / 0.2])  # the probe's path at t = 1/24 s
    other = load_scene(write_scene({**SCENE, "scene": {"name": "dask", "seed": 6}}, "other.toml"))
    assert not states_complete(tmp_path, other, 2) and states_complete(tmp_path, scene, 2)
    with pytest.raises(UserError, match="state_0002.npz: a state of another version of the scene"):
        read_state(tmp_path, 2, other, 1)
    with pytest.raises(UserError, match="state_0003.npz: frame 3's simulation state is missing"):
        read_state(tmp_path, 3, scene, 1)


def test_local_workers_share_the_cores_without_oversubscribing():
    assert [worker_threads(n, cpus=2) for n in (1, 2, 3)] == [2, 1, 1]
    assert worker_threads(2, cpus=8) == 4


@pytest.mark.parametrize("argv, expected", [(["--workers", "0"], "--workers: expected a positive number"),
                                            (["--workers", "2", "--scheduler", "tcp://x:1"], "not allowed with")])
def test_bad_dask_options_exit_2_naming_the_option(argv, expected, capsys, write_scene):
    with pytest.raises(SystemExit) as e:
        main(["render", str(write_scene(SCENE)), *argv])
    assert e.value.code == 2 and expected in capsys.readouterr().err
