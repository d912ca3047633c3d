"""The scene-file schema: every key a scene may hold, its type, range and default.

Every table forbids unknown keys (a typo must never silently switch an effect off), numbers must be
finite, and types are strict (``"70"`` is not a number). ``docs/scene-format.md`` documents the same
keys for users; ``tests/test_scene_docs.py`` checks that the two agree.
"""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from postfx.registry import EFFECTS

from sim.integrators import REGISTRY
from sim.integrators.chainmail import ChainMailSceneSettings
from sim.integrators.cnn.settings import CNNSceneSettings
from sim.integrators.ebm.settings import EBMSceneSettings
from sim.integrators.explicit import ExplicitSceneSettings
from sim.integrators.reference import ReferenceSceneSettings
from sim.integrators.xpbd.settings import XPBDSceneSettings

from tissuerender.scene.shapes import SHAPES

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Vec2Pos = Annotated[list[Annotated[float, Field(gt=0.0)]], Field(min_length=2, max_length=2)]
RGB = Annotated[list[Annotated[float, Field(ge=0.0, le=1e6)]], Field(min_length=3, max_length=3)]

INTEGRATORS = (*REGISTRY, "none")
FORMATS = ("png", "hdr_npy", "vtu")
AXES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class SceneInfo(Strict):
    name: Annotated[str, Field(min_length=1, max_length=200)]
    seed: Annotated[int, Field(ge=0, le=2**31 - 1)] = 0


class Region(Strict):
    """A node set: one face of the body's bounding box (``side``) or an axis-aligned box."""

    side: Literal[AXES] | None = None  # type: ignore[valid-type]
    box_min: Vec3 | None = None
    box_max: Vec3 | None = None

    @model_validator(mode="after")
    def _one_selector(self):
        has_box = self.box_min is not None or self.box_max is not None
        if (self.side is None) == (not has_box):
            raise ValueError("give either 'side' or both 'box_min' and 'box_max'")
        if has_box and (self.box_min is None or self.box_max is None):
            raise ValueError("'box_min' and 'box_max' go together")
        if has_box and any(lo > hi for lo, hi in zip(self.box_min, self.box_max)):
            raise ValueError(f"box_min {self.box_min} must not exceed box_max {self.box_max}")
        return self


class Prescribed(Region):
    """Nodes of a region moved by ``displacement`` [m], ramped linearly from t_start to t_end [s]."""

    displacement: Vec3
    t_start: Annotated[float, Field(ge=0.0)] = 0.0
    t_end: Annotated[float, Field(ge=0.0)] = 0.0


class Traction(Region):
    """A constant surface traction [Pa] over the region's boundary faces (integrated to nodal forces)."""

    traction: Vec3


class PaintStroke(Strict):
    """A poly6 stiffness stroke (Qian 4.26-4.28): the stiffness multiplier rises by ``amount`` at
    ``centre`` and falls smoothly to nothing at ``radius``."""

    centre: Vec3
    radius: Annotated[float, Field(gt=0.0, le=10.0)]
    amount: Annotated[float, Field(gt=-1.0, le=1e4)]


class MaterialOverride(Strict):
    E: Annotated[float, Field(gt=0.0, le=1e9)] | None = None
    nu: Annotated[float, Field(ge=0.0, lt=0.5)] | None = None
    density: Annotated[float, Field(gt=0.0, le=1e5)] | None = None


Unit = Annotated[float, Field(ge=0.0, le=1.0)]
UnitRGB = Annotated[list[Unit], Field(min_length=3, max_length=3)]


class OpticsOverride(Strict):
    """Replaces values of the preset's optics (``materials.optics.OpticalMaterial``) for one object; what
    ``tissuerender lookdev`` prints for a look to keep."""

    albedo: UnitRGB | None = None
    roughness: Annotated[float, Field(ge=1e-3, le=1.0)] | None = None
    ior: Annotated[float, Field(ge=1.0, le=3.0)] | None = None
    k_sss: Unit | None = None
    sigma: Annotated[list[Annotated[float, Field(gt=0.0, le=1e6)]], Field(min_length=3, max_length=3)] | None = None
    sss_colour: UnitRGB | None = None

    def values(self) -> dict:
        """The keys the scene sets (None: not set)."""
        return {k: v for k, v in self.model_dump().items() if v is not None}


