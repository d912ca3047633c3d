"""Cutting in the scene format (issue 21 item 3; docs/interaction.md, "Cutting").

- a tool's ``cut = [{t_start, t_end}]``: from ``t_start`` to ``t_end`` its blade (an instrument's capsules without
  its shaft: the L-hook's wire, the grasper's jaws; a sphere or capsule whole) removes the body tets it sweeps
  through (``sim.cutting``) and does not push tissue;
- a body's ``cut_material``: the preset the faces exposed by a cut are drawn with (default ``"tissue_cut"``, freshly
  cut parenchyma: darker and wetter than an organ's serosa; or any body preset).

Cutting is implemented in XPBD only: :func:`check_cut` rejects it, naming the key and the integrator, in a scene
simulated by another integrator or not simulated at all, and a ``cut_material`` no tool's cut can expose.
"""
from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

import materials
from materials.optics import OPTICS
from sim.cutting import Cut

CUT_INTEGRATORS = ("xpbd",)
CUT_MATERIAL = "tissue_cut"
CUT_MATERIALS = tuple(materials.PRESET_NAMES) + (CUT_MATERIAL,)  # presets a cut face may be drawn with
INSTRUMENT_SHAFTS = 1  # an instrument's first capsule is its shaft (tissuerender.instruments.local_capsules)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class CutSpec(_Strict):
    t_start: Annotated[float, Field(ge=0.0, le=1e6, description="time the blade starts cutting [s]")]
    t_end: Annotated[float, Field(ge=0.0, le=1e6, description="time it stops [s] (> t_start)")]

    @model_validator(mode="after")
    def _ordered(self):
        if self.t_end <= self.t_start:
            raise ValueError(f"t_end must be after t_start, found t_start = {self.t_start}, t_end = {self.t_end}")
        return self

    def to_sim(self, probe: int, tool_kind: str) -> Cut:
        blade_from = INSTRUMENT_SHAFTS if tool_kind in ("grasper", "l_hook") else 0
        return Cut(probe=probe, t_start=self.t_start, t_end=self.t_end, blade_from=blade_from)


def cut_optics(name: str):
    """The optical material of a cut face drawn with preset ``name``."""
    return OPTICS[name]


def check_cut(scene):
    """``(key, message)`` for a cut or cut material that would have no effect or cannot be honoured, else None."""
    cutting = [i for i, t in enumerate(scene.tools) if t.cut]
    for i, o in enumerate(scene.objects):
        if o.cut_material is None:
            continue
        key = f"objects[{i}].cut_material"
        if o.kind == "surface":
            return key, "a static surface is never simulated, so never cut; remove it"
        if not cutting:
            return key, "no tool has a cut, so no cut face is ever drawn; add a tool's cut or remove it"
    if not cutting:
        return None
    key = f"tools[{cutting[0]}].cut"
    integrator = scene.simulation.integrator
    if not scene.simulated():
        return key, "cutting acts on simulated tissue only, and this scene simulates nothing; remove it"
    if integrator not in CUT_INTEGRATORS:
        return key, (f"cutting is implemented for the xpbd integrator only, not for simulation.integrator = "
                     f"{integrator!r}; use integrator = \"xpbd\" or remove it")
    if scene.output.passes:
        return key, ("the ground-truth passes do not follow a cut yet (output.passes = "
                     f"{list(scene.output.passes)}); remove the passes or the cut")
    return None
