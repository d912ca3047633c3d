"""Check a scene fully: everything a render builds before its first frame, so that "valid" means "renders".

``load_scene`` checks each table and the cross-references between them; what only building the scene can
show is checked here by building it as ``tissuerender.pipeline.render`` does, up to (not including) the first
frame: the plan, the tet meshes and static surfaces (mesh files read, surfaces voxelised, regions and paint
strokes applied), one integrator per body (its constructor refuses what it cannot simulate: gravity for the
ChainMail, average nodal pressure on a material without a volumetric split, paint strokes for the EBM), the
camera, light and render settings the renderer is given, and the post-effect chain with its backend.

``tissuerender validate`` calls :func:`check_scene`; a render may call it in place of its own
``make_plan`` / ``build_world`` and keep the world it returns.
"""
from __future__ import annotations

from dataclasses import dataclass

import postfx
from postfx.gl.context import Context
from tissuerender.errors import UserError
from tissuerender.plan import Plan, make_plan
from tissuerender.render_inputs import check_camera, light_for, settings_for
from tissuerender.renderer.frame import check_light
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder, recorder_or_new
from tissuerender.world import World, build_world


@dataclass
class CheckedScene:
    """What the checks built: the plan and the world at rest (the render's first frame starts from it)."""

    plan: Plan
    world: World
    recorder: StageRecorder


def check_scene(scene: Scene, recorder: StageRecorder | None = None) -> CheckedScene:
    """Build ``scene`` up to its first frame; raise :class:`UserError` (exit 2) with the file and key when
    any part of it cannot be built or rendered."""
    recorder = recorder_or_new(recorder)
    plan = make_plan(scene)
    world = build_world(scene, plan, recorder)
    check_camera(scene)
    settings = settings_for(scene, scene.seed)
    try:
        check_light(light_for(scene), settings)
    except NotImplementedError as e:  # the same message as a render's (pipeline.render_hdr)
        raise UserError(f"{scene.path}: [effects] asks for something this renderer cannot do: {e}") from None
    if scene.effect_chain() and scene.effects.backend == "osmesa":
        try:
            Context.get()  # what postfx.apply_chain does first with this backend
        except postfx.OSMesaUnavailable as e:  # the same message as a render's (pipeline.postprocess)
            raise UserError(f"{scene.path}: effects.backend = \"osmesa\": {e}") from None
    return CheckedScene(plan, world, recorder)
