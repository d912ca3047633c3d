"""``render --resume``: it continues only the same scene's render, every output counts towards a finished
frame, and a render killed in the middle of a frame (SIGKILL and SIGINT in a real subprocess, SIGTERM in
this process) leaves only complete files, from which ``--resume`` finishes a sequence byte-identical to an uninterrupted run."""
from __future__ import annotations

import copy
import errno
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w

import tissuerender
from tissuerender import load_scene, pipeline
from tissuerender.cli import main
from tissuerender.distributed import render_distributed
from tissuerender.errors import UserError
from tissuerender.files import TEMPORARY_NAME, OutputError, one_writer, remove_temporaries, write_atomic
from tissuerender.manifest import frame_ranges, parse_frame_ranges
from tissuerender.plan import make_plan
from tissuerender.render_inputs import render_objects
from tissuerender.stages import StageRecorder
from tissuerender.world import advance, build_world

from tests.conftest import pressed_block_scene

TREE = Path(tissuerender.__file__).resolve().parents[1]  # the tree under test, for the subprocesses

# Simulated (xpbd and a pressing probe, so state carries from frame to frame), every format, and slow enough
# per frame (3x3 supersamples, 128 uniform light samples) that a signal sent when frame 2's PNG appears lands
# while frame 2's other files are written or frame 3 renders; the assertions hold wherever it lands.
SCENE = pressed_block_scene("resume", {"sampling": "uniform", "samples": 128}, {
    "resolution": [32, 24], "frames": 6, "fps": 24.0, "formats": ["png", "hdr_npy", "vtu"], "supersampling": 3})
OUTPUTS = [f"frame_{k:04d}.{ext}" for k in range(1, 7) for ext in ("png", "npy")] + \
          [f"block_{k:04d}.vtu" for k in range(1, 7)]
# manifest keys that do not depend on timing, the machine or which run wrote which frame
STABLE = ("kind", "scene", "scene_name", "scene_sha256", "seed", "versions", "plan", "formats", "frames_total",
          "frames_requested", "frames_done", "frames_done_ranges", "complete", "postfx_backend")
# SIGTERM takes the same path as SIGINT once its handler has raised; it is sent in this process below
# (test_sigterm_...), which keeps the subprocesses (each pays the CLI's start-up) to two.
SIGNALS = {"SIGKILL": (signal.SIGKILL, -signal.SIGKILL), "SIGINT": (signal.SIGINT, 130)}


def _write(path: Path, data: dict) -> Path:
    path.write_text(tomli_w.dumps(data))
    return path


