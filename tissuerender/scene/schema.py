"""The scene-file schema: every key a scene may hold, its type, range and default.

Every table forbids unknown keys (a typo must never silently switch an effect off), numbers must be
finite, and types are strict (``"70"`` is not a number). ``docs/scene-format.md`` documents the same
keys for users; ``tests/test_scene_docs.py`` checks that the two agree.
"""
from __future__ import annotations

import math
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

from tissuerender.scene.camera_schema import CameraKeyframe, CameraLens, check_path, degenerate_view
from tissuerender.scene.bc_schema import HeldComponents
from tissuerender.scene.cut_schema import CUT_MATERIALS, CutSpec
from tissuerender.scene.interaction_schema import ContactSpec, FloorSpec, GraspSpec  # noqa: F401 (ContactSpec: load.SceneFile)
from tissuerender.scene.optics_schema import LayerOverride
from tissuerender.scene.field_schema import FieldColours
from tissuerender.scene.shapes import SHAPES

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Vec2Pos = Annotated[list[Annotated[float, Field(gt=0.0)]], Field(min_length=2, max_length=2)]
RGB = Annotated[list[Annotated[float, Field(ge=0.0, le=1e6)]], Field(min_length=3, max_length=3)]

INTEGRATORS = (*REGISTRY, "none")
FORMATS = ("png", "hdr_npy", "vtu", "exr", "depth_png", "mp4")  # the last three: docs/ground-truth.md
PASSES = ("depth", "normal", "segmentation", "material_coords", "flow", "scene_flow", "tracks")  # docs/ground-truth.md
AXES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class SceneInfo(Strict):
    name: Annotated[str, Field(min_length=1, max_length=200, description="name used in messages and the manifest")]
    seed: Annotated[int, Field(ge=0, le=2**31 - 1, description=(
        "master seed: per-frame seeds derive from it, so the same scene and seed give the same pixels"))] = 0


class Region(Strict):
    """A node set: one face of the body's bounding box (``side``) or an axis-aligned box."""

    side: Literal[AXES] | None = Field(  # type: ignore[valid-type]
        None, description="the nodes on that face of the body's bounding box (or give box_min and box_max)")
    box_min: Vec3 | None = Field(None, description="lower corner of an axis-aligned box in world coordinates [m]; "
                                 "the nodes inside it (with box_max)")
    box_max: Vec3 | None = Field(None, description="upper corner of the box [m] (with box_min)")

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


class FixedRegion(Region, HeldComponents):
    """A region whose nodes are held at rest (in every component, or in some: ``tissuerender.scene.bc_schema``)."""


class Prescribed(Region, HeldComponents):
    """Nodes of a region moved by ``displacement`` [m], ramped linearly from t_start to t_end [s]."""

    displacement: Annotated[Vec3, Field(description="displacement of the region's nodes [m]")]
    t_start: Annotated[float, Field(ge=0.0, description="start of the linear ramp [s]")] = 0.0
    t_end: Annotated[float, Field(ge=0.0, description=(
        "end of the ramp [s]; a step at t_start when t_end <= t_start"))] = 0.0


class Traction(Region):
    """A constant surface traction [Pa] over the region's boundary faces (integrated to nodal forces)."""

    traction: Annotated[Vec3, Field(description=(
        "constant traction [Pa] over the boundary faces whose three nodes lie in the region"))]


class PaintStroke(Strict):
    """A poly6 stiffness stroke (Qian 4.26-4.28): the stiffness multiplier rises by ``amount`` at
    ``centre`` and falls smoothly to nothing at ``radius``."""

    centre: Annotated[Vec3, Field(description="centre of the stroke [m]")]
    radius: Annotated[float, Field(gt=0.0, le=10.0, description="radius h of the poly6 kernel [m]")]
    amount: Annotated[float, Field(gt=-1.0, le=1e4, description=(
        "a: each node within h gets a (1 - v^2/h^2)^3; each tet's E (and both Lame parameters) is multiplied by "
        "1 + the mean weight of its nodes; a stroke that would make a stiffness non-positive is an error"))]


