"""Per-frame simulation states on disk: ``OUT/states/state_NNNN.npz``, what a frame rendered elsewhere (a Dask
task, ``tissuerender.distributed``) needs of the simulation instead of rerunning it.

The simulation of a sequence is sequential; once it has run, each frame depends only on its own state (and,
for the velocity channel, the previous frame's). A state file holds, compressed (``np.savez_compressed``):

=================  ==========================================================================================
key                value
=================  ==========================================================================================
``scene_sha256``   the scene file's sha256: a state of another version of the scene is never used
``frame``          the frame index ``k`` (1-based)
``t``              the frame's time ``(k - 1) / fps`` [s]
``x_<i>``          body ``i``'s node positions (n, 3) float64 [m], bodies in scene order
``v_<i>``          body ``i``'s node velocities (n, 3) float64 [m/s] (the .vtu output writes them)
``tool_<j>``       tool ``j``'s centre at ``t`` (3,) [m], as the probe's keyframed path gives it (informative)
``tool_loads``     (tools, 6) force [N] and torque [N m] on each tool over the interval ending at ``t``
                   (``tissuerender.world.ToolForceLog``), when the world resolves tool contact
=================  ==========================================================================================

float64 is stored as is, so a frame rendered from a state file is bit-identical to one rendered from the
simulation in memory. Files are written atomically (``tissuerender.files.write_atomic``).
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.model import State
from tissuerender.errors import UserError
from tissuerender.files import write_atomic
from tissuerender.scene import Scene
from tissuerender.world import World, make_probe

STATES_FOLDER = "states"


def state_path(out: Path, k: int) -> Path:
    return Path(out) / STATES_FOLDER / f"state_{k:04d}.npz"


@dataclass
class FrameState:
    """One frame's simulation state as read back: positions and velocities by body, in scene order."""

    frame: int
    t: float
    x: list[np.ndarray]
    v: list[np.ndarray]
    tool_loads: np.ndarray | None = None


def write_state(out: Path, k: int, world: World, scene: Scene) -> Path:
    """Write the world's current state as frame ``k``'s (the world has advanced ``k - 1`` frame intervals)."""
    if world.frames_advanced != k - 1:
        raise ValueError(f"write_state: frame {k} needs a world advanced {k - 1} intervals, found "
                         f"{world.frames_advanced}")
    t = (k - 1) / scene.output.fps
    arrays = {"scene_sha256": np.array(scene.sha256), "frame": np.array(k), "t": np.array(t)}
    for i, state in enumerate(world.states):
        arrays[f"x_{i}"] = state.x
        arrays[f"v_{i}"] = state.v
    for j, tool in enumerate(scene.tools):
        arrays[f"tool_{j}"] = make_probe(tool).position(t)
    if world.tool_loads is not None:
        arrays["tool_loads"] = np.zeros_like(world.tool_loads) if k == 1 else np.asarray(world.tool_loads, float)
    path = state_path(out, k)

    def write(tmp):
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    write_atomic(path, write)
    return path


def _sha256_of(path: Path) -> str | None:
    """The scene sha256 a state file records, None when the file is missing or unreadable."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return str(data["scene_sha256"])
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError):
        return None


def states_complete(out: Path, scene: Scene, n_frames: int) -> bool:
    """Whether ``out/states`` holds a readable state of this scene (same sha256) for frames 1 ... n_frames:
    then a resumed render need not run the simulation again."""
    return all(_sha256_of(state_path(out, k)) == scene.sha256 for k in range(1, n_frames + 1))


def read_state(out: Path, k: int, scene: Scene, n_bodies: int) -> FrameState:
    """Frame ``k``'s state; a UserError naming the file when it is missing, unreadable, of another scene
    version or of another number of bodies."""
    path = state_path(out, k)
    advice = "render again without --resume to rerun the simulation"
    try:
        with np.load(path, allow_pickle=False) as data:
            found = str(data["scene_sha256"])
            if found != scene.sha256:
                raise UserError(f"{path}: a state of another version of the scene (sha256 {found[:12]}…, "
                                f"{scene.path} has {scene.sha256[:12]}…); {advice}")
            x = [data[f"x_{i}"] for i in range(n_bodies)]
            v = [data[f"v_{i}"] for i in range(n_bodies)]
            loads = data["tool_loads"] if "tool_loads" in data.files else None
            return FrameState(int(data["frame"]), float(data["t"]), x, v, loads)
    except FileNotFoundError:
        raise UserError(f"{path}: frame {k}'s simulation state is missing; {advice}") from None
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise UserError(f"{path}: cannot read frame {k}'s simulation state ({e}); {advice}") from None


def apply_state(world: World, state: FrameState) -> None:
    """Put the bodies of ``world`` (built from the same scene) in ``state``, as the simulation left them after
    ``state.frame - 1`` frame intervals."""
    world.states = [State(x=x, v=v, t=state.t) for x, v in zip(state.x, state.v)]
    world.frames_advanced = state.frame - 1
