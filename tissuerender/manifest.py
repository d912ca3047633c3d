"""``out/manifest.json``: what a render was made from (scene, seed, package versions, machine), what was
planned and what ran with its timings, and how far it got."""
from __future__ import annotations

import os
import platform
from importlib import metadata

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


def manifest(scene: Scene, plan: Plan, recorder: StageRecorder, frames_done: int, wall: float, extra: dict) -> dict:
    return {
        "scene": str(scene.path),
        "scene_name": scene.name,
        "scene_sha256": scene.sha256,
        "seed": scene.seed,
        "versions": package_versions(),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "plan": plan.as_dict(),
        "executed": recorder.summary(),
        "frames_total": scene.output.frames,
        "frames_done": frames_done,
        "wall_seconds": round(wall, 3),
        **extra,
    }
