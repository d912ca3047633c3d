"""What the renderer is given for one frame, built from the scene and the world at time ``t``: the camera,
the area light, the render settings and the triangle meshes (deformed bodies, static surfaces, tools)."""
from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

import materials
from materials.optics import with_overrides
from sim.mesh.surface import vertex_normals
from tissuerender import instruments
from tissuerender.field_colours import vertex_albedo
from tissuerender.errors import SceneError
from tissuerender.groundtruth.lens import FisheyeLens, fisheye_lens
from tissuerender.plan import Plan
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings
from tissuerender.scene import Scene
from tissuerender.scene.camera_schema import degenerate_view
from tissuerender.scene.cut_schema import CUT_MATERIAL, cut_optics
from tissuerender.stages import StageRecorder
from tissuerender.world import World, make_probe


def camera_pose(scene: Scene, t: float = 0.0) -> tuple[tuple, tuple, tuple]:
    """(position, look_at, up) of the laparoscope at time ``t`` [s]: the scene's fixed pose, or its ``path``
    interpolated linearly in time in each of position, look_at and up, held before the first keyframe and
    after the last (docs/ground-truth.md, "Moving camera")."""
    c = scene.camera
    if not c.path:
        return tuple(c.position), tuple(c.look_at), tuple(c.up)
    times = np.array([k.t for k in c.path], dtype=np.float64)

    def along(values) -> tuple:
        values = np.asarray(values, dtype=np.float64)
        return tuple(float(np.interp(t, times, values[:, axis])) for axis in range(3))

    pose = (along([k.position for k in c.path]), along([k.look_at for k in c.path]),
            along([k.up if k.up is not None else c.up for k in c.path]))
    problem = degenerate_view(*pose)
    if problem:
        raise SceneError(scene.path, "camera.path", f"at t = {t:g} s the interpolated pose has no orientation: "
                         f"{problem}; add a keyframe there")
    return pose


def camera_for(scene: Scene, width: int | None = None, height: int | None = None, t: float | None = None) -> Camera:
    """The camera at time ``t`` [s] (default 0: the first frame's) at the given size (default the scene's)."""
    c = scene.camera
    position, look_at, up = camera_pose(scene, 0.0 if t is None else t)
    return Camera(position=position, look_at=look_at, up=up, fov_deg=c.fov_deg, near=c.near, far=c.far,
                  width=width or scene.width, height=height or scene.height,
                  focus_distance=c.focus_distance, aperture=c.aperture)


def check_camera(scene: Scene) -> None:
    """What a render needs of the camera, before its first frame: the lens can image the field of view, and
    every frame's pose along a path has an orientation (a scene error naming the key otherwise)."""
    lens_for(scene, camera_for(scene))
    c = scene.camera
    if not c.path:
        return
    times = np.arange(scene.output.frames, dtype=np.float64) / scene.output.fps
    keys = np.array([k.t for k in c.path], dtype=np.float64)

    def along(values) -> np.ndarray:
        values = np.asarray(values, dtype=np.float64)
        return np.stack([np.interp(times, keys, values[:, axis]) for axis in range(3)], axis=1)

    position, look_at = along([k.position for k in c.path]), along([k.look_at for k in c.path])
    up = along([k.up if k.up is not None else c.up for k in c.path])
    view = look_at - position
    cross = np.cross(view, up)
    # the thresholds of camera_schema.degenerate_view, which camera_pose applies to the first bad frame
    bad = (np.einsum("ij,ij->i", view, view) < 1e-18) | (
        np.einsum("ij,ij->i", cross, cross) < 1e-18 * np.maximum(np.einsum("ij,ij->i", up, up), 1e-300))
    if bad.any():
        camera_pose(scene, float(times[np.argmax(bad)]))


def lens_for(scene: Scene, camera: Camera) -> FisheyeLens | None:
    """The laparoscope's lens for ``camera``'s size and field of view (``[camera.lens]``), None for a pinhole;
    a scene error naming ``camera.lens`` when the model cannot image that field."""
    spec = scene.camera.lens
    if spec is None:
        return None
    try:
        lens = _lens_at_origin(float(camera.fov_deg), int(camera.width), int(camera.height),
                               tuple(spec.coefficients), float(spec.vignetting))
    except ValueError as e:
        raise SceneError(scene.path, "camera.lens", f"{e} (fov_deg = {camera.fov_deg:g}, "
                         f"image {camera.width} x {camera.height}, coefficients {list(spec.coefficients)})") from None
    # the remap depends on the field, size and coefficients only: built once, posed per frame
    pinhole = replace(camera, width=lens.pinhole.width, height=lens.pinhole.height, fov_deg=lens.pinhole.fov_deg)
    return replace(lens, pinhole=pinhole)


@functools.lru_cache(maxsize=8)
def _lens_at_origin(fov_deg: float, width: int, height: int, coefficients: tuple, vignetting: float) -> FisheyeLens:
    camera = Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 1.0, 0.0), up=(0.0, 0.0, 1.0), fov_deg=fov_deg,
                    near=1.0, far=2.0, width=width, height=height)
    return fisheye_lens(camera, coefficients, vignetting)


def light_for(scene: Scene) -> AreaLight:
    lt = scene.light
    return AreaLight(size=tuple(lt.size), radiance=tuple(lt.radiance), attach=lt.attach,
                     position=lt.position, normal=lt.normal, up=lt.up, offset=tuple(lt.offset),
                     importance=tuple((tuple(k.centre), k.radius, k.multiplier) for k in lt.importance),
                     reflection_cone=lt.reflection_cone, cone_samples=lt.cone_samples,
                     sampling=lt.sampling, samples=lt.samples, pattern=lt.pattern, estimator=lt.estimator,
                     penumbra_samples=lt.penumbra_samples)


