"""Shared fixtures: a minimal valid scene as a dict, and a writer that puts scene dicts on disk."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import tomli_w

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