def _default_sigint():
    # a child started from a non-interactive shell inherits SIGINT ignored; a user's Ctrl-C is not
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """The scene, an uninterrupted render of it (in this process, which also fills the tree's numba cache for
    the subprocesses), and one CLI render per signal, started together and each sent its signal as soon as
    frame 2's PNG exists: {signal name: (output folder, exit status, stderr)}."""
    root = tmp_path_factory.mktemp("resume")
    scene_path = _write(root / "scene.toml", SCENE)
    reference = root / "reference"
    tissuerender.render(load_scene(scene_path), reference, progress=False)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TREE), os.environ.get("PYTHONPATH", "")]),
           "NUMBA_NUM_THREADS": "1"}
    runs = {}
    for name in SIGNALS:
        out = root / name
        proc = subprocess.Popen([sys.executable, "-m", "tissuerender.cli", "render", str(scene_path), "-o", str(out),
                                 "--quiet"], env=env, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
        runs[name] = (out, proc)
    waiting = set(runs)
    deadline = time.monotonic() + 600
    while waiting and time.monotonic() < deadline:
        for name in sorted(waiting):
            out, proc = runs[name]
            if (out / "frame_0002.png").exists() or proc.poll() is not None:
                proc.send_signal(SIGNALS[name][0])
                waiting.discard(name)
        time.sleep(0.002)
    results = {}
    for name, (out, proc) in runs.items():
        if name in waiting:
            proc.kill()
        _, err = proc.communicate(timeout=600)
        results[name] = (out, proc.returncode, err)
    return scene_path, reference, results


@pytest.mark.parametrize("name", list(SIGNALS))
def test_render_killed_mid_frame_resumes_to_identical_files(killed, name):
    scene_path, reference, results = killed
    out, code, err = results[name]
    assert code == SIGNALS[name][1], err
    if name != "SIGKILL":  # a handled signal ends with the advice, no traceback
        assert err.strip() == "interrupted: finished frames are kept; rerun with --resume to continue"
    names = sorted(p.name for p in out.iterdir())
    assert "frame_0002.png" in names and "frame_0006.png" not in names  # it stopped on the way
    # every output on disk is complete: byte-identical to the uninterrupted run's
    for n in names:
        if n in OUTPUTS:
            assert (out / n).read_bytes() == (reference / n).read_bytes(), n
        elif n == "tool_forces.csv":  # rewritten whole after each frame: the rows so far, as the full run's
            assert (reference / n).read_text().startswith((out / n).read_text()), n
        else:  # the only other names: the manifest, and (after SIGKILL) hidden temporaries
            assert n == "manifest.json" or (name == "SIGKILL" and TEMPORARY_NAME.match(n)), n
    interrupted = json.loads((out / "manifest.json").read_text())
    assert interrupted["complete"] is False
    done = parse_frame_ranges(interrupted["frames_done_ranges"])
    assert interrupted["frames_done"] == len(done) and done == set(range(1, len(done) + 1))
    assert 1 <= len(done) <= 5
    for k in done:  # a frame the manifest calls done has all its files
        assert {f"frame_{k:04d}.png", f"frame_{k:04d}.npy", f"block_{k:04d}.vtu"} <= set(names)

    assert main(["render", str(scene_path), "-o", str(out), "--resume", "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUTS + ["manifest.json", "tool_forces.csv"])  # no temporary left
    for n in OUTPUTS + ["tool_forces.csv"]:
        assert (out / n).read_bytes() == (reference / n).read_bytes(), n
    resumed, uninterrupted = (json.loads((d / "manifest.json").read_text()) for d in (out, reference))
    assert {k: resumed[k] for k in STABLE} == {k: uninterrupted[k] for k in STABLE}
    assert resumed["resumed_skipped"] == [f"frame_{k:04d}.png" for k in sorted(done)]


def test_sigterm_stops_a_render_like_ctrl_c_and_the_handler_is_restored(scene_dict, write_scene, tmp_path,
                                                                        monkeypatch, capsys):
    scene_dict["output"]["frames"] = 3
    path = write_scene(scene_dict)
    real, calls = pipeline.write_png, []

    def terminated_during_frame_2(target, image):
        calls.append(target.name)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGTERM)  # the handler raises at the next bytecode, inside this write
        real(target, image)

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(pipeline, "write_png", terminated_during_frame_2)
    out = tmp_path / "out"
    assert main(["render", str(path), "-o", str(out), "--quiet"]) == 143
    assert capsys.readouterr().err == "terminated: finished frames are kept; rerun with --resume to continue\n"
    assert signal.getsignal(signal.SIGTERM) == before
    assert sorted(p.name for p in out.iterdir()) == ["frame_0001.png", "manifest.json"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["complete"], manifest["frames_done"], manifest["frames_done_ranges"]) == (False, 1, "1")
    # --resume finishes the sequence byte-identical to an uninterrupted render
    monkeypatch.setattr(pipeline, "write_png", real)
    assert main(["render", str(path), "-o", str(out), "--resume", "--quiet"]) == 0
    whole = tmp_path / "whole"
    assert main(["render", str(path), "-o", str(whole), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in whole.iterdir())
    for p in whole.iterdir():
        if p.name != "manifest.json":
            assert (out / p.name).read_bytes() == p.read_bytes(), p.name


# --- refusals --------------------------------------------------------------------------------------------


@pytest.fixture
def finished(scene_dict, write_scene, tmp_path):
    """A finished one-frame render of the minimal scene: (scene dict, scene path, output folder)."""
    path = write_scene(scene_dict)
    out = tmp_path / "out"
    assert main(["render", str(path), "-o", str(out), "--quiet"]) == 0
    return scene_dict, path, out


def _folder(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}


@pytest.mark.parametrize("change, reasons", [
    ({"seed": 4}, ["another version of the scene file (sha256"]),
    ({"frames": 2}, ["another version of the scene file", "frames_total is 1, the scene has 2"]),
    ({"formats": ["png", "hdr_npy"]},
     ["another version of the scene file", "its formats are ['png'], the scene writes ['png', 'hdr_npy']"]),
])
def test_resume_refuses_another_scene_and_says_why(finished, write_scene, capsys, change, reasons):
    scene_dict, path, out = finished
    table = "scene" if "seed" in change else "output"
    scene_dict[table].update(change)
    write_scene(scene_dict)  # the same file, edited
    before = _folder(out)
    assert main(["render", str(path), "-o", str(out), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {out / 'manifest.json'}: --resume refused: ") and err.count("\n") == 1
    for reason in reasons:
        assert reason in err
    assert ("frames_total" in err) == ("frames" in change) and ("formats" in err) == ("formats" in change)
    assert "render without --resume" in err
    assert _folder(out) == before  # nothing written, nothing removed


@pytest.mark.parametrize("key, value, reason", [
    ("scene_sha256", "0" * 64, "its frames come from another version of the scene file (sha256 000000000000…, "
                               "{path} now has {sha}…)"),
    ("frames_total", 7, "frames_total is 7, the scene has 1"),
    ("formats", ["png", "vtu"], "its formats are ['png', 'vtu'], the scene writes ['png']"),
])
def test_resume_names_only_the_field_that_differs(finished, capsys, key, value, reason):
    _, path, out = finished
    manifest = json.loads((out / "manifest.json").read_text())
    (out / "manifest.json").write_text(json.dumps({**manifest, key: value}))
    assert main(["render", str(path), "-o", str(out), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err
    reason = reason.format(path=path, sha=manifest["scene_sha256"][:12])
    assert err == f"error: {out / 'manifest.json'}: --resume refused: {reason}; render without --resume " \
                  "to start the folder over, or into another folder\n"


@pytest.mark.parametrize("content, reason", [
    ("{\"frames\": 3", "cannot read the manifest (Expecting"),
    ("[1, 2]", "not a manifest of a tissuerender render (expected \"kind\": \"tissuerender.render\", found 'list')"),
    ("{\"scene_sha256\": \"abc\", \"frames_total\": 1}", "not a manifest of a tissuerender render"),
    (None, "key 'frames_done_ranges': expected frame ranges like \"1-4,6\", found '3-1'"),
])
def test_resume_refuses_a_manifest_that_is_not_ours_or_unreadable(finished, capsys, content, reason):
    _, path, out = finished
    if content is None:  # ours, but damaged
        manifest = json.loads((out / "manifest.json").read_text())
        content = json.dumps({**manifest, "frames_done_ranges": "3-1"})
    (out / "manifest.json").write_text(content)
    assert main(["render", str(path), "-o", str(out), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {out / 'manifest.json'}: --resume: ") and reason in err, err
    assert err.count("\n") == 1 and (out / "manifest.json").read_text() == content


def test_resume_refuses_frames_without_a_manifest(finished, capsys):
    _, path, out = finished
    (out / "manifest.json").unlink()
    assert main(["render", str(path), "-o", str(out), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {out}: --resume: the folder holds frame files (frame_0001.png, 1 in all) but no " \
                  "manifest.json, so nothing says which scene they show; render without --resume to overwrite " \
                  "them, or into another folder\n"
    assert sorted(p.name for p in out.iterdir()) == ["frame_0001.png"]


def test_resume_into_an_empty_or_missing_folder_renders_everything(scene_dict, write_scene, tmp_path):
    path = write_scene(scene_dict)
    assert main(["render", str(path), "-o", str(tmp_path / "new"), "--resume", "--quiet"]) == 0
    manifest = json.loads((tmp_path / "new" / "manifest.json").read_text())
    assert (manifest["complete"], manifest["frames_done_ranges"], manifest["written"]) == \
        (True, "1", ["frame_0001.png"])


# --- what counts as a finished frame ----------------------------------------------------------------------


def _small_dynamic(scene_dict, frames=3, formats=("png", "vtu")):
    scene_dict["simulation"] = {"integrator": "xpbd", "dt": 1 / 24, "substeps": 2, "iterations": 2}
    scene_dict["tools"] = copy.deepcopy(SCENE["tools"])
    scene_dict["output"].update(frames=frames, formats=list(formats), resolution=[32, 24])
    return scene_dict


def test_a_missing_vtu_makes_its_frame_unfinished(scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(_small_dynamic(scene_dict)))
    out = tmp_path / "out"
    tissuerender.render(scene, out, progress=False)
    original = {n: (out / n).read_bytes() for n in ("frame_0002.png", "block_0002.vtu")}
    (out / "block_0002.vtu").unlink()
    resumed = tissuerender.render(scene, out, resume=True, progress=False)
    assert [p.name for p in resumed.written] == ["frame_0002.png", "block_0002.vtu"]
    assert [p.name for p in resumed.skipped] == ["frame_0001.png", "frame_0003.png"]
    assert {n: (out / n).read_bytes() for n in original} == original


def test_a_full_disk_names_the_file_keeps_the_finished_frames_and_resumes(scene_dict, write_scene, tmp_path,
                                                                          monkeypatch, capsys):
    """ENOSPC when frame 2's PNG lands (os.replace, the last step of every write): exit status 2 and one line
    naming the file, no traceback, no temporary left; frame 1 and the manifest stay; once there is room, --resume
    writes what is missing, the same bytes as an uninterrupted render."""
    path = write_scene(_small_dynamic(scene_dict))
    reference, out = tmp_path / "reference", tmp_path / "out"
    assert main(["render", str(path), "-o", str(reference), "--quiet"]) == 0
    replace = os.replace

    def full_disk(src, dst):
        if Path(dst).name == "frame_0002.png":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        replace(src, dst)

    monkeypatch.setattr(tissuerender.files.os, "replace", full_disk)
    capsys.readouterr()
    assert main(["render", str(path), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"error: {out / 'frame_0002.png'}: cannot write: No space left on device; the finished frames"
                          " are kept")
    assert sorted(p.name for p in out.iterdir()) == ["block_0001.vtu", "frame_0001.png", "manifest.json",
                                                     "tool_forces.csv"]
    assert json.loads((out / "manifest.json").read_text())["frames_done_ranges"] == "1"
    monkeypatch.setattr(tissuerender.files.os, "replace", replace)
    assert main(["render", str(path), "-o", str(out), "--resume", "--quiet"]) == 0
    names = sorted(p.name for p in reference.iterdir() if p.name != "manifest.json")
    assert names == sorted(p.name for p in out.iterdir() if p.name != "manifest.json")
    assert all((out / n).read_bytes() == (reference / n).read_bytes() for n in names)


def test_a_second_render_into_a_folder_in_use_is_refused_and_touches_nothing(scene_dict, write_scene, tmp_path,
                                                                           capsys):
    """While one render writes into a folder (its lock held here, as that render's process holds it), another
    render or resume there exits 2 naming the folder and leaves its files, temporaries included (which it would
    otherwise delete as a killed writer's); once the lock is released, the render runs."""
    path = write_scene(scene_dict)
    out = tmp_path / "out"
    out.mkdir()
    busy = out / ".frame_0001.abcdefgh.tmp.png"  # the first render's frame, being written
    busy.write_text("half a frame")
    with one_writer(out):
        for extra in ([], ["--resume"]):
            capsys.readouterr()
            assert main(["render", str(path), "-o", str(out), "--quiet", *extra]) == 2
            err = capsys.readouterr().err
            assert err == f"error: {out}: another tissuerender process is writing into this folder; wait for it to " \
                          "finish or choose another output folder\n"
        with pytest.raises(UserError, match="another tissuerender process is writing"):  # before any cluster starts
            render_distributed(load_scene(path), out, workers=1, progress=False)
        assert sorted(p.name for p in out.iterdir()) == [busy.name]
    assert main(["render", str(path), "-o", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frame_0001.png", "manifest.json"]  # the stale one removed


def test_a_folder_that_cannot_be_locked_is_written_unguarded(tmp_path, monkeypatch):
    """A file system without flock (some network mounts answer ENOLCK): the render goes on, as without the
    lock; the lock is the guard against a second render, not a condition of the first."""
    def no_locks(fd, how):
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(tissuerender.files.fcntl, "flock", no_locks)
    with one_writer(tmp_path):
        write_atomic(tmp_path / "frame_0001.png", lambda tmp: Path(tmp).write_text("x"))
    assert (tmp_path / "frame_0001.png").read_text() == "x"


def test_an_unwritable_output_is_an_output_error_and_other_errors_pass(tmp_path):
    def raising(error):
        def write(tmp):
            raise error
        return write

    with pytest.raises(OutputError, match=r"frame_0001\.png: cannot write: Read-only file system"):
        write_atomic(tmp_path / "frame_0001.png", raising(OSError(errno.EROFS, "Read-only file system")))
    with pytest.raises(ValueError, match="a writer's own bug"):  # not the machine's refusal: passed on as it is
        write_atomic(tmp_path / "frame_0001.png", raising(ValueError("a writer's own bug")))
    assert list(tmp_path.iterdir()) == []


def test_resume_with_another_frames_option_continues_the_same_sequence(scene_dict, write_scene, tmp_path):
    scene = load_scene(write_scene(_small_dynamic(scene_dict)))
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    tissuerender.render(scene, whole, progress=False)
    first = tissuerender.render(scene, parts, progress=False, frames=2)
    assert (first.manifest["frames_requested"], first.manifest["frames_done_ranges"]) == (2, "1-2")
    assert first.manifest["complete"] is True and first.manifest["frames_total"] == 3
    rest = tissuerender.render(scene, parts, resume=True, progress=False)
    assert [p.name for p in rest.written] == ["frame_0003.png", "block_0003.vtu"]
    assert _folder(parts).keys() == _folder(whole).keys()
    assert {n: b for n, b in _folder(parts).items() if n != "manifest.json"} == \
        {n: b for n, b in _folder(whole).items() if n != "manifest.json"}
    # a shorter --frames on resume keeps what is finished beyond it
    again = tissuerender.render(scene, parts, resume=True, progress=False, frames=1)
    assert again.written == [] and again.manifest["frames_done_ranges"] == "1-3"


def test_fresh_render_over_another_scenes_frames_never_resumes_them(scene_dict, write_scene, tmp_path, capsys):
    """Without --resume the folder starts over: the manifest records no frame until this run writes it, so the
    other scene's frames beyond --frames are re-rendered by a later --resume, never kept."""
    _small_dynamic(scene_dict, formats=("png",))
    old = write_scene(copy.deepcopy(scene_dict), "old.toml")
    scene_dict["scene"]["seed"] = 11
    scene_dict["light"]["radiance"] = [1000.0, 1000.0, 1000.0]
    new = write_scene(scene_dict, "new.toml")
    out, clean = tmp_path / "out", tmp_path / "clean"
    assert main(["render", str(old), "-o", str(out), "--quiet"]) == 0
    stale = (out / "frame_0003.png").read_bytes()
    assert main(["render", str(new), "-o", str(out), "--frames", "2"]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"note: {out} also holds 1 frame file(s) this render did not write (frame_0003.png, …)")
    assert json.loads((out / "manifest.json").read_text())["frames_done_ranges"] == "1-2"
    assert main(["render", str(new), "-o", str(out), "--resume", "--quiet"]) == 0
    assert main(["render", str(new), "-o", str(clean), "--quiet"]) == 0
    assert (out / "frame_0003.png").read_bytes() == (clean / "frame_0003.png").read_bytes() != stale


def test_skipped_frame_hands_the_next_one_the_positions_render_objects_would(scene_dict, write_scene):
    """The velocity channel of the first frame after a skipped one differences against the skipped frame's
    surface positions, so a resumed frame sees the same ``previous`` as in an uninterrupted run."""
    scene = load_scene(write_scene(_small_dynamic(scene_dict)))
    plan, recorder = make_plan(scene), StageRecorder()
    world = build_world(scene, plan, recorder)
    advance(world, scene, recorder)
    _, positions = render_objects(world, scene, 1 / 24, plan, recorder)
    skipped = pipeline._surface_positions(world, plan)
    assert skipped.keys() == positions.keys() == {"block"}
    assert (skipped["block"] == positions["block"]).all()
    assert (skipped["block"] != world.bodies[0].surface.points).any()  # the probe has moved the surface


# --- temporaries and the record of finished frames --------------------------------------------------------


def test_atomic_writes_use_names_a_render_recognises_as_temporaries(tmp_path):
    seen = []
    for name in ("frame_0002.png", "block_0002.vtu", "manifest.json", "frame_0002.npy"):
        write_atomic(tmp_path / name, lambda tmp: (seen.append(Path(tmp).name), Path(tmp).write_text("x")))
    assert len(seen) == 4 and all(TEMPORARY_NAME.match(n) for n in seen), seen
    assert not any(TEMPORARY_NAME.match(p.name) for p in tmp_path.iterdir())
    leftovers = [tmp_path / n for n in seen] + [tmp_path / ".notes", tmp_path / "frame.tmp.png"]
    for p in leftovers:
        p.write_text("partial")
    assert remove_temporaries(tmp_path) == sorted(tmp_path / n for n in seen)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [".notes", "frame.tmp.png", "frame_0002.png", "block_0002.vtu", "manifest.json", "frame_0002.npy"])


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_atomic_writes_give_a_new_file_the_mode_of_a_plain_open_and_keep_a_replaced_files(tmp_path, umask, mode):
    """tempfile.mkstemp's 0o600 used to reach every output through the rename."""
    old = os.umask(umask)
    try:
        write_atomic(tmp_path / "frame_0001.png", lambda tmp: Path(tmp).write_text("x"))
        with open(tmp_path / "plain.txt", "w") as f:
            f.write("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "frame_0001.png").stat().st_mode) == mode
    assert stat.S_IMODE((tmp_path / "plain.txt").stat().st_mode) == mode
    os.chmod(tmp_path / "frame_0001.png", 0o640)
    write_atomic(tmp_path / "frame_0001.png", lambda tmp: Path(tmp).write_text("y"))
    assert stat.S_IMODE((tmp_path / "frame_0001.png").stat().st_mode) == 0o640
    assert (tmp_path / "frame_0001.png").read_text() == "y"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_0001.png", "plain.txt"]


@pytest.mark.parametrize("frames, text", [(set(), ""), ({1}, "1"), ({1, 2, 3, 5}, "1-3,5"),
                                          ({2, 4, 5, 6, 9, 10}, "2,4-6,9-10")])
def test_frame_ranges_round_trip(frames, text):
    assert frame_ranges(frames) == text and parse_frame_ranges(text) == frames


@pytest.mark.parametrize("text", ["0", "3-1", "1,,2", "1-", "a", " 1"])
def test_frame_ranges_reject_what_frame_ranges_never_writes(text):
    with pytest.raises(ValueError, match="expected frame ranges"):
        parse_frame_ranges(text)