class MaterialOverride(Strict):
    """Replaces values of the preset's mechanics (``materials.mechanics``) for one body."""

    E: Annotated[float, Field(gt=0.0, le=1e9)] | None = Field(None, description="Young's modulus [Pa]")
    nu: Annotated[float, Field(ge=0.0, lt=0.5)] | None = Field(None, description=(
        "Poisson ratio [-]; materials simulated with the stable Neo-Hookean law need nu > 1/8 (its bulk modulus "
        "lambda - mu/3 is not positive below; exit 2 otherwise)"))
    density: Annotated[float, Field(gt=0.0, le=1e5)] | None = Field(None, description="mass density [kg/m^3]")


Unit = Annotated[float, Field(ge=0.0, le=1.0)]
UnitRGB = Annotated[list[Unit], Field(min_length=3, max_length=3)]


class OpticsOverride(LayerOverride):
    """Replaces values of the preset's optics (``materials.optics.OpticalMaterial``) for one object; what
    ``tissuerender lookdev`` prints for a look to keep."""

    albedo: UnitRGB | None = Field(None, description=(
        "diffuse albedo (linear RGB); on a layered material both tissue layers' colours are scaled to give it"))
    roughness: Annotated[float, Field(ge=1e-3, le=1.0)] | None = Field(None, description=(
        "GGX alpha of the tissue's specular lobe (under a layered material's wet coat, which keeps its own)"))
    ior: Annotated[float, Field(ge=1.0, le=3.0)] | None = Field(None, description=(
        "index of refraction (Fresnel F0 = ((n - 1)/(n + 1))^2)"))
    k_sss: Unit | None = Field(None, description="subsurface weight (Qian eq. 6.5); not for plastic")
    sigma: Annotated[list[Annotated[float, Field(gt=0.0, le=1e6)]], Field(min_length=3, max_length=3)] | None = Field(
        None, description="effective attenuation [1/m] of the thickness term exp(-sigma T) (Qian eq. 6.8); not for plastic")
    sss_colour: UnitRGB | None = Field(None, description="subsurface colour (C = sss_colour / pi); not for plastic")

    def values(self) -> dict:
        """The keys the scene sets (None: not set)."""
        return {k: v for k, v in self.model_dump().items() if v is not None}


