"""``tissuerender batch``: sequence i's scene comes from (spec seed, i) only, so two runs of one spec give
identical scene files and frames and another seed changes them; spec errors exit 2 naming the key path; a
resumed batch keeps finished sequences; docs/batch-format.md documents every spec key."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import tomli_w

from tissuerender import load_scene
from tissuerender.batch.spec import BatchInfo, MaterialRanges, Randomise, SpecFile
from tissuerender.cli import main

DOCS = Path(__file__).resolve().parents[1] / "docs" / "batch-format.md"

# xpbd with a probe, so the randomised stiffness and tool path change the frames; 32x24, 2 frames, 3 sequences
BASE = {
    "scene": {"name": "base", "seed": 1},
    "objects": [{"name": "block", "kind": "body", "shape": "box", "size": [0.1, 0.1, 0.04], "cell_size": 0.02,
                 "material": "liver", "fixed": [{"side": "z_min"}]}],
    "simulation": {"integrator": "xpbd", "dt": 1 / 24, "substeps": 2, "iterations": 2},
    "tools": [{"name": "probe", "radius": 0.015, "keyframes": [
        {"t": 0.0, "position": [0.05, 0.05, 0.07]}, {"t": 0.1, "position": [0.05, 0.05, 0.02]}]}],
    "camera": {"position": [0.0, -0.25, 0.2], "look_at": [0.05, 0.05, 0.02], "fov_deg": 60.0},
    "light": {"attach": "camera", "size": [0.02, 0.02], "radiance": [3000.0, 3000.0, 3000.0], "samples": 4},
    "effects": {"tonemap": {}},
    "output": {"resolution": [32, 24], "frames": 2, "fps": 24.0},
}
SPEC = {
    "batch": {"scene": "base.toml", "sequences": 3, "seed": 7},
    "randomise": {"camera_jitter": 0.01, "light_radiance": [0.5, 1.5], "tool_offset": 0.005,
                  "tool_time_offset": 0.02, "materials": [{"object": "block", "E": [2000.0, 9000.0],
                                                           "roughness": [0.2, 0.6]}]},
}


def _write(folder: Path, spec: dict) -> Path:
    (folder / "base.toml").write_text(tomli_w.dumps(BASE))
    path = folder / "spec.toml"
    path.write_text(tomli_w.dumps(spec))
    return path


def _files(folder: Path) -> dict[str, bytes]:
    """The sequences' scene files and frames (manifests hold timings and paths)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.suffix in (".toml", ".png")}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The spec rendered twice into two folders, and with another seed into a third."""
    root = tmp_path_factory.mktemp("batch")
    spec = _write(root, SPEC)
    other = root / "other"
    other.mkdir()
    other_spec = _write(other, {**SPEC, "batch": {**SPEC["batch"], "seed": 8}})
    for path, out in ((spec, root / "a"), (spec, root / "b"), (other_spec, root / "c")):
        assert main(["batch", str(path), "-o", str(out), "-q"]) == 0
    return root


def test_two_runs_of_one_spec_give_identical_scene_files_and_frames(runs):
    a, b = _files(runs / "a"), _files(runs / "b")
    assert sorted(a) == [f"seq_{i:04d}/{n}" for i in range(3) for n in ("frame_0001.png", "frame_0002.png",
                                                                         "scene.toml")]
    assert a == b


def test_sequences_differ_from_each_other_and_another_seed_changes_them(runs):
    a, c = _files(runs / "a"), _files(runs / "c")
    scenes = [load_scene(runs / "a" / f"seq_{i:04d}" / "scene.toml") for i in range(3)]
    assert len({s.objects[0].override.E for s in scenes}) == 3
    assert all(2000.0 <= s.objects[0].override.E <= 9000.0 and 0.2 <= s.objects[0].optics.roughness <= 0.6
               for s in scenes)
    assert all(1500.0 <= s.light.radiance[0] <= 4500.0 and abs(s.camera.position[0]) <= 0.01 for s in scenes)
    assert all(s.tools[0].keyframes[0].t <= 0.02 for s in scenes)
    assert len({a[f"seq_{i:04d}/frame_0002.png"] for i in range(3)}) == 3
    assert all(a[k] != c[k] for k in a)  # every scene file and frame changes with the seed


def test_the_batch_manifest_records_every_sequence_and_a_resume_keeps_finished_ones(runs):
    out = runs / "a"
    data = json.loads((out / "batch.json").read_text())
    assert (data["kind"], data["complete"], data["sequences_complete"], data["seed"]) == \
        ("tissuerender.batch", True, 3, 7)
    assert [e["scene_sha256"] for e in data["sequences"]] == [load_scene(out / e["folder"] / "scene.toml").sha256
                                                            for e in data["sequences"]]
    (out / "seq_0001" / "frame_0002.png").unlink()  # one frame of one sequence lost
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.png")}
    assert main(["batch", str(runs / "spec.toml"), "-o", str(out), "-q", "--resume"]) == 0
    after = {p: p.stat().st_mtime_ns for p in out.rglob("*.png")}
    assert after.keys() == before.keys() | {out / "seq_0001" / "frame_0002.png"}
    assert all(after[p] == t for p, t in before.items())  # nothing finished was rendered again
    assert _files(out) == _files(runs / "b")


@pytest.mark.parametrize("change, expected", [
    ({"batch": {"scene": "base.toml", "sequences": 0}}, "spec.toml: batch.sequences: expected input should be greater"),
    ({"randomise": {"light_radiance": [2.0, 1.0]}},
     "spec.toml: randomise.light_radiance: expected a range [low, high] with low <= high, found [2.0, 1.0]"),
    ({"randomise": {"materials": [{"object": "lung", "E": [1.0, 2.0]}]}},
     "spec.toml: randomise.materials[0].object: expected one of the base scene's objects (block), found 'lung'"),
    ({"randomise": {"materials": [{"object": "block", "E": [9000.0, 2000.0]}]}},
     "spec.toml: randomise.materials[0].E: expected a range [low, high] with low <= high"),
    ({"randomise": {"camera_jiter": 0.1}}, "spec.toml: randomise.camera_jiter: unknown key (found 0.1); check its "
                                           "spelling against docs/batch-format.md"),
    ({"batch": {"scene": "missing.toml", "sequences": 1}}, "spec.toml: batch.scene: expected a scene file"),
])
def test_spec_errors_exit_2_naming_the_key_path(tmp_path, capsys, change, expected):
    spec = _write(tmp_path, {**SPEC, **change})
    assert main(["batch", str(spec), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1 and "Traceback" not in err


def test_the_batch_format_doc_names_every_spec_key():
    text = DOCS.read_text()
    for model in (SpecFile, BatchInfo, Randomise, MaterialRanges):
        for name in model.model_fields:
            # a key `name`, or a table heading `[name]` / `[[randomise.name]]`
            assert re.search(rf"`\[*(\w+\.)?{name}\]*`", text), \
                f"docs/batch-format.md does not document {model.__name__}.{name}"
