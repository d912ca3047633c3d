"""Every option a scene sets must change the render: one that would be accepted and then ignored is an error
naming its key (issue 16, "nothing silent").

Validation of each table on its own (``schema``) cannot see these: whether a key does anything depends on
other keys (``light.penumbra_samples`` only with ``effects.shadows``, ``cell_size`` only for a procedural or
voxelised body, an integrator's table only when that integrator is selected). A key counts as *set* when the
scene file names it (pydantic's ``model_fields_set``), so a default never raises; a value that switches
something on (``effects.motion = true``, ``penumbra_samples > 0``) counts as set whatever it is.
"""
from __future__ import annotations

import materials
from sim.integrators import REGISTRY
from sim.mesh.io import is_surface_file
from tissuerender.errors import SceneError
from tissuerender.scene.cut_schema import check_cut
from tissuerender.scene.interaction_schema import check_interaction

# [effects] keys that act only through another switch: key -> (the switch, what the key does)
EFFECT_DEPENDS = {
    "sss_thickness": "sss",
    "ao_distance": "ao",
    "ao_samples": "ao",
    "environment_up": "mucus_reflection",
    "environment_down": "mucus_reflection",
    "environment_axis": "mucus_reflection",
}


def _set(model) -> set[str]:
    return set(model.model_fields_set)


def check_every_option_has_an_effect(scene) -> None:
    """Raise :class:`SceneError` naming the first key of ``scene`` (a ``load.Scene``) that would have no effect."""
    for check in (_objects, _simulation, _tools, _camera, _light, _effects, _output, check_interaction,
                  check_cut):
        problem = check(scene)
        if problem is not None:
            key, message = problem
            raise SceneError(scene.path, key, message)


def _objects(scene):
    for i, obj in enumerate(scene.objects):
        key = f"objects[{i}]"
        given = _set(obj)
        if obj.kind == "surface":
            for name in ("render_subdivision", "override", "field_colours"):
                if name in given:
                    return f"{key}.{name}", (f"a static surface is rendered as its file's triangles and never "
                                             f"simulated: {name!r} has no effect on it (only bodies take it); remove it")
        elif obj.mesh is not None:
            tet_file = not is_surface_file(scene.resolve(obj.mesh))
            unused = ("size", "cell_size") if tet_file else ("size",)
            for name in unused:
                if name in given:
                    how = ("a body read from a tet-mesh file keeps the file's nodes as they are" if tet_file else
                           "a body voxelised from a surface file keeps the file's coordinates (only cell_size, "
                           "the voxel size, applies)")
                    return f"{key}.{name}", f"{how}: {name!r} has no effect; remove it (or use 'scale')"
    return None


def _simulation(scene):
    sim = scene.simulation
    given = _set(sim)
    tables = set(REGISTRY)
    if sim.integrator == "none":
        for name in ("dt", "substeps", "iterations", "gravity", "write_vtu", *sorted(tables)):
            if name in given:
                return f"simulation.{name}", ("has no effect with integrator = \"none\" (nothing is simulated); "
                                              "choose an integrator or remove it")
        for i, obj in enumerate(scene.objects):
            # `fixed` is accepted: it holds nodes at rest, as every node already is without a simulation
            for name in ("prescribed", "tractions", "paint", "override"):
                if getattr(obj, name):
                    return f"objects[{i}].{name}", ("acts on the simulation, and simulation.integrator = \"none\": it "
                                                    "has no effect; choose an integrator or remove it")
        return None
    for name in sorted(tables - {sim.integrator}):
        if name in given:
            return f"simulation.{name}", (f"the table of an integrator that is not selected (integrator = "
                                          f"{sim.integrator!r}) has no effect; remove it")
    fields = REGISTRY[sim.integrator].settings.model_fields
    for name in ("substeps", "iterations"):
        description = fields[name].description or ""
        if name in given and description.startswith("ignored"):
            return f"simulation.{name}", f"the {sim.integrator} integrator ignores it ({description}); remove it"
    table = getattr(sim, sim.integrator)
    table_given = _set(table)
    if sim.integrator == "xpbd":
        for name in ("solver", "coupled"):
            if name in table_given and table.material == "model":
                return f"simulation.xpbd.{name}", ("material = \"model\" projects one energy constraint per tet by "
                                                   "coloured Gauss-Seidel sweeps: it has no solver choice or constraint "
                                                   "coupling; remove it")
        if "relaxation" in table_given and table.solver != "jacobi":
            return "simulation.xpbd.relaxation", "only the Jacobi solver relaxes its steps: set solver = \"jacobi\" or remove it"
        green = {"green_stretch_min", "green_stretch_max", "shear_max", "strain_hold"} & table_given
        for name in ("limit_frame", "limit_compliance"):
            if name in table_given and not green:
                return f"simulation.xpbd.{name}", ("shapes the Green-strain limits, but none is set (green_stretch_min, "
                                                   "green_stretch_max, shear_max or strain_hold); remove it")
        if "limit_axes" in table_given and not green & {"green_stretch_min", "green_stretch_max"}:
            return "simulation.xpbd.limit_axes", ("chooses the axes of green_stretch_min / green_stretch_max, and neither "
                                                  "is set; remove it")
    if sim.integrator == "cnn" and table.force_model != "energy":
        for name in ("energy_rho", "energy_gradient"):
            if name in table_given:
                return f"simulation.cnn.{name}", "only the energy force model uses it: set force_model = \"energy\" or remove it"
    return None