class ObjectSpec(Strict):
    """A simulated body (``kind = "body"``) or a static surface from a file (``kind = "surface"``)."""

    name: Annotated[str, Field(min_length=1, max_length=200, description="unique among objects")]
    kind: Literal["body", "surface"] = Field("body", description=(
        "a simulated tet-mesh body, or a static surface (a triangle mesh that is only rendered)"))
    material: str = Field(description=(
        "material preset (materials/): liver, kidney, gallbladder, colon_mucosa, small_bowel, fat, fascia, peritoneum, "
        "vessels, plastic; mechanics "
        "and optics together"))
    shape: Literal[SHAPES] | None = Field(None, description=(  # type: ignore[valid-type]
        "procedural body (a body has exactly one of shape or mesh)"))
    size: Vec3 | None = Field(None, description=(
        "bounding box [m] of a box-like shape; default per shape: box (1, 1, 1), beam (2, 0.2, 0.2), cube (2, 2, 2; "
        "equal sides), cylinder ([diameter, diameter, length], axis z; 1, 1, 2), slab (0.2, 0.2, 0.03)"))
    cell_size: Annotated[float, Field(gt=0.0, le=10.0)] | None = Field(None, description=(
        "grid cell [m] of a procedural tet mesh (default min(size)/4, organs scale/6) or of the voxelised surface "
        "of a mesh body (default 1/8 of its smallest extent); a body may have at most 400,000 tets"))
    scale: Annotated[float, Field(gt=0.0, le=1e3)] | None = Field(None, description=(
        "size [m] of an organ shape (liver 0.15, kidney 0.11, gallbladder 0.05 by default); for a mesh file (body or static surface), "
        "a uniform scale of the file's coordinates, applied before position"))
    mesh: str | None = Field(None, description=(
        "path relative to the scene: a body's tet mesh (.msh gmsh 1, 2.2 or 4, .vtu, .vtk unstructured grid, .mesh) "
        "or closed surface (.ply, .obj, .stl, .vtp, .vtk POLYDATA, gmsh 1 .msh of triangles; voxelised into tets of "
        "cell_size, its own triangles drawn, embedded in them); a static surface's triangles (.ply, .obj, .stl, "
        ".vtp; vertex normals and UVs in the file are kept); see docs/meshes.md"))
    position: Vec3 = Field([0.0, 0.0, 0.0], description="translation applied to the mesh [m]")
    render_subdivision: Annotated[int, Field(ge=0, le=3, description=(
        "body: levels of 4-to-1 subdivision of the render surface, embedded in the tets by barycentric coordinates "
        "(organ shapes: a smooth contour of their shape at cell_size / 2**max(1, levels), within scale / 160 to / 64, "
        "instead of the tets' boundary; see docs/meshes.md)"))] = 0
    override: MaterialOverride | None = Field(None, description="body: replace the preset's mechanics (table below)")
    optics: OpticsOverride | None = Field(None, description=(
        "replace optical values of the preset (table below); tissuerender lookdev prints the table for a look"))
    fixed: list[FixedRegion] = Field([], description="body: regions whose nodes are held at rest (table below)")
    prescribed: list[Prescribed] = Field([], description="body: regions moved by a displacement ramp (table below)")
    tractions: list[Traction] = Field([], description="body: regions loaded by a constant traction (table below)")
    floor: FloorSpec | None = Field(None, description="body: a static plane it rests on, with friction (xpbd; table below)")
    cut_material: Literal[CUT_MATERIALS] | None = Field(None, description=(  # type: ignore[valid-type]
        "body: the preset the faces a tool's cut exposes are drawn with (default tissue_cut: darker, wetter "
        "parenchyma; docs/interaction.md, \"Cutting\")"))
    paint: Annotated[list[PaintStroke], Field(max_length=1000)] = Field([], description=(
        "body: heterogeneous stiffness, poly6 strokes (Qian 4.26-4.28; table below)"))
    field_colours: FieldColours | None = Field(None, description=(
        "body: draw its surface coloured by a field (displacement) through a colormap (table below)"))

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
    integrator: Literal[INTEGRATORS] = Field("none", description=(  # type: ignore[valid-type]
        "how bodies move; none renders them at rest"))
    dt: Annotated[float, Field(gt=0.0, le=1.0, description=(
        "simulation step [s]; must divide the frame interval 1/fps (to rounding: abs(n dt - 1/fps) <= 4 n eps / fps), "
        "else exit 2 naming the two nearest steps that do (e.g. 1/48 or 1/72 at 24 fps); each frame advances "
        "n = 1/(fps dt) steps and ends exactly on its time (k - 1)/fps; a render may take at most 2,000,000 steps"))] = 1.0 / 72.0
    substeps: Annotated[int, Field(ge=1, le=1000, description=(
        "substeps per step (xpbd, ebm, cnn, cnn_chainmail, explicit)"))] = 10
    iterations: Annotated[int, Field(ge=1, le=10000, description=(
        "solver iterations per substep (xpbd, ebm, cnn_chainmail)"))] = 10
    gravity: Vec3 = Field([0.0, 0.0, -9.81], description=(
        "gravity [m/s^2]; a non-zero gravity alone makes a scene dynamic"))
    write_vtu: bool = Field(False, description=(
        "also write the simulation state of each frame as .vtu for ParaView (as formats = [..., \"vtu\"])"))
    # each integrator's table is its own scene settings model (sim.integrators: declared once, with the integrator)
    xpbd: XPBDSceneSettings = Field(XPBDSceneSettings(), description="the xpbd integrator's table (below)")
    reference: ReferenceSceneSettings = Field(ReferenceSceneSettings(), description="the reference integrator's table")
    ebm: EBMSceneSettings = Field(EBMSceneSettings(), description="the ebm integrator's table")
    cnn: CNNSceneSettings = Field(CNNSceneSettings(), description="the cnn integrator's table")
    cnn_chainmail: ChainMailSceneSettings = Field(ChainMailSceneSettings(), description="the cnn_chainmail integrator's table")
    explicit: ExplicitSceneSettings = Field(ExplicitSceneSettings(), description="the explicit integrator's table")