def settings_for(scene: Scene, seed: int) -> RenderSettings:
    e = scene.effects
    return RenderSettings(shadows=e.shadows, sss=e.sss, sss_thickness=e.sss_thickness, ao=e.ao, mucus_reflection=e.mucus_reflection,
                          supersampling=scene.output.supersampling,
                          jitter=scene.output.jitter,
                          seed=seed, motion=e.motion, ambient=tuple(e.ambient), ao_distance=e.ao_distance,
                          ao_samples=e.ao_samples, environment_up=tuple(e.environment_up),
                          environment_down=tuple(e.environment_down), environment_axis=tuple(e.environment_axis))


def tool_surface(tool, t: float):
    """A triangle mesh of a visible tool at time ``t`` (sphere or capsule along its axis), placed on the
    simulation probe's own path."""
    import trimesh  # heavy (pulls in scipy.spatial) and needed only by scenes with visible tools: kept lazy

    if tool.kind in instruments.INSTRUMENT_KINDS:
        return instruments.instrument_surface(tool, t)
    probe = make_probe(tool)
    if tool.kind == "mesh":  # its file's triangles turned and placed as they push (tissuerender.contacts.mesh_tool_probe)
        points, triangles, normals = probe.drawn
        if probe.orientations is None:
            return points + probe.position(t), triangles, normals
        R = probe.rotation(t)
        return points @ R.T + probe.position(t), triangles, normals @ R.T
    centre = np.asarray(probe.position(t), dtype=np.float64)
    if tool.kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=3, radius=tool.radius)
    else:
        m = trimesh.creation.capsule(height=tool.length, radius=tool.radius, count=[24, 24])
        axis = np.asarray(tool.axis, dtype=np.float64)
        m.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], axis / np.linalg.norm(axis)))
    return np.asarray(m.vertices) + centre, np.asarray(m.faces, dtype=np.int32), np.asarray(m.vertex_normals)


def optics_for(spec):
    """The object's optics when its scene overrides some (``[objects.optics]``), else None (the preset's)."""
    if spec.optics is None:
        return None
    return with_overrides(materials.get_preset(spec.material).optics, spec.optics.values())


def render_objects(world: World, scene: Scene, t: float, plan: Plan, recorder: StageRecorder, previous=None):
    """The frame's render objects, in order: bodies, static surfaces, visible tools; and the bodies' surface
    positions by name (the next frame's ``previous``, for the velocity channel)."""
    objects = []
    positions = {}
    oid = 0
    for i, body in enumerate(world.bodies):
        if "embed" in plan:
            with recorder.run("embed"):
                pts = body.surface_points(world.states[i].x)
                normals = vertex_normals(pts, body.surface.triangles)
        else:
            pts, normals = body.surface.points, body.surface.normals
        velocity = None
        if "velocity_channel" in plan:
            prev = previous.get(body.spec.name, pts) if previous else pts
            prev = prev if prev.shape == pts.shape else pts  # a cut changed the surface (tissuerender.world)
            velocity = (pts - prev) * scene.output.fps
        positions[body.spec.name] = pts
        colours = body.spec.field_colours
        objects.append(RenderObject(points=pts, triangles=body.surface.triangles, normals=normals,
                                    uv=body.surface.uv, material=body.spec.material, object_id=oid,
                                    velocity=velocity, optics=optics_for(body.spec), name=body.spec.name,
                                    vertex_albedo=None if colours is None else
                                    vertex_albedo(colours, body, world.states[i].x, pts)))
        oid += 1
    for s in world.surfaces:
        vel = np.zeros_like(s.surface.points) if "velocity_channel" in plan else None
        objects.append(RenderObject(points=s.surface.points, triangles=s.surface.triangles,
                                    normals=s.surface.normals, uv=s.surface.uv, material=s.spec.material,
                                    object_id=oid, velocity=vel, optics=optics_for(s.spec), name=s.spec.name))
        oid += 1
    for tool in scene.tools:
        if tool.visible:
            pts, tris, normals = tool_surface(tool, t)
            vel = np.zeros_like(pts) if "velocity_channel" in plan else None
            steel = tool.kind in instruments.INSTRUMENT_KINDS
            objects.append(RenderObject(points=pts, triangles=tris, normals=normals, uv=None,
                                        material="steel" if steel else "plastic", object_id=oid, velocity=vel,
                                        optics=materials.optics.OPTICS["steel"] if steel else None, name=tool.name))
            oid += 1
    objects += cut_objects(world, plan, oid)  # after the tools: every other object keeps its id
    return objects, positions


def cut_objects(world: World, plan: Plan, first_id: int) -> list:
    """The faces cuts exposed (``world.cut_faces``), one render object per cut body after every other object, drawn
    with the body's ``cut_material`` (docs/interaction.md, "Cutting"); velocities zero."""
    objects = []
    for i in sorted(world.cut_faces):
        faces, _ = world.cut_faces[i]
        if not faces.triangles.size:
            continue
        spec = world.bodies[i].spec
        pts = world.states[i].x[faces.vertex_map]
        material = spec.cut_material or CUT_MATERIAL
        objects.append(RenderObject(points=pts, triangles=faces.triangles, normals=vertex_normals(pts, faces.triangles),
                                    uv=faces.uv, material=material, object_id=first_id + len(objects),
                                    velocity=np.zeros_like(pts) if "velocity_channel" in plan else None,
                                    optics=cut_optics(material), name=f"{spec.name} (cut)"))
    return objects