class ObjectSpec(Strict):
    """A simulated body (``kind = "body"``) or a static surface from a file (``kind = "surface"``)."""

    name: Annotated[str, Field(min_length=1, max_length=200)]
    kind: Literal["body", "surface"] = "body"
    material: str
    shape: Literal[SHAPES] | None = None  # type: ignore[valid-type]
    size: Vec3 | None = None
    cell_size: Annotated[float, Field(gt=0.0, le=10.0)] | None = None
    scale: Annotated[float, Field(gt=0.0, le=1e3)] | None = None
    mesh: str | None = None
    position: Vec3 = [0.0, 0.0, 0.0]
    render_subdivision: Annotated[int, Field(ge=0, le=3)] = 0
    override: MaterialOverride | None = None
    optics: OpticsOverride | None = None
    fixed: list[Region] = []
    prescribed: list[Prescribed] = []
    tractions: list[Traction] = []
    paint: Annotated[list[PaintStroke], Field(max_length=1000)] = []

    @model_validator(mode="after")
    def _geometry_source(self):
        if self.kind == "surface":
            if self.mesh is None:
                raise ValueError("a static surface needs 'mesh' (a .ply, .obj or .stl file)")
            extra = [k for k in ("shape", "size", "cell_size") if getattr(self, k) is not None]
            extra += [k for k in ("fixed", "prescribed", "tractions", "paint") if getattr(self, k)]
            if extra:
                raise ValueError(f"a static surface takes no {', '.join(extra)} (only bodies are simulated)")
        elif (self.shape is None) == (self.mesh is None):
            raise ValueError("a body needs exactly one of 'shape' (procedural) or 'mesh' (a tet-mesh file)")
        return self


class Simulation(Strict):
    integrator: Literal[INTEGRATORS] = "none"  # type: ignore[valid-type]
    dt: Annotated[float, Field(gt=0.0, le=1.0)] = 1.0 / 72.0  # divides the default frame interval 1/24 s (3 steps)
    substeps: Annotated[int, Field(ge=1, le=1000)] = 10
    iterations: Annotated[int, Field(ge=1, le=10000)] = 10
    gravity: Vec3 = [0.0, 0.0, -9.81]
    write_vtu: bool = False
    # each integrator's table is its own scene settings model (sim.integrators: declared once, with the integrator)
    xpbd: XPBDSceneSettings = XPBDSceneSettings()
    reference: ReferenceSceneSettings = ReferenceSceneSettings()
    ebm: EBMSceneSettings = EBMSceneSettings()
    cnn: CNNSceneSettings = CNNSceneSettings()
    cnn_chainmail: ChainMailSceneSettings = ChainMailSceneSettings()
    explicit: ExplicitSceneSettings = ExplicitSceneSettings()


class Keyframe(Strict):
    t: Annotated[float, Field(ge=0.0, le=1e6)]
    position: Vec3


class Tool(Strict):
    name: Annotated[str, Field(min_length=1, max_length=200)]
    kind: Literal["sphere", "capsule"] = "sphere"
    radius: Annotated[float, Field(gt=0.0, le=10.0)]
    length: Annotated[float, Field(ge=0.0, le=10.0)] = 0.0
    axis: Vec3 = [0.0, 0.0, 1.0]
    visible: bool = True
    keyframes: Annotated[list[Keyframe], Field(min_length=1, max_length=10000)]

    @model_validator(mode="after")
    def _ordered(self):
        times = [k.t for k in self.keyframes]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError(f"keyframe times must increase strictly, found {times}")
        if self.kind == "capsule" and self.length <= 0.0:
            raise ValueError("a capsule needs length > 0")
        if sum(a * a for a in self.axis) < 1e-12:
            raise ValueError(f"axis must be a non-zero vector, found {self.axis}")
        return self