class Keyframe(Strict):
    t: Annotated[float, Field(ge=0.0, le=1e6, description="time [s]")]
    position: Annotated[Vec3, Field(description="the tool's position at t [m] (an instrument's: its tip joint)")]
    orientation: Annotated[list[float], Field(min_length=4, max_length=4)] | None = Field(None, description=(
        "grasper / l_hook / mesh: unit quaternion (w, x, y, z) taking the tool frame (an instrument's +z towards the "
        "tip; a mesh tool's file coordinates) to the world, slerped between keyframes (normalised; default: an "
        "instrument's +z turned onto axis, a mesh tool unturned); docs/interaction.md, \"Instruments\", \"Mesh tools\""))
    jaw_deg: Annotated[float, Field(ge=0.0, le=90.0)] | None = Field(None, description=(
        "grasper: jaw opening angle [deg], linear between keyframes (default 30)"))


def _turns(keyframes) -> bool:
    """Whether the orientations of ``keyframes`` (None: unturned) are not all one rotation (q and -q are one)."""
    qs = [(1.0, 0.0, 0.0, 0.0) if k.orientation is None else tuple(k.orientation) for k in keyframes]
    unit = [[c / math.sqrt(sum(v * v for v in q)) for c in q] for q in qs]
    # one rotation: |q0 . q| = 1 up to the rounding of normalising and of the sum (a few ulps)
    return any(abs(sum(a * b for a, b in zip(unit[0], q))) < 1.0 - 1e-12 for q in unit[1:])


class Tool(Strict):
    name: Annotated[str, Field(min_length=1, max_length=200, description="unique among tools")]
    kind: Literal["sphere", "capsule", "grasper", "l_hook", "mesh"] = Field("sphere", description=(
        "rigid probe shape; grasper and l_hook: steel instruments made of capsules; mesh: a closed triangle mesh "
        "file (docs/interaction.md)"))
    radius: Annotated[float, Field(gt=0.0, le=10.0)] | None = Field(None, description=(
        "probe radius [m] (required, except for a mesh)"))
    mesh: str | None = Field(None, description=(
        "kind = \"mesh\": a closed, outward-wound triangle mesh (.obj, .ply, .stl) relative to the scene, its "
        "coordinates [m] relative to the keyframed position, turned by the keyframes' orientation"))
    length: Annotated[float, Field(ge=0.0, le=10.0, description=(
        "capsule segment length [m] (> 0 for a capsule); an instrument's shaft length behind its tip (> 0)"))] = 0.0
    axis: Vec3 = Field([0.0, 0.0, 1.0], description=(
        "capsule axis (non-zero); an instrument's handle-to-tip direction where a keyframe gives no orientation"))
    visible: bool = Field(True, description="render the tool (it pushes tissue only when the scene is simulated)")
    keyframes: Annotated[list[Keyframe], Field(min_length=1, max_length=10000, description=(
        "path, linearly interpolated, times strictly increasing (table below)"))]
    grasp: Annotated[list[GraspSpec], Field(max_length=100)] = Field([], description=(
        "jaws closing on the tissue and opening again (xpbd; table below; docs/interaction.md)"))
    cut: Annotated[list[CutSpec], Field(max_length=100)] = Field([], description=(
        "time windows in which the tool's blade removes the body tets it sweeps through (xpbd; table below; "
        "docs/interaction.md, \"Cutting\")"))

    @model_validator(mode="after")
    def _ordered(self):
        times = [k.t for k in self.keyframes]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError(f"keyframe times must increase strictly, found {times}")
        if self.kind not in ("sphere", "mesh") and self.length <= 0.0:
            raise ValueError(f"a {self.kind} needs length > 0")
        if (self.kind == "mesh") != (self.mesh is not None) or (self.kind != "mesh") == (self.radius is None):
            raise ValueError("a mesh tool needs 'mesh' and takes no radius; every other kind needs 'radius' and no "
                             f"'mesh' (kind {self.kind!r})")
        if self.kind == "mesh" and self.cut:
            raise ValueError("a mesh tool cannot cut: a blade is a sphere, a capsule or an instrument's jaws or hook")
        if self.kind == "mesh" and any(g.radius is None for g in self.grasp):
            raise ValueError("a mesh tool's grasp needs its own radius (the default is 1.5 tool radii)")
        if self.kind == "mesh" and self.grasp and _turns(self.keyframes):
            raise ValueError("a mesh tool whose orientation changes between keyframes cannot grasp: grasped nodes "
                             "keep their offset from the path point and would not turn with the tool; give every "
                             "keyframe the same orientation or none")
        for k in self.keyframes:
            if k.orientation is not None and sum(c * c for c in k.orientation) < 1e-12:
                raise ValueError(f"keyframe t = {k.t}: orientation must be a non-zero quaternion, found {k.orientation}")
        if sum(a * a for a in self.axis) < 1e-12:
            raise ValueError(f"axis must be a non-zero vector, found {self.axis}")
        return self


