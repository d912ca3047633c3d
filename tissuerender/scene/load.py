"""Reading a scene file: TOML -> validated :class:`Scene`, or a :class:`SceneError` naming the key.

Checks run in order: the file exists and is UTF-8 TOML; every table matches ``schema`` (unknown
keys, wrong types, out-of-range and non-finite numbers are errors); then cross-references (material
presets, mesh files next to the scene, effect names, unique names) and size limits that would make
a render hang (tet counts, step counts).
"""
from __future__ import annotations

import hashlib
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, ValidationError

import materials
import postfx
from materials.optics import with_overrides
from sim.mesh.io import SURFACE_SUFFIXES, TET_SUFFIXES
from tissuerender.errors import SceneError
from tissuerender.scene import schema
from tissuerender.scene.shapes import estimated_tets
from tissuerender.scene.unused import check_every_option_has_an_effect

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

MAX_TETS = 400_000
MAX_SIM_STEPS = 2_000_000


class SceneFile(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)

    scene: schema.SceneInfo = Field(description="the scene's name and seed")
    objects: Annotated[list[schema.ObjectSpec], Field(min_length=1, max_length=64, description=(
        "bodies (simulated tet meshes) and static surfaces (rendered triangle meshes)"))]
    simulation: schema.Simulation = Field(schema.Simulation(), description="how bodies move")
    tools: Annotated[list[schema.Tool], Field(max_length=16, description=(
        "rigid probes on keyframed paths: drawn, and pushing simulated tissue"))] = []
    contacts: Annotated[list[schema.ContactSpec], Field(max_length=64, description=(
        "pairs of objects that cannot pass through each other, with friction (xpbd; table below)"))] = []
    camera: schema.Camera = Field(description="the laparoscope's view")
    light: schema.Light = Field(schema.Light(), description="a rectangular area light")
    effects: dict = Field({}, description="renderer switches and post-effect tables (validated as schema.Effects)")
    output: schema.Output = Field(schema.Output(), description="what to write")


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``path`` is where it was read from (mesh paths resolve against its folder)."""

    path: Path
    sha256: str
    info: schema.SceneInfo
    objects: tuple[schema.ObjectSpec, ...]
    simulation: schema.Simulation
    tools: tuple[schema.Tool, ...]
    camera: schema.Camera
    light: schema.Light
    effects: schema.EffectsBase
    output: schema.Output
    contacts: tuple = ()  # ContactSpec: body-body and body-surface contact (tissuerender.contacts)

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def seed(self) -> int:
        return self.info.seed

    @property
    def width(self) -> int:
        return self.output.resolution[0]

    @property
    def height(self) -> int:
        return self.output.resolution[1]

    @property
    def steps_per_frame(self) -> int:
        """Simulation steps per frame interval: ``1 / (fps dt)``, a whole number in a loaded scene (``load_scene``
        rejects a ``simulation.dt`` that does not divide the frame interval)."""
        return max(1, round(1.0 / (self.output.fps * self.simulation.dt)))

    def resolve(self, relative: str) -> Path:
        p = Path(relative)
        return p if p.is_absolute() else (self.path.parent / p)

    def motion_sources(self) -> list[str]:
        """What makes a body move: tools, prescribed displacements, tractions, gravity on free nodes."""
        bodies = [o for o in self.objects if o.kind == "body"]
        if not bodies:
            return []
        sources = [f"tools ({', '.join(t.name for t in self.tools)})"] if self.tools else []
        for o in bodies:
            sources += [f"objects.{o.name}.{k}" for k in ("prescribed", "tractions") if getattr(o, k)]
        if any(abs(g) > 0.0 for g in self.simulation.gravity):
            sources.append("simulation.gravity")
        return sources

    def why_not_simulated(self) -> str | None:
        """Why no body is simulated (the plan's reason), or None when the scene is simulated."""
        if not any(o.kind == "body" for o in self.objects):
            return "no simulated bodies"
        if self.simulation.integrator == "none":
            return "simulation.integrator = \"none\""
        if not self.motion_sources():
            return "static scene: no tool, load, prescribed motion or gravity moves a body"
        return None

    def simulated(self) -> bool:
        return self.why_not_simulated() is None

    def effect_chain(self, feed_camera: bool = True) -> list[tuple[str, BaseModel]]:
        """The post-effects to run, in order: explicit ``order``, else the preset's, else the default.
        ``camera.focus_distance`` / ``camera.aperture``, when the scene sets them, are the depth of field's."""
        listed = {name: getattr(self.effects, name) for name in postfx.EFFECTS if getattr(self.effects, name) is not None}
        preset = list(postfx.CAMERA_PRESETS[self.effects.preset]) if self.effects.preset else []
        chain: dict[str, BaseModel] = {}
        for name, params in preset:
            chain[name] = postfx.EFFECTS[name].model_validate(params)
        chain.update(listed)  # the scene's own tables override the preset's parameters
        lens = {k: getattr(self.camera, k) for k in ("focus_distance", "aperture") if k in self.camera.model_fields_set}
        if feed_camera and lens and "depth_of_field" in chain:
            dof = chain["depth_of_field"]
            chain["depth_of_field"] = type(dof).model_validate({**dof.model_dump(), **lens})
        order = self.effects.order or [n for n in postfx.DEFAULT_ORDER if n in chain]
        return [(name, chain[name]) for name in order]


def _key_path(loc) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def short_repr(value, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def validation_error(path: Path, err: ValidationError, prefix: str = "") -> SceneError:
    errors = err.errors(include_url=False)
    first = errors[0]
    key = _key_path(((prefix,) if prefix else ()) + tuple(first["loc"]))
    kind = first["type"]
    if kind == "extra_forbidden":
        msg = f"unknown key (found {short_repr(first['input'])}); check its spelling against docs/scene-format.md"
    elif kind == "missing":
        msg = "missing required key"
    else:
        msg = f"expected {first['msg'][0].lower() + first['msg'][1:]}, found {short_repr(first.get('input'))}"
    if len(errors) > 1:
        msg += f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})"
    return SceneError(path, key or None, msg)


