"""What the renderer is given for one frame, built from the scene and the world at time ``t``: the camera,
the area light, the render settings and the triangle meshes (deformed bodies, static surfaces, tools)."""
from __future__ import annotations

import numpy as np

import materials
from materials.optics import with_overrides
from sim.mesh.surface import vertex_normals
from tissuerender.plan import Plan
from tissuerender.renderer import AreaLight, Camera, RenderObject, RenderSettings
from tissuerender.scene import Scene
from tissuerender.stages import StageRecorder
from tissuerender.world import World, make_probe


def camera_for(scene: Scene, width: int | None = None, height: int | None = None) -> Camera:
    c = scene.camera
    return Camera(position=c.position, look_at=c.look_at, up=c.up, fov_deg=c.fov_deg, near=c.near, far=c.far,
                  width=width or scene.width, height=height or scene.height,
                  focus_distance=c.focus_distance, aperture=c.aperture)


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

    probe = make_probe(tool)
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
            velocity = (pts - prev) * scene.output.fps
        positions[body.spec.name] = pts
        objects.append(RenderObject(points=pts, triangles=body.surface.triangles, normals=normals,
                                    uv=body.surface.uv, material=body.spec.material, object_id=oid,
                                    velocity=velocity, optics=optics_for(body.spec), name=body.spec.name))
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
            objects.append(RenderObject(points=pts, triangles=tris, normals=normals, uv=None,
                                        material="plastic", object_id=oid, velocity=vel, name=tool.name))
            oid += 1
    return objects, positions