class Camera(Strict):
    position: Vec3 | None = Field(None, description="laparoscope tip [m] (required unless path is given)")
    look_at: Vec3 | None = Field(None, description=(
        "point in the centre of the view [m] (not equal to position; required unless path is given)"))
    up: Vec3 = Field([0.0, 0.0, 1.0], description=(
        "up direction (not parallel to the view); with a path, the default of each keyframe's up"))
    path: Annotated[list[CameraKeyframe], Field(max_length=10000)] = Field([], description=(
        "a moving laparoscope: keyframed poses, times strictly increasing, linear in position, look_at and up "
        "(table below; instead of position and look_at)"))
    lens: CameraLens | None = Field(None, description=(
        "wide-angle lens distortion and vignetting applied to colour and every pass (table below; "
        "docs/ground-truth.md, \"Lens\"); fov_deg is then the angle the distorted image's width spans; none: a pinhole"))
    fov_deg: Annotated[float, Field(gt=1.0, lt=179.0, description="horizontal field of view [deg]")] = 70.0
    near: Annotated[float, Field(gt=0.0, le=1e3, description="near clip distance [m]")] = 0.005
    far: Annotated[float, Field(gt=0.0, le=1e5, description="far clip distance [m] (> near)")] = 10.0
    focus_distance: Annotated[float, Field(gt=0.0, le=1e5)] | None = Field(None, description=(
        "thin-lens focus distance [m]: the depth_of_field effect's (it must be in the effect chain, and its table "
        "must not set it too)"))
    aperture: Annotated[float, Field(ge=0.0, le=1.0, description=(
        "thin-lens aperture radius [m]: the depth_of_field effect's, as focus_distance"))] = 0.0

    @model_validator(mode="after")
    def _frame(self):
        if self.far <= self.near:
            raise ValueError(f"far ({self.far}) must exceed near ({self.near})")
        if self.path:
            if self.position is not None or self.look_at is not None:
                raise ValueError("with 'path' the pose comes from its keyframes: remove 'position' and 'look_at'")
            check_path(self.path, self.up)
            return self
        if self.position is None or self.look_at is None:
            raise ValueError("give 'position' and 'look_at' (or a keyframed 'path')")
        problem = degenerate_view(self.position, self.look_at, self.up)
        if problem:
            raise ValueError(problem)
        return self


class ImportanceStroke(Strict):
    """A painted light-sampling region (Qian Fig. 6.15): shading points within ``radius`` of ``centre``
    get up to ``multiplier`` times the light samples."""

    centre: Annotated[Vec3, Field(description="centre of the painted region [m]")]
    radius: Annotated[float, Field(gt=0.0, le=10.0, description="radius [m] (smooth poly6 falloff)")]
    multiplier: Annotated[float, Field(ge=1.0, le=64.0, description=(
        "up to multiplier x samples within radius; each sample still weighs A/m, so only noise moves"))]


