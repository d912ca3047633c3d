"""The cost of a frame, stage by stage, for every shipped scene (issue 17 item 1, in the spirit of Qian Fig. 7.7).

Each scene of ``scenes/`` renders its first ``FRAMES`` frames through ``pipeline.render`` (so the stages are the
ones its plan runs: simulation, contact, embed, raster, BVH, shadows, thickness/SSS, shading, each post-effect,
writing) into a temporary folder, at its own resolution or scaled down to ``max_width`` (aspect kept). The
pipeline's ``StageRecorder`` times each stage. A warm-up render of one frame comes first, so numba's compiling
(or cache loading) is not counted. The setup stages (``mesh``, ``load_surface``) run once per render and are
listed apart; every other stage is divided by the frames rendered (``simulate`` runs from the second frame on,
so its per-frame figure is per frame interval simulated).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numba

from tissuerender.pipeline import render
from tissuerender.plan import make_plan
from tissuerender.report.render_measure import scaled_resolution, variant
from tissuerender.scene import load_scene

SCENES_DIR = Path(__file__).resolve().parents[2] / "scenes"
SETUP_STAGES = ("mesh", "load_surface")
FRAMES = 2
# "tiny" (the test suite's) skips the warm-up: its figures then include numba's cache loading, and only the
# stages run are checked
STAGE_SWEEPS = {"full": {"max_width": None, "frames": 3, "warm": True},
                "quick": {"max_width": 160, "frames": FRAMES, "warm": True},
                "tiny": {"max_width": 48, "frames": FRAMES, "warm": False}}
# planned stages timed inside another: contact, Prony state and fibre terms are parts of each simulation step
INSIDE_SIMULATE = ("contact", "prony_state", "fibre_terms")


def shipped_scenes() -> list[Path]:
    return sorted(SCENES_DIR.glob("*.toml"))


def small(scene, sweep: dict):
    """The scene at the sweep's resolution and frame count (its output formats kept: writing is a stage)."""
    frames = min(sweep["frames"], scene.output.frames)
    return variant(scene, output={"resolution": scaled_resolution(scene, sweep["max_width"]), "frames": frames})


def scene_costs(path: Path, sweep: dict) -> dict:
    scene = small(load_scene(path), sweep)
    frames = scene.output.frames
    with tempfile.TemporaryDirectory(prefix="tissuerender-stage-costs-") as tmp:
        if sweep["warm"]:  # the same frames once untimed: the second frame's simulation compiles too
            render(scene, Path(tmp) / "warm", progress=False)
        result = render(scene, Path(tmp) / "run", progress=False)
    summary = result.recorder.summary()
    planned = make_plan(scene).names
    per_frame = {name: s["seconds"] / frames for name, s in summary.items() if name not in SETUP_STAGES}
    return {"scene": path.stem, "path": str(path), "resolution": scene.output.resolution, "frames": frames,
            "planned": planned, "stages": summary, "timed_inside": timed_inside(planned, summary),
            "setup_s": {name: summary[name]["seconds"] for name in SETUP_STAGES if name in summary},
            "per_frame_s": per_frame, "frame_s": sum(per_frame.values())}


def timed_inside(planned: list[str], recorded: dict) -> dict[str, str | None]:
    """For each planned stage with no timing of its own, the recorded stage its time is part of: ``simulate``
    for contact, Prony and fibre terms; for a pointwise post-effect (noise, tone map, grade, mask), the effect
    before it, with which the chain runs it fused in one pass (``postfx.chain.ChainResult.fused``). None: none."""
    inside = {}
    for i, name in enumerate(planned):
        if name in recorded:
            continue
        if name in INSIDE_SIMULATE:
            inside[name] = "simulate" if "simulate" in recorded else None
        elif name.startswith("postfx."):
            before = [n for n in planned[:i] if n.startswith("postfx.") and n in recorded]
            inside[name] = before[-1] if before else None
        else:
            inside[name] = None
    return inside


def run_stage_costs(sweep: dict, paths: list[Path] | None = None, tick=lambda: None) -> dict:
    """Every shipped scene's (or ``paths``') per-stage costs, with the thread count they ran on."""
    rows = []
    for path in paths if paths is not None else shipped_scenes():
        rows.append(scene_costs(path, sweep))
        tick()
    return {"title": "per-stage cost of a frame, every shipped scene (Qian Fig. 7.7 spirit)",
            "numba_threads": numba.get_num_threads(), "sweep": sweep, "scenes": rows}