def read_toml(path: Path) -> dict:
    if not path.exists():
        raise SceneError(path, None, "no such file")
    if not path.is_file():
        raise SceneError(path, None, "not a regular file")
    raw = path.read_bytes()
    if not raw.strip():
        raise SceneError(path, None, "the file is empty; expected a TOML scene with [scene], [[objects]] and [camera]")
    if b"\x00" in raw[:4096]:
        raise SceneError(path, None, "binary content; expected a UTF-8 TOML text file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(path, None, f"not UTF-8 text (bad byte at offset {e.start}); expected a TOML file") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(path, None, f"TOML syntax error: {e}") from None
    except RecursionError:
        raise SceneError(path, None, "TOML nesting too deep") from None


def load_scene(path) -> Scene:
    """Read and validate a scene file; raise :class:`SceneError` with the key path on any problem."""
    path = Path(path)
    data = read_toml(path)
    return scene_from_data(data, path, hashlib.sha256(path.read_bytes()).hexdigest())


def scene_from_data(data: dict, path, sha256: str) -> Scene:
    """Validate a scene given as the parsed TOML tables (``tissuerender lookdev`` builds its stage this
    way); ``path`` names it in messages and anchors relative mesh paths, ``sha256`` identifies it."""
    path = Path(path)
    try:
        parsed = SceneFile.model_validate(data)
    except ValidationError as e:
        raise validation_error(path, e) from None
    try:
        effects = schema.Effects.model_validate(parsed.effects)
    except ValidationError as e:
        raise validation_error(path, e, "effects") from None
    scene = Scene(
        path=path,
        sha256=sha256,
        info=parsed.scene,
        objects=tuple(parsed.objects),
        simulation=parsed.simulation,
        # a mesh tool's file resolved against the scene's folder (its probe and drawing are built from the tool alone)
        tools=tuple(t.model_copy(update={"mesh": str(path.parent / t.mesh)}) if t.mesh else t for t in parsed.tools),
        camera=parsed.camera,
        light=parsed.light,
        effects=effects,
        output=parsed.output,
        contacts=tuple(parsed.contacts),
    )
    _check_references(scene)
    return scene


def _check_references(scene: Scene) -> None:
    p = scene.path
    names = set()
    for i, obj in enumerate(scene.objects):
        key = f"objects[{i}]"
        if obj.name in names:
            raise SceneError(p, f"{key}.name", f"expected a unique object name, found {obj.name!r} twice")
        names.add(obj.name)
        if obj.material not in materials.PRESET_NAMES:
            raise SceneError(p, f"{key}.material",
                             f"expected one of {', '.join(materials.PRESET_NAMES)}, found {obj.material!r}")
        if obj.optics is not None:
            try:
                with_overrides(materials.get_preset(obj.material).optics, obj.optics.values())
            except ValueError as e:
                k, _, msg = str(e).partition(": ")
                raise SceneError(p, f"{key}.optics.{k}", f"{msg} (material {obj.material!r})") from None
        if obj.mesh is not None:
            mesh_path = scene.resolve(obj.mesh)
            suffixes = SURFACE_SUFFIXES if obj.kind == "surface" else TET_SUFFIXES + SURFACE_SUFFIXES
            if mesh_path.suffix.lower() not in suffixes:
                raise SceneError(p, f"{key}.mesh", f"expected a {'/'.join(suffixes)} file, found {obj.mesh!r}")
            if not mesh_path.is_file():
                raise SceneError(p, f"{key}.mesh", f"mesh file not found: {mesh_path}")
        if obj.shape is not None:
            try:
                n = estimated_tets(obj)
            except ValueError as e:
                raise SceneError(p, key, str(e)) from None
            if n > MAX_TETS:
                raise SceneError(p, f"{key}.cell_size",
                                 f"expected at most {MAX_TETS} tets, found about {n} for this size and cell size")
    for i, tool in enumerate(scene.tools):
        if tool.mesh is not None and (Path(tool.mesh).suffix.lower() not in SURFACE_SUFFIXES
                                      or not scene.resolve(tool.mesh).is_file()):
            raise SceneError(p, f"tools[{i}].mesh", f"expected a {'/'.join(SURFACE_SUFFIXES)} file, found {tool.mesh!r}"
                             f" ({scene.resolve(tool.mesh)} {'exists' if scene.resolve(tool.mesh).is_file() else 'not found'})")
    tool_names = [t.name for t in scene.tools]
    if len(set(tool_names)) != len(tool_names):
        raise SceneError(p, "tools", f"expected unique tool names, found {tool_names}")
    sim = scene.simulation
    if sim.integrator != "none":
        # n steps of dt must end exactly on the frame time (k - 1) / fps, where the renderer draws the tools. Rounding
        # allowed: dt and 1/fps are each within half an ulp of their decimal values, and the integrators add the n
        # steps one by one (each addition rounds by half an ulp of a time <= the interval): |n dt - 1/fps| <= 4 n eps / fps
        frame_interval = 1.0 / scene.output.fps
        ratio = frame_interval / sim.dt
        n = round(ratio)
        if n < 1 or abs(n * sim.dt - frame_interval) > 4.0 * n * sys.float_info.epsilon * frame_interval:
            fps = scene.output.fps
            options = [f"1/{k * fps:g} = {1.0 / (k * fps)!r}" for k in sorted({max(1, math.floor(ratio)), math.ceil(ratio)})]
            raise SceneError(p, "simulation.dt",
                             f"expected a step that divides the frame interval 1/{fps:g} s = {frame_interval!r} s "
                             f"(output.fps = {fps:g}) into whole steps, found {sim.dt!r} ({ratio:.4g} steps per frame); "
                             f"use {' or '.join(options)}")
        total = scene.steps_per_frame * scene.output.frames
        if total > MAX_SIM_STEPS:
            raise SceneError(p, "simulation.dt",
                             f"expected at most {MAX_SIM_STEPS} simulation steps in all, found {total}")
    eff = scene.effects
    if eff.preset is not None and eff.preset not in postfx.CAMERA_PRESETS:
        raise SceneError(p, "effects.preset",
                         f"expected one of {', '.join(postfx.CAMERA_PRESETS)}, found {eff.preset!r}")
    if eff.order is not None:
        available = set(postfx.CAMERA_PRESETS.get(eff.preset, ()) and [n for n, _ in postfx.CAMERA_PRESETS[eff.preset]])
        available |= {n for n in postfx.EFFECTS if getattr(eff, n) is not None}
        for j, name in enumerate(eff.order):
            if name not in postfx.EFFECTS:
                raise SceneError(p, f"effects.order[{j}]",
                                 f"expected one of {', '.join(postfx.EFFECTS)}, found {name!r}")
            if name not in available:
                raise SceneError(p, f"effects.order[{j}]",
                                 f"{name!r} is ordered but has no [effects.{name}] table or preset entry")
        if len(set(eff.order)) != len(eff.order):
            raise SceneError(p, "effects.order", f"expected each effect once, found {eff.order}")
        for name in postfx.EFFECTS:  # in registry order, so the message is deterministic
            if name in available and name not in eff.order:
                source = f"an [effects.{name}] table" if getattr(eff, name) is not None else f"an entry in preset {eff.preset!r}"
                raise SceneError(p, "effects.order", f"{name!r} has {source} but is missing from the order, so it would "
                                 f"not run: list it in order, or remove it")
    check_every_option_has_an_effect(scene)