class Light(Strict):
    attach: Literal["camera", "world"] = Field("camera", description=(
        "at the scope tip (moves with the camera) or placed in the world"))
    size: Vec2Pos = Field([0.01, 0.01], description="rectangle size [m]")
    radiance: RGB = Field([2000.0, 2000.0, 2000.0], description=(
        "emitted radiance [W/(m^2 sr)] (a laparoscope light guide is small and bright: E = L A cos / d^2)"))
    offset: Vec3 = Field([0.0, 0.0, 0.0], description=(
        "camera-attached light: offset [m] in the camera frame (x right, y up, z forward)"))
    position: Vec3 | None = Field(None, description="world light: centre [m] (required)")
    normal: Vec3 | None = Field(None, description="world light: emitting direction (required)")
    up: Vec3 = Field([0.0, 0.0, 1.0], description="world light: orientation of the rectangle's height")
    sampling: Literal["adaptive", "uniform", "importance"] = Field("adaptive", description=(
        "adaptive count m(d) by distance (Qian 6.15-6.16: samples up to 0.08 m, half up to 0.16 m, a quarter "
        "beyond; each sample weighs A/m(d)), uniform (always samples), or painted importance (Qian Fig. 6.15)"))
    samples: Annotated[int, Field(ge=1, le=4096, description=(
        "light samples per point (the maximum m for adaptive sampling)"))] = 16
    importance: Annotated[list[ImportanceStroke], Field(max_length=1000)] = Field([], description=(
        "painted sampling regions for sampling = \"importance\" (table below)"))
    reflection_cone: bool = Field(False, description=(
        "also sample the part of the light inside the specular reflection cone (Qian 6.21, made unbiased: the light "
        "is split into that rectangle and the rest, each sampled with its own A/m weight; the cone's half-angle "
        "comes from the GGX lobe width, where D falls to a tenth of its peak)"))
    cone_samples: Annotated[int, Field(ge=1, le=4096, description=(
        "samples inside the reflection cone per point (with reflection_cone)"))] = 16
    pattern: Literal["blue_noise", "white_noise"] = Field("blue_noise", description=(
        "per-pixel offsets of the light samples: a tiled blue-noise texture (the supersamples of a pixel draw one "
        "interleaved stratified set), or an independent uniform offset per shading point (docs/renderer.md)"))
    estimator: Literal["mc", "ratio"] = Field("ratio", description=(
        "the diffuse lobe's estimate (\"mc\" by default with reflection_cone): the ratio estimator (Heitz, Hill "
        "& McGuire 2018: the closed-form unshadowed irradiance of the rectangle times the sampled (f V)/(n.wi), "
        "exact where the light is unoccluded and the lobe Lambertian, consistent as m grows), or plain Monte Carlo "
        "(sum of f V A/m, unbiased); specular lobes stay Monte Carlo; ratio needs the numba shading pass, so not "
        "with reflection_cone"))
    penumbra_samples: Annotated[int, Field(ge=0, le=4096, description=(
        "needs effects.shadows: pixels whose first shadow rays disagree, and their 8 neighbours, are shaded again "
        "with this many samples per point (at least samples), replacing the first ones; adaptive, so slightly "
        "biased where the first rays all agree inside a penumbra; 0: off; not with reflection_cone"))] = 0

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
    resolution: Annotated[list[Annotated[int, Field(ge=8, le=8192)]], Field(min_length=2, max_length=2, description=(
        "image size [width, height] in pixels"))] = [640, 480]
    frames: Annotated[int, Field(ge=1, le=100000, description="number of frames")] = 1
    fps: Annotated[float, Field(gt=0.0, le=10000.0, description=(
        "frames per second (frame k shows time (k-1)/fps)"))] = 24.0
    formats: Annotated[list[Literal[FORMATS]], Field(min_length=1, description=(  # type: ignore[valid-type]
        "frame_0001.png..., float32 HDR radiance frame_0001.npy, simulation state NAME_0001.vtu (needs a "
        "simulated scene), multi-layer OpenEXR frame_0001.exr (colour and passes), 16-bit depth PNG "
        "passes/depth_0001.png (needs the depth pass), preview.mp4 video (needs png)"))] = ["png"]
    supersampling: Annotated[int, Field(ge=1, le=8, description="N x N samples per pixel, box-filtered")] = 1
    jitter: bool = Field(True, description=(
        "with supersampling > 1, each sample at a seeded random point of its own cell (stratified jitter); false: "
        "the cell centres"))
    passes: Annotated[list[Literal[PASSES]], Field(description=(  # type: ignore[valid-type]
        "ground-truth passes written per frame as passes/<pass>_0001.npy, with cameras.json and labels.json "
        "(docs/ground-truth.md): depth (camera z [m], float32), normal (camera-space unit normals), segmentation "
        "(int32 instance ids), material_coords (rest position [m] of the tissue point seen), flow (optical flow [px] "
        "and occlusion to the neighbouring frames), scene_flow (3D motion [m] of the point seen), tracks (tracks.npz "
        "and its TAP-Vid layouts)"))] = []
    track_points: Annotated[int, Field(ge=1, le=1_000_000, description=(
        "with passes = [..., \"tracks\"]: number of query points sampled (scene seed) on the tissue seen in "
        "frame 1"))] = 256
    track_queries: Annotated[list[Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=3, max_length=3)]],
                             Field(max_length=1_000_000, description=(
        "with passes = [..., \"tracks\"]: the query points as [t, y, x] (frame index from 0, pixel row, pixel "
        "column; the pixel must see tissue or a tool in frame t), tracked instead of sampled ones"))] = []


