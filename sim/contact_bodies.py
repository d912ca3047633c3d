"""Contact between simulated bodies and with static triangle surfaces and mesh tools (issue 21 item 4), for XPBD.

Bodies in contact are simulated as one model (:func:`merge_models`: their nodes and tets side by side, so one
XPBD solve sees both and a contact correction moves both bodies by their inverse masses in the same Gauss-Seidel
sweep); :class:`BodyGroup` splits its state back into the bodies'. A pair of bodies ``a``, ``b`` gets two
:class:`SurfaceContact` constraints, ``a``'s boundary nodes against ``b``'s boundary surface and the reverse
(symmetric: neither body is the "master"). A static surface or a mesh tool is a :class:`SurfaceContact` with its
own vertices. The kernels and equations: ``sim.contact_mesh``.

Each :class:`SurfaceContact` adds to row ``pair`` of ``XPBD.contact_loads`` the force [N] exerted on the pair's
second member (body ``b`` or the static surface) by the first: ``sign`` times the impulse its corrections gave
the nodes it tests, over ``h dt`` (``sign = -1`` for ``a``'s nodes against ``b``; ``+1`` for ``b``'s nodes against
``a``), and its moment about the origin [N m].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.contact import ContactPlane
from sim.contact_mesh import (GRID_CELLS, build_grid, face_adjacency, mean_edge_length, project_nodes, pseudonormals,
                              triangle_boxes)
from sim.mesh.surface import boundary_faces
from sim.model import Model, PrescribedDisplacement, State
from sim.pose import orientation_at, quat_matrix
from sim.probe import Probe


@dataclass
class SurfaceContact:
    """The model's ``nodes`` against a triangle surface ``faces`` (outward wound): with ``points`` a static surface
    ([m], faces index them), else a surface of the model's own nodes (faces index nodes: another body's boundary in
    a merged model). ``reach`` [m]: the deepest a node is found inside (default: a static surface half its box's
    smallest side, at least its mean edge; a body's surface its mean edge). ``friction``: Coulomb coefficient."""

    nodes: np.ndarray
    faces: np.ndarray
    points: np.ndarray | None = None
    friction: float = 0.0
    reach: float | None = None
    pair: int = 0
    sign: float = -1.0

    def __post_init__(self):
        self.nodes = np.ascontiguousarray(self.nodes, dtype=np.int64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        if not self.friction >= 0.0:
            raise ValueError(f"contact friction must be >= 0, found {self.friction}")
        if self.reach is not None and not self.reach > 0.0:
            raise ValueError(f"contact reach must be > 0, found {self.reach}")


def default_reach(points: np.ndarray, faces: np.ndarray, closed_static: bool) -> float:
    """A body's or an open surface's mean edge; a closed static surface's half its box's smallest side (every point
    inside it is then within reach of its surface), at least its mean edge."""
    edge = mean_edge_length(points, faces)
    if not closed_static:
        return edge
    used = points[np.unique(faces)]
    return max(0.5 * float((used.max(axis=0) - used.min(axis=0)).min()), edge)


class SurfaceContactState:
    """The run-time state of one :class:`SurfaceContact`: the surface's normals and grid, and per tested node its
    normal impulse, triangle, barycentrics and normal over the substep."""

    def __init__(self, spec: SurfaceContact, X: np.ndarray):
        self.spec = spec
        self.static = spec.points is not None
        if self.static:
            self.vmap = np.arange(spec.points.shape[0], dtype=np.int64)
            self.faces = spec.faces
            self.xv = np.ascontiguousarray(spec.points, dtype=np.float64)
            self.wv = np.zeros(self.xv.shape[0])
        else:
            self.vmap, local = np.unique(spec.faces, return_inverse=True)
            self.faces = np.ascontiguousarray(local.reshape(-1, 3), dtype=np.int64)
        rest = self.xv if self.static else X
        self.adjacent = face_adjacency(self.faces)
        closed = self.static and bool((self.adjacent >= 0).all())
        self.reach = spec.reach if spec.reach is not None else default_reach(rest, spec.faces, closed)
        k, q = self.faces.shape[0], spec.nodes.size
        self.face_n, self.edge_n = np.zeros((k, 3)), np.zeros((k, 3, 3))
        self.vert_n = np.zeros((self.vmap.size, 3))
        self.lam_n, self.tri = np.zeros(q), np.zeros(q, dtype=np.int64)
        self.bary, self.normal = np.zeros((q, 3)), np.zeros((q, 3))
        self.active = spec.nodes  # the nodes the sweeps of this substep visit (begin)
        self.no_hint = np.zeros(0, dtype=np.int64)
        self.hint = self.no_hint
        self.shift = np.zeros(3)
        self.centre = np.zeros(3)
        if self.static:
            self._surface(self.xv)

    # a static surface's grid is built once: cells this many times finer than the boxes' mean side hold fewer
    # triangles to test per node (the nearest triangle within reach is the same with any cell: every triangle whose
    # grown box holds the node is in its cell, visited in the same order)
    static_cell_split = 3

    def _surface(self, xv: np.ndarray) -> None:
        """Normals and grid of the surface at ``xv`` (the static points, or the model's positions)."""
        pseudonormals(xv, self.vmap, self.faces, self.adjacent, self.face_n, self.edge_n, self.vert_n)
        self.lo, self.hi, self.cell = triangle_boxes(xv, self.vmap, self.faces, self.reach, GRID_CELLS)
        if self.static:  # still at most GRID_CELLS cells along the grid's longest side
            extent = float((self.hi.max(axis=0) - self.lo.min(axis=0)).max())
            self.cell = max(self.cell / self.static_cell_split, extent / GRID_CELLS)
        self.origin, self.dims, self.start, self.items = build_grid(self.lo, self.hi, self.cell)

    def project(self, x: np.ndarray, w: np.ndarray, load: np.ndarray) -> int:
        """One pass over the nodes; adds ``sign`` times their impulse and its moment about ``centre`` to ``load``."""
        if not self.active.size:
            return 0
        xv, wv = (self.xv, self.wv) if self.static else (x, w)
        return int(project_nodes(x, w, self.active, xv, self.vmap, wv, self.shift, self.faces, self.face_n,
                                 self.edge_n, self.vert_n, self.lo, self.hi, self.origin, self.cell, self.dims,
                                 self.start, self.items, self.reach, self.lam_n, self.tri, self.bary, self.normal,
                                 load, self.centre, self.spec.sign, self.hint))


class MeshProbe(Probe):
    """A rigid tool given by a closed triangle mesh (``points`` [m] in the tool frame, its origin the path point;
    outward wound ``faces``), moved along its keyframed path and, with ``orientations`` (k, 4), one unit quaternion
    ``(w, x, y, z)`` per keyframe taking the tool frame to the world, turned by their slerp (``sim.pose``; None:
    never turned). Nodes inside are pushed onto its surface (``sim.contact_mesh``, the surface with infinite mass):
    the surface is the points turned by the rotation at the substep's time about the path point, translated there
    (its normals and grid built again only when the rotation changes). Its load is summed as the capsules'
    (``sim.probe``), torque about the path point."""

    KINDS = ("mesh",)

    def __init__(self, points, faces, times, positions, reach: float | None = None, orientations=None):
        super().__init__(kind="mesh", radius=0.0, times=times, positions=positions)
        self.points = np.asarray(points, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.orientations = None
        if orientations is not None:
            q = np.asarray(orientations, dtype=np.float64).reshape(-1, 4)
            if q.shape[0] != self.times.size or not (np.linalg.norm(q, axis=1) > 0.0).all():
                raise ValueError(f"a mesh tool needs one non-zero quaternion per keyframe ({self.times.size}), "
                                 f"found {q.tolist()}")
            self.orientations = q / np.linalg.norm(q, axis=1)[:, None]
        self.contact = SurfaceContactState(SurfaceContact(np.zeros(0), faces, np.asarray(points, float), reach=reach,
                                                          sign=1.0), np.zeros((0, 3)))
        self.all_nodes = np.zeros(0, dtype=np.int64)
        self._turned = None  # the quaternion the contact surface is turned by

    def rotation(self, t: float) -> np.ndarray:
        """The rotation matrix (tool frame to world) at ``t``."""
        if self.orientations is None:
            return np.eye(3)
        return quat_matrix(orientation_at(self.times, self.orientations, t))

    def capsules(self, t: float) -> list[tuple]:
        return []

    def push_out(self, x: np.ndarray, t: float, inv_mass: np.ndarray, load: np.ndarray) -> int:
        c = self.contact
        if self.all_nodes.size != x.shape[0]:
            self.all_nodes = np.arange(x.shape[0], dtype=np.int64)
            c.lam_n, c.tri = np.zeros(x.shape[0]), np.zeros(x.shape[0], dtype=np.int64)
            c.bary, c.normal = np.zeros((x.shape[0], 3)), np.zeros((x.shape[0], 3))
        if self.orientations is not None:
            q = orientation_at(self.times, self.orientations, t)
            if self._turned is None or not np.array_equal(q, self._turned):
                c.xv = self.points @ quat_matrix(q).T  # turned about the path point
                c._surface(c.xv)
                self._turned = q
        c.spec.nodes = c.active = self.all_nodes
        c.hint = c.no_hint
        c.shift = self.position(t)
        c.centre = c.shift
        return c.project(x, inv_mass, load)


def boundary_nodes_and_faces(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    faces = boundary_faces(np.asarray(tets, dtype=np.int64))
    return np.unique(faces), faces


@dataclass
class BodyGroup:
    """Bodies simulated as one merged model: body k holds the merged nodes ``offsets[k]:offsets[k + 1]``."""

    models: list[Model]
    model: Model
    offsets: np.ndarray
    contacts: list = field(default_factory=list)

    def merge_states(self, states: list[State]) -> State:
        return State(x=np.concatenate([s.x for s in states]), v=np.concatenate([s.v for s in states]),
                     t=states[0].t)

    def split_state(self, state: State) -> list[State]:
        o = self.offsets
        return [State(x=state.x[o[k]:o[k + 1]].copy(), v=state.v[o[k]:o[k + 1]].copy(), t=state.t)
                for k in range(len(self.models))]

    def body_surface(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Body k's boundary nodes and outward faces, as merged node ids."""
        o = self.offsets[k]
        nodes, faces = boundary_nodes_and_faces(self.models[k].tets)
        return nodes + o, faces + o


def merge_models(models: list[Model]) -> BodyGroup:
    """One model holding every body of ``models`` (same constitutive model, material extras, pressure treatment and
    gravity: else ValueError naming the difference); their fixed nodes, prescriptions, loads and contact planes
    (restricted to the body's nodes) carried over."""
    first = models[0]
    for k, m in enumerate(models[1:], 1):
        for name in ("constitutive", "pressure"):
            if getattr(m, name) != getattr(first, name):
                raise ValueError(f"bodies in contact must share {name}: body 0 has {getattr(first, name)!r}, "
                                 f"body {k} {getattr(m, name)!r}")
        if not np.array_equal(m.gravity, first.gravity):
            raise ValueError(f"bodies in contact must share gravity, found {list(first.gravity)} and {list(m.gravity)}")
        if repr(m.material_params) != repr(first.material_params):
            raise ValueError(f"bodies in contact must share material extras (material_params), found "
                             f"{first.material_params} for body 0 and {m.material_params} for body {k}")
    offsets = np.concatenate([[0], np.cumsum([m.n_nodes for m in models])]).astype(np.int64)
    cat = lambda name: np.concatenate([getattr(m, name) for m in models])  # noqa: E731
    fibre = None
    if any(m.fibre is not None for m in models):
        fibre = np.concatenate([m.fibre if m.fibre is not None else np.tile([1.0, 0.0, 0.0], (m.n_tets, 1))
                                for m in models])
    external = None
    if any(m.external_force is not None for m in models):
        external = np.concatenate([m.external_force if m.external_force is not None else np.zeros((m.n_nodes, 3))
                                   for m in models])
    prescribed, planes = [], []
    for m, o in zip(models, offsets):
        for p in m.prescribed:
            prescribed.append(PrescribedDisplacement(np.asarray(p.nodes) + o, p.displacement, p.t_start, p.t_end,
                                                     held=p.held))
        for plane in getattr(m, "contact_planes", ()):
            own = np.arange(m.n_nodes) if plane.nodes is None else np.asarray(plane.nodes)
            planes.append(ContactPlane(plane.point, plane.normal, plane.friction, nodes=own + o))
    merged = Model(
        X=cat("X"), tets=np.concatenate([m.tets + o for m, o in zip(models, offsets)]).astype(first.tets.dtype),
        Dm_inv=cat("Dm_inv"), volume=cat("volume"), mass=cat("mass"), E=cat("E"), nu=cat("nu"), mu=cat("mu"),
        lam=cat("lam"), density=first.density, fibre=fibre, constitutive=first.constitutive,
        material_params=first.material_params,
        fixed=np.concatenate([m.fixed if m.fixed is not None else np.zeros(m.n_nodes, bool) for m in models]),
        prescribed=prescribed, gravity=first.gravity, external_force=external, probes=list(first.probes),
        pressure=first.pressure)
    merged.grasps = list(getattr(first, "grasps", ()))
    merged.contact_planes = planes
    merged.contacts = []
    return BodyGroup(list(models), merged, offsets)


def add_body_contact(group: BodyGroup, a: int, b: int, friction: float, pair: int, reach: float | None = None):
    """Contact between bodies ``a`` and ``b`` of ``group`` (both directions), reported in row ``pair``."""
    for first, second, sign in ((a, b, -1.0), (b, a, 1.0)):
        nodes, _ = group.body_surface(first)
        _, faces = group.body_surface(second)
        group.model.contacts.append(SurfaceContact(nodes, faces, None, friction, reach, pair, sign))


def add_static_contact(model: Model, nodes: np.ndarray, points: np.ndarray, faces: np.ndarray, friction: float,
                       pair: int, reach: float | None = None) -> None:
    """Contact of the model's ``nodes`` with a static surface, reported in row ``pair``."""
    if not hasattr(model, "contacts"):
        model.contacts = []
    model.contacts.append(SurfaceContact(nodes, faces, points, friction, reach, pair, -1.0))
