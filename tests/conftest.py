"""Shared fixtures: a minimal valid scene as a dict, and a writer that puts scene dicts on disk; tests marked
``osmesa`` skip where the OSMesa backend cannot run, except under ``CI=true``, where they fail naming why."""
from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest
import tomli_w

import sim  # noqa: F401  (first: numba's cache stamps and inliner for every package's kernels, sim.numba_cache)
import postfx.chain

MINIMAL_SCENE = {
    "scene": {"name": "test", "seed": 3},
    "objects": [
        {"name": "block", "kind": "body", "shape": "box", "size": [0.1, 0.1, 0.04], "cell_size": 0.02,
         "material": "liver", "fixed": [{"side": "z_min"}]},
    ],
    "simulation": {"integrator": "none"},
    "camera": {"position": [0.0, -0.25, 0.2], "look_at": [0.05, 0.05, 0.02], "fov_deg": 60.0},
    "light": {"attach": "camera", "size": [0.02, 0.02], "radiance": [3000.0, 3000.0, 3000.0], "samples": 4},
    "effects": {"tonemap": {}},
    "output": {"resolution": [64, 48], "frames": 1, "fps": 24.0},
}


def pressed_block_scene(name: str, light: dict, output: dict) -> dict:
    """MINIMAL_SCENE simulated (xpbd) with a probe pressing the block from t = 0 to 0.2 s, so every frame's
    state differs and carries to the next; ``light`` updates the light, ``output`` replaces the output table."""
    scene = copy.deepcopy(MINIMAL_SCENE)
    scene["scene"] = {"name": name, "seed": 5}
    scene["simulation"] = {"integrator": "xpbd", "dt": 1 / 24, "substeps": 2, "iterations": 2}
    scene["tools"] = [{"name": "probe", "radius": 0.015, "keyframes": [
        {"t": 0.0, "position": [0.05, 0.05, 0.07]}, {"t": 0.2, "position": [0.05, 0.05, 0.02]}]}]
    scene["light"].update(light)
    scene["output"] = output
    return scene


@pytest.fixture
def scene_dict():
    return copy.deepcopy(MINIMAL_SCENE)


@pytest.fixture
def write_scene(tmp_path):
    def write(data: dict, name: str = "scene.toml") -> Path:
        path = tmp_path / name
        path.write_text(tomli_w.dumps(data))
        return path

    return write


def osmesa_requirement(problem: str | None, environ) -> tuple[str, str] | None:
    """What a test marked ``osmesa`` does when ``problem`` (``postfx.osmesa_problem()``: None when the
    backend runs) keeps it from running: ("skip", why) on a developer's machine, ("fail", why) under
    ``CI=true``, where a skipped backend would pass unseen; None when it can run."""
    if problem is None:
        return None
    if environ.get("CI", "").strip().lower() in ("true", "1", "yes"):
        return "fail", f"CI=true and the OSMesa backend cannot run: {problem}"
    return "skip", f"the OSMesa backend cannot run: {problem}"


def pytest_runtest_setup(item):
    if item.get_closest_marker("osmesa") is None:
        return
    decision = osmesa_requirement(postfx.chain.osmesa_problem(), os.environ)
    if decision is not None:
        action, why = decision
        if action == "fail":
            pytest.fail(why, pytrace=False)
        pytest.skip(why)