class EffectsBase(Strict):
    """Renderer switches (each adds stages only when on; docs/scene-format.md, ``[effects]``); the post-effect
    tables are added from ``postfx.EFFECTS`` (see ``effects_model``)."""

    shadows: Annotated[bool, Field(description="shadow rays against a BVH")] = False
    sss: Annotated[bool, Field(description=(
        "thickness-based subsurface term C exp(-sigma T) (Qian eq. 6.8); adds the thickness pass (and the BVH)"))] = False
    sss_thickness: Annotated[Literal["vertex", "pixel"], Field(
        description="with sss: thickness rays from the render surface's vertices, interpolated over each triangle, "
                    "or from every shading point")] = "vertex"
    ao: Annotated[bool, Field(description=(
        "ambient occlusion: the ambient light is scaled by the cosine-weighted visibility of the hemisphere within "
        "ao_distance (ao_samples rays per point against the BVH); needs a non-zero ambient"))] = False
    ambient: Annotated[RGB, Field(description=(
        "uniform environment radiance [W m^-2 sr^-1] (light scattered around the abdomen): adds albedo x ambient "
        "to every visible point"))] = [0.0, 0.0, 0.0]
    ao_distance: Annotated[float, Field(gt=0.0, le=100.0, description="with ao: occlusion ray length [m]")] = 0.02
    ao_samples: Annotated[int, Field(ge=1, le=256, description="with ao: occlusion rays per shading point")] = 8
    mucus_reflection: Annotated[bool, Field(
        description="the wet mucus coat of a layered material (colon_mucosa) reflects the gradient environment, held as "
                    "low-order spherical harmonics (Qian §7.2.2; tissuerender/renderer/sh.py)")] = False
    environment_up: Annotated[RGB, Field(
        description="with mucus_reflection: environment radiance towards environment_axis [W m^-2 sr^-1] (the lit "
                    "cavity in front of the scope)")] = [0.0, 0.0, 0.0]
    environment_down: Annotated[RGB, Field(
        description="with mucus_reflection: environment radiance away from environment_axis [W m^-2 sr^-1] (the "
                    "darker surround)")] = [0.0, 0.0, 0.0]
    environment_axis: Annotated[Vec3, Field(description="with mucus_reflection: the environment gradient's axis (non-zero)")] = [0.0, 0.0, 1.0]
    motion: Annotated[bool, Field(description=(
        "a per-pixel velocity channel for motion blur: not implemented (no post-effect reads it), so true is an "
        "error"))] = False
    backend: Annotated[Literal["auto", "numpy", "osmesa"], Field(
        description="post-effects backend: numpy (reference), osmesa (off-screen OpenGL, needs Debian libosmesa6), "
                    "auto (osmesa when available, else numpy)")] = "auto"
    preset: Annotated[str | None, Field(description=(
        "a camera preset of postfx.CAMERA_PRESETS (hd_scope, old_scope): its effects with their parameters; the "
        "scene's own [effects.NAME] tables override them"))] = None
    order: Annotated[list[str] | None, Field(description=(
        "explicit order of the post-effects (default: postfx.DEFAULT_ORDER); it must list every effect that has a "
        "table or comes from the preset, each once"))] = None

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
                       **{name: (model | None, Field(None, description=(
                           f"the {name} post-effect's parameters (table below; docs/postfx.md); an empty table "
                           "uses the defaults")))
                          for name, model in EFFECTS.items()})
