"""A body's surface coloured by a simulated field (issue 19 item 5: the seed validation cases drawn as colour maps;
``tissuerender.field_colours`` computes the field, ``tissuerender.renderer.fieldmap`` draws it).

``[objects.field_colours]``: ``field`` (``"displacement"``: the magnitude of each surface point's displacement from
rest [m]; ``"displacement_x"``, ``_y``, ``_z``: one signed component [m]; ``"von_mises"``: the von Mises equivalent
of the Cauchy stress of the body's constitutive model [Pa], volume-averaged onto the surface), ``colormap`` (a
matplotlib colormap, default ``"viridis"``) and ``range = [low, high]``, the field values drawn at the colormap's two
ends (clamped beyond them); the render's ``manifest.json`` records it, with the field's unit, as the colour bar's
scale. Without ``range`` each frame is scaled from 0 (or its smallest value, when negative) to its own largest value
(the colour bar then differs from frame to frame, and the manifest says so).
"""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

FIELDS = {"displacement": "m", "displacement_x": "m", "displacement_y": "m", "displacement_z": "m",
          "von_mises": "Pa"}  # field name -> unit (tissuerender.field_colours computes each)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class FieldColours(_Strict):
    field: Literal[tuple(FIELDS)] = Field(description=(  # type: ignore[valid-type]
        "the per-vertex field drawn: displacement = |x - X| of each surface point [m]; displacement_x, _y, _z = one "
        "signed component of x - X [m]; von_mises = von Mises equivalent of the Cauchy stress of the body's "
        "constitutive model [Pa], from each tet's deformation gradient, averaged onto the surface by rest volume"))
    colormap: str = Field("viridis", description="matplotlib colormap name (e.g. viridis, magma, cividis)")
    range: Annotated[list[Annotated[float, Field(ge=-1e12, le=1e12)]], Field(min_length=2, max_length=2)] | None = \
        Field(None, description=("field values at the colormap's low and high ends (low < high); default per frame: "
                                 "min(0, its minimum) to its maximum"))

    @field_validator("colormap")
    @classmethod
    def _known_colormap(cls, name: str) -> str:
        import matplotlib  # the colormap registry; only scenes with a field colour map need it

        if name not in matplotlib.colormaps:
            raise ValueError(f"unknown matplotlib colormap {name!r}; e.g. viridis, plasma, magma, cividis")
        return name

    @model_validator(mode="after")
    def _ordered(self):
        if self.range is not None and not self.range[0] < self.range[1]:
            raise ValueError(f"range must be [low, high] with low < high, found {self.range}")
        return self

    def legend(self) -> dict:
        """The colour bar as the manifest records it."""
        return {"field": self.field, "unit": FIELDS[self.field], "colormap": self.colormap,
                "range": list(self.range) if self.range is not None
                else "per frame: min(0, the frame's minimum) to the frame's maximum"}
