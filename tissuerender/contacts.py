"""The scene's ``[[contacts]]`` in the simulated world (issue 21 item 4; docs/interaction.md, "Contact between
bodies"): bodies in contact with each other are simulated as one merged model (``sim.contact_bodies.BodyGroup``),
stepped by one integrator for the group; a body's contact with a static surface is a constraint of its own model
(or of its group's). The force on each pair's second object from the first is a row ``contact:<a>:<b>`` of
``tool_forces.csv``, after the tools' and floors'.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from sim.contact_bodies import (BodyGroup, MeshProbe, add_body_contact, add_static_contact, boundary_nodes_and_faces,
                                merge_models)
from sim.contact_mesh import face_adjacency
from sim.errors import MeshError
from sim.mesh import io
from sim.mesh.surface import orient_outward, vertex_normals, weld
from sim.mesh.types import SurfaceMesh
from sim.model import State
from tissuerender.errors import UserError


@lru_cache(maxsize=16)
def _tool_surface(path: str):
    try:
        read = io.read_surface(path)  # welded on positions alone, outward wound (as a body's surface file)
        surface = orient_outward(weld(SurfaceMesh(read.points, read.triangles, source=read.source)))
    except MeshError as e:
        raise UserError(f"{path}: {e}") from None
    faces = surface.triangles.astype(np.int64)
    open_edges = int((face_adjacency(faces) < 0).sum())
    if open_edges:
        raise UserError(f"{path}: a mesh tool must be a closed surface (its inside pushes tissue out), found "
                        f"{open_edges} edges with one triangle or more than two")
    if read.normals is not None:  # drawn as the file gives it, else flat (a file without normals has sharp edges)
        drawn = (read.points, read.triangles.astype(np.int32), read.normals)
    else:
        p = surface.points[faces]
        n = vertex_normals(p.reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3))  # unshared: the face normals
        drawn = (p.reshape(-1, 3), np.arange(3 * len(faces), dtype=np.int32).reshape(-1, 3), n)
    return surface.points, faces, drawn


def mesh_tool_probe(tool) -> MeshProbe:
    """The probe of a ``kind = "mesh"`` tool: its file's closed surface (read once per file), on its keyframed path,
    turned by the keyframes' orientations where one gives any (a keyframe without: unturned); ``drawn``: the
    (points, triangles, normals) it is drawn with in the tool frame (``tissuerender.render_inputs.tool_surface``
    places them with ``probe.rotation`` and ``probe.position``)."""
    points, faces, drawn = _tool_surface(tool.mesh)
    times = np.array([k.t for k in tool.keyframes], dtype=np.float64)
    positions = np.array([k.position for k in tool.keyframes], dtype=np.float64)
    orientations = None
    if any(k.orientation is not None for k in tool.keyframes):
        orientations = np.array([[1.0, 0.0, 0.0, 0.0] if k.orientation is None else k.orientation
                                 for k in tool.keyframes], dtype=np.float64)
    probe = MeshProbe(points, faces, times, positions, orientations=orientations)
    probe.drawn = drawn
    return probe


def contact_names(scene) -> list[str]:
    """The rows of the contacts in the tool-force log: ``contact:<a>:<b>``, the force on b from a."""
    return [f"contact:{c.bodies[0]}:{c.bodies[1]}" for c in scene.contacts]


@dataclass
class ContactGroup:
    """Bodies (indices into ``World.bodies``) stepped together as ``group.model``: ``integrator`` is set on the
    first member (the others get None), ``floor_rows`` and ``contact_rows`` map the world's load rows to the
    integrator's ``plane_loads`` and ``contact_loads`` rows."""

    members: list[int]
    group: BodyGroup
    integrator: object = None
    floor_rows: list = field(default_factory=list)
    contact_rows: list = field(default_factory=list)


def attach_contacts(scene, bodies, surfaces, first_contact_row: int) -> tuple[list[ContactGroup], dict]:
    """Merge the bodies in contact into groups and add every contact constraint to its model. Returns the groups and,
    for each body not in a group, its ``contact_rows`` (list of (world row, integrator row)). The bodies' models
    must already carry their probes, grasps and floors."""
    body_of = {b.spec.name: i for i, b in enumerate(bodies)}
    surface_of = {s.spec.name: s for s in surfaces}
    parent = list(range(len(bodies)))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for c in scene.contacts:
        a, b = c.bodies
        if a in body_of and b in body_of:
            parent[root(body_of[a])] = root(body_of[b])
    members: dict[int, list[int]] = {}
    for i in range(len(bodies)):
        members.setdefault(root(i), []).append(i)
    groups, group_of = [], {}
    for ms in members.values():
        if len(ms) > 1:
            try:
                g = ContactGroup(ms, merge_models([bodies[i].model for i in ms]))
            except ValueError as e:
                names = ", ".join(repr(bodies[i].spec.name) for i in ms)
                raise ValueError(f"bodies {names} in contact: {e}") from None
            groups.append(g)
            for k, i in enumerate(ms):
                group_of[i] = (g, k)
    single_rows: dict[int, list] = {}
    for row, c in enumerate(scene.contacts, first_contact_row):
        a, b = c.bodies
        if a in body_of and b in body_of:
            g, ka = group_of[body_of[a]]
            _, kb = group_of[body_of[b]]
            pair = len(g.contact_rows)
            add_body_contact(g.group, ka, kb, c.friction, pair, c.reach)
            g.contact_rows.append((row, pair))
            continue
        body, surface = (body_of[a], surface_of[b]) if a in body_of else (body_of[b], surface_of[a])
        if body in group_of:
            g, k = group_of[body]
            nodes, _ = g.group.body_surface(k)
            model, rows = g.group.model, g.contact_rows
        else:
            nodes, _ = boundary_nodes_and_faces(bodies[body].model.tets)
            model, rows = bodies[body].model, single_rows.setdefault(body, [])
        pair = len(rows)
        add_static_contact(model, nodes, surface.surface.points, surface.surface.triangles, c.friction, pair, c.reach)
        # the pair's second member is the surface: a body named second has the force on it from the surface, minus
        rows.append((row, pair) if a in body_of else (row, pair, -1.0))
    return groups, single_rows


class GroupStepper:
    """Steps a contact group as the integrator of its first member: ``step`` takes that member's state, the others'
    from ``world.states`` (written back after the step), so ``tissuerender.world.advance`` drives it as any body's
    integrator. ``tool_loads``, ``plane_loads`` and ``contact_loads`` are the group integrator's."""

    def __init__(self, world, group: ContactGroup, integrator):
        self.world, self.group, self.integrator = world, group, integrator
        self.floor_rows, self.contact_rows = group.floor_rows, group.contact_rows
        self.name = integrator.name

    def step(self, state: State, dt: float) -> State:
        g = self.group
        states = [state] + [self.world.states[i] for i in g.members[1:]]
        merged = g.group.merge_states(states)
        merged.t = state.t
        merged = self.integrator.step(merged, dt)
        parts = g.group.split_state(merged)
        for i, part in zip(g.members[1:], parts[1:]):
            self.world.states[i] = part
        return parts[0]

    def __getattr__(self, name):
        if name.startswith("__") or name == "integrator":  # unpickling looks these up before __dict__ is filled
            raise AttributeError(name)
        return getattr(self.integrator, name)


def add_contact_loads(loads: np.ndarray, integrator, n: int) -> None:
    """Add the integrator's contact forces (over one of the frame's ``n`` steps) to the world's rows."""
    for entry in getattr(integrator, "contact_rows", ()):
        row, pair, sign = (*entry, 1.0)[:3]
        loads[row] += sign * integrator.contact_loads[pair] / n