class Camera(Strict):
    position: Vec3
    look_at: Vec3
    up: Vec3 = [0.0, 0.0, 1.0]
    fov_deg: Annotated[float, Field(gt=1.0, lt=179.0)] = 70.0
    near: Annotated[float, Field(gt=0.0, le=1e3)] = 0.005
    far: Annotated[float, Field(gt=0.0, le=1e5)] = 10.0
    focus_distance: Annotated[float, Field(gt=0.0, le=1e5)] | None = None
    aperture: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0

    @model_validator(mode="after")
    def _frame(self):
        if self.far <= self.near:
            raise ValueError(f"far ({self.far}) must exceed near ({self.near})")
        d = [a - b for a, b in zip(self.look_at, self.position)]
        if sum(c * c for c in d) < 1e-18:
            raise ValueError("look_at must differ from position")
        cross = [d[1] * self.up[2] - d[2] * self.up[1], d[2] * self.up[0] - d[0] * self.up[2],
                 d[0] * self.up[1] - d[1] * self.up[0]]
        if sum(c * c for c in cross) < 1e-18 * max(sum(u * u for u in self.up), 1e-300):
            raise ValueError(f"up {self.up} must not be parallel to the view direction")
        return self


class ImportanceStroke(Strict):
    """A painted light-sampling region (Qian Fig. 6.15): shading points within ``radius`` of ``centre``
    get up to ``multiplier`` times the light samples."""

    centre: Vec3
    radius: Annotated[float, Field(gt=0.0, le=10.0)]
    multiplier: Annotated[float, Field(ge=1.0, le=64.0)]


class Light(Strict):
    attach: Literal["camera", "world"] = "camera"
    size: Vec2Pos = [0.01, 0.01]
    radiance: RGB = [2000.0, 2000.0, 2000.0]
    offset: Vec3 = [0.0, 0.0, 0.0]
    position: Vec3 | None = None
    normal: Vec3 | None = None
    up: Vec3 = [0.0, 0.0, 1.0]
    sampling: Literal["adaptive", "uniform", "importance"] = "adaptive"
    samples: Annotated[int, Field(ge=1, le=4096)] = 16
    importance: Annotated[list[ImportanceStroke], Field(max_length=1000)] = []
    reflection_cone: bool = False
    cone_samples: Annotated[int, Field(ge=1, le=4096)] = 16
    pattern: Literal["blue_noise", "white_noise"] = "blue_noise"
    estimator: Literal["mc", "ratio"] = "ratio"
    penumbra_samples: Annotated[int, Field(ge=0, le=4096)] = 0

    @model_validator(mode="before")
    @classmethod
    def _estimator_default(cls, data):
        # the ratio estimator is the default, except with the reflection cone (NumPy path), which has none
        if isinstance(data, dict) and data.get("reflection_cone") is True and "estimator" not in data:
            data = {**data, "estimator": "mc"}
        return data

    @model_validator(mode="after")
    def _estimator(self):
        for key, on in (("estimator = \"ratio\"", self.estimator == "ratio"),
                        ("penumbra_samples > 0", self.penumbra_samples > 0)):
            if on and self.reflection_cone:
                raise ValueError(f"{key} runs in the numba shading pass, which the reflection cone does not use: "
                                 "set reflection_cone = false")
        return self

    @model_validator(mode="after")
    def _importance(self):
        if self.sampling == "importance" and not self.importance:
            raise ValueError("sampling = \"importance\" needs painted strokes in 'importance' "
                             "(e.g. importance = [{ centre = [0, 0, 0], radius = 0.02, multiplier = 8 }])")
        if self.importance and self.sampling != "importance":
            raise ValueError("'importance' strokes are only used with sampling = \"importance\"")
        return self

    @model_validator(mode="after")
    def _placement(self):
        if self.attach == "world" and (self.position is None or self.normal is None):
            raise ValueError("a world light needs 'position' and 'normal'")
        if self.attach == "camera" and (self.position is not None or self.normal is not None):
            raise ValueError("a camera-attached light takes 'offset', not 'position'/'normal'")
        return self


