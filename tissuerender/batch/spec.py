"""The batch spec file (TOML), validated like a scene: unknown keys, wrong types and bad ranges are errors
naming the file and the key path (exit 2). docs/batch-format.md documents every key;
tests/test_batch.py checks that it names every field of these classes.

    [batch]
    scene = "base.toml"      # the base scene, relative to the spec file
    sequences = 8
    seed = 1

    [randomise]
    camera_jitter = 0.005    # [m]
    light_radiance = [0.8, 1.25]
    tool_offset = 0.004      # [m]

    [[randomise.materials]]
    object = "block"
    E = [3000.0, 9000.0]
    roughness = [0.3, 0.6]
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_core import PydanticCustomError

from tissuerender.errors import SceneError
from tissuerender.scene import Scene, load_scene
from tissuerender.scene.load import read_toml, validation_error

Range = Annotated[list[Annotated[float, Field(ge=0.0, le=1e12)]], Field(min_length=2, max_length=2)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


def _ordered(rng: list[float] | None) -> list[float] | None:
    if rng is not None and rng[0] > rng[1]:
        raise PydanticCustomError("range_order", "a range [low, high] with low <= high")
    return rng


class BatchInfo(Strict):
    scene: Annotated[str, Field(min_length=1, description="the base scene file, relative to the spec file")]
    sequences: Annotated[int, Field(ge=1, le=1_000_000, description="how many sequences to make")]
    seed: Annotated[int, Field(ge=0, le=2**31 - 1, description=(
        "the batch seed: sequence i's randomisation comes from (seed, i) only"))] = 0


class MaterialRanges(Strict):
    """Uniform ranges [low, high] replacing a body's mechanics (``objects.override``) or optics
    (``objects.optics``) values; each must lie within the scene key's own range (docs/scene-format.md)."""

    object: Annotated[str, Field(min_length=1, description="the name of an object of the base scene")]
    E: Range | None = Field(None, description="Young's modulus [Pa] (bodies)")
    nu: Range | None = Field(None, description="Poisson's ratio (bodies; high < 0.5)")
    density: Range | None = Field(None, description="mass density [kg/m^3] (bodies)")
    roughness: Range | None = Field(None, description="microfacet roughness (0.001 ... 1)")
    ior: Range | None = Field(None, description="index of refraction (1 ... 3)")
    k_sss: Range | None = Field(None, description="subsurface weight (0 ... 1; not for plastic)")

    _ranges_ordered = field_validator("E", "nu", "density", "roughness", "ior", "k_sss")(_ordered)


class Randomise(Strict):
    seed: bool = Field(True, description="give each sequence its own scene seed (noise, jitter), from (seed, i)")
    camera_jitter: Annotated[float, Field(ge=0.0, le=10.0, description=(
        "camera.position moves by a uniform offset in [-j, j] on each axis [m]; look_at stays"))] = 0.0
    light_radiance: Range | None = Field(None, description=(
        "light.radiance is multiplied by one factor drawn uniformly from [low, high]"))
    tool_offset: Annotated[float, Field(ge=0.0, le=10.0, description=(
        "each tool's keyframe path shifts by one uniform offset in [-d, d] on each axis [m]"))] = 0.0
    tool_time_offset: Annotated[float, Field(ge=0.0, le=1e3, description=(
        "each tool's keyframe times shift by one uniform offset in [0, s] [s]"))] = 0.0
    materials: Annotated[list[MaterialRanges], Field(max_length=64, description=(
        "per-object material ranges (table below)"))] = []

    _ranges_ordered = field_validator("light_radiance")(_ordered)


class SpecFile(Strict):
    batch: BatchInfo = Field(description="the base scene, the number of sequences and the seed")
    randomise: Randomise = Field(Randomise(), description="what varies from sequence to sequence")


@dataclass(frozen=True)
class BatchSpec:
    path: Path
    sha256: str
    batch: BatchInfo
    randomise: Randomise
    base: Scene  # the base scene, loaded and validated
    base_data: dict  # its TOML tables, which each sequence's scene starts from


def load_spec(path) -> BatchSpec:
    """Read and validate a batch spec and its base scene; a SceneError naming the file and key on any problem."""
    path = Path(path)
    data = read_toml(path)
    try:
        parsed = SpecFile.model_validate(data)
    except ValidationError as e:
        error = validation_error(path, e)
        error.args = (error.args[0].replace("docs/scene-format.md", "docs/batch-format.md"),)
        raise error from None
    base_path = path.parent / parsed.batch.scene
    if not base_path.is_file():
        raise SceneError(path, "batch.scene", f"expected a scene file, found no file at {base_path}")
    base = load_scene(base_path)
    names = {o.name: o for o in base.objects}
    for i, m in enumerate(parsed.randomise.materials):
        if m.object not in names:
            raise SceneError(path, f"randomise.materials[{i}].object",
                             f"expected one of the base scene's objects ({', '.join(names)}), found {m.object!r}")
        if names[m.object].kind != "body" and (m.E or m.nu or m.density):
            raise SceneError(path, f"randomise.materials[{i}]",
                             f"expected no mechanics ranges (E, nu, density) for {m.object!r}: it is a static surface")
    if parsed.randomise.tool_offset or parsed.randomise.tool_time_offset:
        if not base.tools:
            raise SceneError(path, "randomise.tool_offset", "expected a base scene with tools, found none")
    return BatchSpec(path, hashlib.sha256(path.read_bytes()).hexdigest(), parsed.batch, parsed.randomise, base,
                     read_toml(base_path))
