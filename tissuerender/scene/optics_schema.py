"""The layer keys of a scene's ``[objects.optics]`` table: values of the preset's wet layer stack
(``materials.optics.TissueLayers``; the model in ``tissuerender.renderer.bsdf.mucosa``). Every tissue preset
has a stack; the plastic reference has none and refuses these keys (exit 2)."""
from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

Unit = Annotated[float, Field(ge=0.0, le=1.0)]
UnitRGB = Annotated[list[Unit], Field(min_length=3, max_length=3)]
Absorption = Annotated[list[Annotated[float, Field(ge=0.0, le=1e6)]], Field(min_length=3, max_length=3)]
Alpha = Annotated[float, Field(ge=1e-3, le=1.0)]
Attenuation = Annotated[list[Annotated[float, Field(gt=0.0, le=1e6)]], Field(min_length=3, max_length=3)]


class LayerOverride(BaseModel):
    """Layer-stack values for one object (top to bottom: wet coat, granular lobe, connective layer, deep layer)."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)

    coat_roughness: Alpha | None = Field(None, description=(
        "GGX alpha of the wet coat (mucus / serous film); 0.04-0.1 gives the small sharp wet highlights"))
    coat_ior: Annotated[float, Field(ge=1.0, le=3.0)] | None = Field(None, description=(
        "index of refraction of the coat (water 1.33; exact dielectric Fresnel); the layers under it get the rest"))
    coat_thickness: Annotated[float, Field(ge=0.0, le=0.01)] | None = Field(None, description=(
        "coat thickness [m] for its absorption (serous film ~2e-5, colonic mucus 1e-4 - 8e-4)"))
    coat_absorption: Absorption | None = Field(None, description="coat absorption [1/m] per RGB channel")
    granular_weight: Unit | None = Field(None, description="share of the granular specular lobe under the coat")
    granular_roughness: Alpha | None = Field(None, description=(
        "GGX alpha of the granular lobe (scaled by the texture's roughness map)"))
    connective_colour: UnitRGB | None = Field(None, description="diffuse colour of the connective (upper) layer")
    connective_thickness: Annotated[float, Field(ge=0.0, le=0.01)] | None = Field(None, description=(
        "connective layer thickness [m]; the deep colour shows through exp(-2 absorption thickness)"))
    connective_absorption: Absorption | None = Field(None, description="connective layer absorption [1/m] per RGB channel")
    submucosa_colour: UnitRGB | None = Field(None, description="diffuse colour of the deep (vessel-bearing) layer")
    connective_sss_colour: UnitRGB | None = Field(None, description=(
        "subsurface colour of the connective layer (default: the material's sss_colour); weighted 1 - e in the "
        "thickness term's colour, e = exp(-2 connective_absorption connective_thickness)"))
    connective_sigma: Attenuation | None = Field(None, description=(
        "attenuation [1/m] of the thickness term within the connective layer's thickness (default: the material's "
        "sigma)"))
    submucosa_sss_colour: UnitRGB | None = Field(None, description=(
        "subsurface colour of the deep layer (default: the material's sss_colour); weighted e"))
    submucosa_sigma: Attenuation | None = Field(None, description=(
        "attenuation [1/m] of the thickness term below the connective layer (default: the material's sigma)"))
    vessel_density: Annotated[float, Field(ge=0.0, le=10.0)] | None = Field(None, description=(
        "strength of the vessel trees in the texture (0: none)"))
    bump: Annotated[float, Field(ge=0.0, le=0.1)] | None = Field(None, description=(
        "relief height of the texture's normal map, in texture widths"))