def _tools(scene):
    for i, tool in enumerate(scene.tools):
        given = _set(tool)
        if tool.kind in ("sphere", "mesh"):
            for name in ("length", "axis"):
                if name in given:
                    return f"tools[{i}].{name}", f"a {tool.kind} has no axis or length (only a capsule); remove it"
        instrument = tool.kind in ("grasper", "l_hook")
        for j, k in enumerate(tool.keyframes):
            for name in ("orientation", "jaw_deg"):
                turns = instrument or tool.kind == "mesh"
                if name in _set(k) and not (turns if name == "orientation" else tool.kind == "grasper"):
                    owner = "an instrument or a mesh tool" if name == "orientation" else "a grasper"
                    return f"tools[{i}].keyframes[{j}].{name}", (
                        f"a tool of kind {tool.kind!r} has no {name} (only {owner}); remove it")
        if instrument and "axis" in given and all(k.orientation is not None for k in tool.keyframes):
            return f"tools[{i}].axis", "every keyframe gives an orientation, so the axis is never used; remove it"
        if not tool.visible and not scene.simulated():
            return f"tools[{i}].visible", ("an invisible tool acts only by pushing simulated tissue, and this scene "
                                           "simulates nothing: the tool has no effect")
    return None


def _camera(scene):
    cam = scene.camera
    if cam.path and "up" in _set(cam) and all(k.up is not None for k in cam.path):
        return "camera.up", "every camera.path keyframe gives its own 'up', so it has no effect; remove it"
    given = _set(scene.camera) & {"focus_distance", "aperture"}
    if not given:
        return None
    in_chain = {name: params for name, params in scene.effect_chain(feed_camera=False)}
    dof = in_chain.get("depth_of_field")
    for name in sorted(given):
        if dof is None:
            return f"camera.{name}", ("only the depth_of_field post-effect uses the lens's focus and aperture, and it is "
                                      "not in the effect chain: add [effects.depth_of_field] or remove the key")
        table = getattr(scene.effects, "depth_of_field", None)
        if table is not None and name in table.model_fields_set:
            return f"camera.{name}", (f"set twice: also effects.depth_of_field.{name}; the camera's value feeds the "
                                      "depth of field, so keep only one")
    return None


def _light(scene):
    light = scene.light
    given = _set(light)
    if light.attach == "world" and "offset" in given:
        return "light.offset", "a world light is placed by 'position' and 'normal'; 'offset' (camera-attached lights only) has no effect"
    if light.attach == "camera" and "up" in given:
        return "light.up", "a camera-attached light is oriented by the camera; 'up' (world lights only) has no effect"
    if "cone_samples" in given and not light.reflection_cone:
        return "light.cone_samples", "only the reflection cone uses it: set reflection_cone = true or remove it"
    if light.penumbra_samples > 0 and not scene.effects.shadows:
        return "light.penumbra_samples", ("penumbrae come from shadow rays, which are off: set effects.shadows = true "
                                          "or penumbra_samples = 0")
    return None


def _effects(scene):
    eff = scene.effects
    given = _set(eff)
    if eff.motion:
        return "effects.motion", ("not implemented: no post-effect reads the velocity channel (there is no motion "
                                  "blur); remove it")
    for name, switch in EFFECT_DEPENDS.items():
        if name in given and not getattr(eff, switch):
            return f"effects.{name}", f"only effects.{switch} uses it, and that is off: set {switch} = true or remove it"
    if eff.mucus_reflection and not any(materials.get_preset(o.material).optics.layers is not None
                                        for o in scene.objects):
        return "effects.mucus_reflection", ("only a layered material (every tissue preset, not plastic) has a wet coat, and no object "
                                            "is made of one: the reflection has no effect")
    if "backend" in given and not scene.effect_chain():
        return "effects.backend", "chooses how the post-effects run, but the scene has none; remove it"
    return None


def _output(scene):
    out = scene.output
    if "jitter" in _set(out) and out.supersampling == 1:
        return "output.jitter", "jitters the supersamples within a pixel, but supersampling = 1; remove it"
    if "track_points" in _set(out) and "tracks" not in out.passes:
        return "output.track_points", "sets the number of tracked points, but passes does not list tracks; remove it"
    if "track_queries" in _set(out) and "tracks" not in out.passes:
        return "output.track_queries", "gives query points to track, but passes does not list tracks; remove it"
    if "track_queries" in _set(out) and "track_points" in _set(out):
        return "output.track_points", "the points tracked are track_queries' when given; remove track_points"
    width, height = out.resolution
    for i, (t, y, x) in enumerate(out.track_queries):
        if t >= out.frames or y >= height or x >= width:
            return f"output.track_queries[{i}]", (f"expected [t, y, x] with t < frames = {out.frames}, y < {height} "
                                                  f"and x < {width}, found {[t, y, x]}")
    if "mp4" in out.formats and "png" not in out.formats:
        return "output.formats", "mp4 is made from the PNG frames at the end of the sequence: add \"png\""
    if "depth_png" in out.formats and "depth" not in out.passes:
        return "output.formats", "depth_png writes the depth pass as 16-bit PNG: add \"depth\" to output.passes"
    if not scene.simulated():
        for key, on in (("output.formats", "vtu" in out.formats), ("simulation.write_vtu", scene.simulation.write_vtu)):
            if on:
                return key, (f"vtu writes the simulated state, but this scene simulates nothing "
                             f"({scene.why_not_simulated()}): only the manifest would be written; remove vtu")
    return None
