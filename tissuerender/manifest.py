"""``out/manifest.json``: what a render was made from (scene, seed, package versions, machine), what was
planned and what ran with its timings, and how far it got: which frames are finished. ``--resume`` reads it
back (``read_resumable``) and continues only a render of the same scene file, frame count and formats."""
from __future__ import annotations

import json
import os
import platform
import re
from importlib import metadata
from pathlib import Path

from tissuerender.errors import UserError
from tissuerender.field_colours import legends
from tissuerender.plan import Plan
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder

PACKAGES = ("tissuerender", "numpy", "numba", "scipy", "vtk", "meshio", "trimesh", "pillow", "pydantic")


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


KIND = "tissuerender.render"  # marks a manifest as ours; resume refuses any other file called manifest.json
RANGES = re.compile(r"^$|^\d+(-\d+)?(,\d+(-\d+)?)*$")


def manifest(scene: Scene, plan: Plan, recorder: StageRecorder, formats: list[str], frames_requested: int,
             done: set[int], wall: float, extra: dict) -> dict:
    """The manifest of a render into one folder. ``done`` holds the frames whose outputs this render wrote
    or kept; ``frames_requested`` is the run's ``--frames`` (the scene's count without it)."""
    return {
        "kind": KIND,
        "scene": str(scene.path),
        "scene_name": scene.name,
        "scene_sha256": scene.sha256,
        "seed": scene.seed,
        "versions": package_versions(),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "plan": plan.as_dict(),
        "executed": recorder.summary(),
        "formats": list(formats),
        "frames_total": scene.output.frames,
        "frames_requested": frames_requested,
        "frames_done": len(done),
        "frames_done_ranges": frame_ranges(done),
        "wall_seconds": round(wall, 3),
        **legends(scene),  # the field colour maps' colour bars
        **extra,
    }


def frame_ranges(frames: set[int]) -> str:
    """``{1, 2, 3, 5}`` -> ``"1-3,5"``: the finished frames, short however long the sequence."""
    runs: list[list[int]] = []
    for k in sorted(frames):
        if runs and k == runs[-1][1] + 1:
            runs[-1][1] = k
        else:
            runs.append([k, k])
    return ",".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs)


def parse_frame_ranges(text: str) -> set[int]:
    """The inverse of ``frame_ranges``; a ValueError for anything else (ranges must not run backwards)."""
    if not isinstance(text, str) or not RANGES.match(text):
        raise ValueError(f"expected frame ranges like \"1-4,6\", found {text!r}")
    frames: set[int] = set()
    for part in filter(None, text.split(",")):
        a, _, b = part.partition("-")
        first, last = int(a), int(b or a)
        if not 1 <= first <= last:
            raise ValueError(f"expected frame ranges like \"1-4,6\", found {part!r} in {text!r}")
        frames.update(range(first, last + 1))
    return frames


def read_resumable(path: Path, scene: Scene, formats: list[str]) -> set[int] | None:
    """The frames the manifest at ``path`` records as finished, or None when there is no manifest. A
    UserError saying why when it is unreadable, not ours, or from a render of another scene file, frame count
    or formats (one message lists every difference)."""
    advice = "render without --resume to start the folder over, or into another folder"
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UserError(f"{path}: --resume: cannot read the manifest ({e}); {advice}") from None
    if not isinstance(data, dict) or data.get("kind") != KIND:
        found = data.get("kind") if isinstance(data, dict) else type(data).__name__
        raise UserError(f"{path}: --resume: not a manifest of a tissuerender render (expected \"kind\": "
                        f"\"{KIND}\", found {found!r}); {advice}")
    expected = {"scene_sha256": str, "frames_total": int, "formats": list, "frames_done_ranges": str}
    for key, kind in expected.items():
        if not isinstance(data.get(key), kind) or isinstance(data.get(key), bool):
            raise UserError(f"{path}: --resume: key {key!r}: expected a {kind.__name__}, found "
                            f"{data.get(key)!r}; {advice}")
    differences = []
    if data["scene_sha256"] != scene.sha256:
        differences.append(f"its frames come from another version of the scene file (sha256 "
                           f"{data['scene_sha256'][:12]}…, {scene.path} now has {scene.sha256[:12]}…)")
    if data["frames_total"] != scene.output.frames:
        differences.append(f"frames_total is {data['frames_total']}, the scene has {scene.output.frames}")
    if sorted(data["formats"]) != sorted(formats):
        differences.append(f"its formats are {data['formats']}, the scene writes {list(formats)}")
    if differences:
        raise UserError(f"{path}: --resume refused: " + "; ".join(differences) + f"; {advice}")
    try:
        done = parse_frame_ranges(data["frames_done_ranges"])
    except ValueError as e:
        raise UserError(f"{path}: --resume: key 'frames_done_ranges': {e}; {advice}") from None
    if done and max(done) > scene.output.frames:
        raise UserError(f"{path}: --resume: key 'frames_done_ranges': frame {max(done)} is beyond "
                        f"frames_total = {scene.output.frames}; {advice}")
    return done