class Output(Strict):
    resolution: Annotated[list[Annotated[int, Field(ge=8, le=8192)]], Field(min_length=2, max_length=2)] = [640, 480]
    frames: Annotated[int, Field(ge=1, le=100000)] = 1
    fps: Annotated[float, Field(gt=0.0, le=10000.0)] = 24.0
    formats: Annotated[list[Literal[FORMATS]], Field(min_length=1)] = ["png"]  # type: ignore[valid-type]
    supersampling: Annotated[int, Field(ge=1, le=8)] = 1
    jitter: bool = True


class EffectsBase(Strict):
    """Renderer switches (each adds stages only when on; docs/scene-format.md, ``[effects]``); the post-effect
    tables are added from ``postfx.EFFECTS`` (see ``effects_model``)."""

    shadows: Annotated[bool, Field(description="shadow rays against a BVH")] = False
    sss: Annotated[bool, Field(description="thickness-based subsurface term C exp(-sigma T) (Qian eq. 6.8)")] = False
    sss_thickness: Annotated[Literal["vertex", "pixel"], Field(
        description="thickness rays from the render surface's vertices, or from every shading point")] = "vertex"
    ao: Annotated[bool, Field(description="ambient occlusion of the ambient light; needs a non-zero ambient")] = False
    ambient: Annotated[RGB, Field(description="uniform environment radiance [W m^-2 sr^-1]")] = [0.0, 0.0, 0.0]
    ao_distance: Annotated[float, Field(gt=0.0, le=100.0, description="occlusion ray length [m]")] = 0.02
    ao_samples: Annotated[int, Field(ge=1, le=256, description="occlusion rays per shading point")] = 8
    mucus_reflection: Annotated[bool, Field(
        description="the mucus coat reflects the gradient environment (Qian §7.2.2)")] = False
    environment_up: Annotated[RGB, Field(
        description="environment radiance towards environment_axis [W m^-2 sr^-1]")] = [0.0, 0.0, 0.0]
    environment_down: Annotated[RGB, Field(
        description="environment radiance away from environment_axis [W m^-2 sr^-1]")] = [0.0, 0.0, 0.0]
    environment_axis: Annotated[Vec3, Field(description="the environment gradient's axis (non-zero)")] = [0.0, 0.0, 1.0]
    motion: Annotated[bool, Field(description="per-pixel velocity channel")] = False
    backend: Annotated[Literal["auto", "numpy", "osmesa"], Field(
        description="post-effects backend: NumPy reference, off-screen OpenGL, or OpenGL when available")] = "auto"
    preset: Annotated[str | None, Field(description="a camera preset of postfx.CAMERA_PRESETS")] = None
    order: Annotated[list[str] | None, Field(description="explicit order of the post-effects")] = None

    @model_validator(mode="after")
    def _reflection_needs_an_environment(self):
        if self.mucus_reflection and not any(v > 0.0 for v in self.environment_up + self.environment_down):
            raise ValueError("mucus_reflection reflects the environment, but environment_up and environment_down "
                             "are both [0, 0, 0]: expected a non-zero environment radiance")
        if not any(abs(v) > 0.0 for v in self.environment_axis):
            raise ValueError("environment_axis must not be [0, 0, 0]")
        return self

    @model_validator(mode="after")
    def _ao_needs_ambient(self):
        if self.ao and not any(v > 0.0 for v in self.ambient):
            raise ValueError("ao darkens the ambient light, but ambient is [0, 0, 0]: expected a non-zero "
                             "ambient radiance (e.g. ambient = [0.5, 0.5, 0.5])")
        return self


# The [effects] table: EffectsBase plus one optional [effects.NAME] table per post-effect of the registry,
# validated by that effect's own parameter model (declared once, in its postfx module).
Effects = create_model("Effects", __base__=EffectsBase,
                       **{name: (model | None, None) for name, model in EFFECTS.items()})
