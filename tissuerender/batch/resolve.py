"""Sequence ``i`` of a batch as a fully resolved scene: the base scene's tables with the spec's randomisation
applied, drawn from ``numpy.random.default_rng([batch seed, i])`` and nothing else, so a sequence's scene is the
same whichever machine, worker or order makes it. The draws are made in a fixed order: scene seed, camera,
light, tools (in scene order), materials (in spec order)."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import tomli_w

from tissuerender.batch.spec import BatchSpec


def sequence_name(i: int) -> str:
    return f"seq_{i:04d}"


def resolve_sequence(spec: BatchSpec, i: int) -> dict:
    """The TOML tables of sequence ``i``'s scene (loadable by ``tissuerender render``: mesh paths absolute)."""
    data = copy.deepcopy(spec.base_data)
    base, r = spec.base, spec.randomise
    rng = np.random.default_rng([spec.batch.seed, i])
    data["scene"]["name"] = f"{base.name}-{sequence_name(i)}"
    if r.seed:
        data["scene"]["seed"] = int(rng.integers(0, 2**31 - 1))
    if r.camera_jitter:
        data["camera"]["position"] = [float(p + rng.uniform(-r.camera_jitter, r.camera_jitter))
                                      for p in base.camera.position]
    if r.light_radiance is not None:
        factor = float(rng.uniform(*r.light_radiance))
        data.setdefault("light", {})["radiance"] = [c * factor for c in base.light.radiance]
    for tool, table in zip(base.tools, data.get("tools", [])):
        shift = rng.uniform(-r.tool_offset, r.tool_offset, 3) if r.tool_offset else np.zeros(3)
        delay = float(rng.uniform(0.0, r.tool_time_offset)) if r.tool_time_offset else 0.0
        table["keyframes"] = [{"t": k.t + delay, "position": [float(p + s) for p, s in zip(k.position, shift)]}
                              for k in tool.keyframes]
    objects = {o["name"]: o for o in data["objects"]}
    for m in r.materials:
        table = objects[m.object]
        for key in ("E", "nu", "density"):
            if getattr(m, key) is not None:
                table.setdefault("override", {})[key] = float(rng.uniform(*getattr(m, key)))
        for key in ("roughness", "ior", "k_sss"):
            if getattr(m, key) is not None:
                table.setdefault("optics", {})[key] = float(rng.uniform(*getattr(m, key)))
    for table in data["objects"]:  # the resolved scene lives in another folder than the base scene
        if "mesh" in table and not Path(table["mesh"]).is_absolute():
            table["mesh"] = str((base.path.parent / table["mesh"]).resolve())
    return data


def scene_text(spec: BatchSpec, i: int) -> str:
    """Sequence ``i``'s scene file as TOML text, headed by where it came from."""
    head = (f"# sequence {i} of the batch {spec.path} (seed {spec.batch.seed}), resolved from {spec.base.path}\n"
            "# by `tissuerender batch`: every randomised value is written out; render it as any scene\n")
    return head + tomli_w.dumps(resolve_sequence(spec, i))
