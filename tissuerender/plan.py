"""The plan: which stages a scene needs, and why — derived from the scene alone.

"Simulate only the effects a scene calls for": the pipeline builds and runs a stage only when the plan
lists it, and records what actually ran (``tissuerender.stages.StageRecorder``) in the manifest, so
tests can prove that an unplanned stage never runs.

>>> # tissuerender plan scenes/default.toml  prints one line per stage with its reason
"""
from __future__ import annotations

from dataclasses import dataclass

import materials
import postfx
from sim.integrators import supported_by, supports
from tissuerender.scene import Scene
from tissuerender.scene.schema import PASSES


@dataclass(frozen=True)
class Stage:
    name: str
    reason: str


@dataclass(frozen=True)
class Plan:
    stages: tuple[Stage, ...]
    skipped: tuple[Stage, ...]

    def __contains__(self, name: str) -> bool:
        return any(s.name == name for s in self.stages)

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.stages]

    def describe(self) -> str:
        width = max(len(s.name) for s in self.stages + self.skipped)
        lines = ["stages that will run:"]
        lines += [f"  {s.name:<{width}}  {s.reason}" for s in self.stages]
        if self.skipped:
            lines.append("stages that will not run:")
            lines += [f"  {s.name:<{width}}  {s.reason}" for s in self.skipped]
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"stages": {s.name: s.reason for s in self.stages}, "skipped": {s.name: s.reason for s in self.skipped}}


def _bodies(scene: Scene):
    return [o for o in scene.objects if o.kind == "body"]


def motion_sources(scene: Scene) -> list[str]:
    """What makes a body move: tools, prescribed displacements, tractions, gravity on free nodes."""
    return scene.motion_sources()


def make_plan(scene: Scene) -> Plan:
    run: list[Stage] = []
    skip: list[Stage] = []

    def decide(name: str, needed: bool, why: str, why_not: str) -> None:
        (run if needed else skip).append(Stage(name, why if needed else why_not))

    bodies = _bodies(scene)
    surfaces = [o for o in scene.objects if o.kind == "surface"]
    integrator = scene.simulation.integrator
    movers = motion_sources(scene)
    simulate = bool(bodies) and integrator != "none" and bool(movers)

    decide("mesh", bool(bodies), f"tet meshes for bodies: {', '.join(o.name for o in bodies)}", "no simulated bodies")
    decide("load_surface", bool(surfaces), f"static surfaces: {', '.join(o.name for o in surfaces)}",
           "no static surfaces")
    if not bodies:
        why_not = "no simulated bodies"
    elif integrator == "none":
        why_not = "simulation.integrator = \"none\""
    else:
        why_not = "static scene: no tool, load, prescribed motion or gravity moves a body"
    decide("simulate", simulate, f"{integrator} integrator driven by {', '.join(movers)}", why_not)
    mech = [materials.get_preset(o.material).mechanics for o in bodies]
    viscous = simulate and any(m.viscoelastic for m in mech)
    integrator_settings = getattr(scene.simulation, integrator, None)  # None for "none"
    decide("prony_state", viscous and supports(integrator, "prony", integrator_settings),
           "a body's material is viscoelastic (Prony series)",
           (f"the {integrator} integrator has no viscoelastic terms: the Prony series is ignored "
            f"(supported by {', '.join(supported_by('prony'))})") if viscous else
           ("no simulated viscoelastic material" if simulate else "no simulation"))
    fibred = simulate and any(m.fibre is not None for m in mech)
    fibre_ok = supports(integrator, "fibres", integrator_settings)
    decide("fibre_terms", fibred and fibre_ok, "a body's material is anisotropic",
           (f"the {integrator} integrator has no fibre terms: the material is treated as isotropic "
            f"(supported by {', '.join(supported_by('fibres'))})") if fibred else
           ("no simulated anisotropic material" if simulate else "no simulation"))
    floors = any(o.kind == "body" and o.floor is not None for o in scene.objects)  # issue 21 item 4
    decide("contact", simulate and (bool(scene.tools) or floors or bool(scene.contacts)),
           "tools, floors or contacts touch the tissue",
           "no tools" if not scene.tools else "no simulation")
    decide("embed", simulate, "render surfaces follow the simulated tets", "render surfaces stay at rest")
    decide("write_vtu", simulate and ("vtu" in scene.output.formats or scene.simulation.write_vtu),
           "output.formats lists vtu", "vtu not requested" if simulate else "no simulation")

    eff = scene.effects
    decide("raster", True, "every frame is rasterised into the G-buffer", "")
    decide("velocity_channel", eff.motion, "effects.motion", "effects.motion = false")
    decide("bvh", eff.shadows or eff.sss or eff.ao,
           "needed by " + ", ".join(f"effects.{k}" for k in ("shadows", "sss", "ao") if getattr(eff, k)),
           "shadows, sss and ao are off")
    decide("shadow_rays", eff.shadows, "effects.shadows", "effects.shadows = false")
    decide("thickness", eff.sss, "needed by effects.sss (thickness map from rays against the normal)",
           "effects.sss = false")
    decide("ao", eff.ao, "effects.ao", "effects.ao = false")
    decide("mucus_reflection", eff.mucus_reflection, "effects.mucus_reflection (SH environment term)",
           "effects.mucus_reflection = false")
    decide("shade", True, f"area light, {scene.light.samples} samples ({scene.light.sampling})", "")
    decide("lens", scene.camera.lens is not None, "camera.lens: a wider pinhole remapped to the distorted image",
           "no camera.lens (a pinhole)")
    listed = [n for n, _ in scene.effect_chain()]  # in the order they run
    for name in listed + [n for n in postfx.EFFECTS if n not in listed]:
        decide(f"postfx.{name}", name in listed, f"effects.{name} ({eff.backend} backend)", "not listed in effects")
    decide("write_png", "png" in scene.output.formats, "output.formats lists png", "png not requested")
    decide("write_hdr", "hdr_npy" in scene.output.formats, "output.formats lists hdr_npy", "hdr_npy not requested")
    decide("write_exr", "exr" in scene.output.formats, "output.formats lists exr (colour and passes as layers)",
           "exr not requested")
    decide("write_depth_png", "depth_png" in scene.output.formats, "output.formats lists depth_png",
           "depth_png not requested")
    passes = scene.output.passes
    # ground truth (docs/ground-truth.md): one raster at the output resolution (pixel centres) feeds every pass
    decide("passes.raster", bool(passes), f"output.passes lists {', '.join(passes)}", "no output.passes")
    for name in PASSES:
        decide(f"passes.{name}", name in passes, f"output.passes lists {name}", f"{name} not in output.passes")
    decide("write_passes", bool(passes), "passes/<pass>_NNNN.npy, cameras.json and labels.json",
           "no output.passes")
    motion = [name for name in ("flow", "scene_flow", "tracks") if name in passes]
    decide("write_geometry", bool(motion), f"passes/geometry_NNNN.npz: the render geometry {', '.join(motion)} "
           "are computed from", "no flow, scene_flow or tracks in output.passes")
    decide("write_flow_files", "flow" in passes, "output.passes lists flow: also as .flo and KITTI PNG",
           "flow not in output.passes")
    decide("write_mp4", "mp4" in scene.output.formats, "output.formats lists mp4 (preview.mp4 from the PNGs)",
           "mp4 not requested")
    return Plan(stages=tuple(run), skipped=tuple(skip))
