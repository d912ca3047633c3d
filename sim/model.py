"""The simulation model: rest geometry, per-tet material fields and boundary conditions.

Every integrator (``xpbd``, ``ebm``, ``cnn``, ``explicit``, ``reference``) is built from one
:class:`Model` and advances one :class:`State`; nothing about the model is integrator specific.

Rest geometry follows the usual linear-tet FEM conventions (Zhang eqs. 5.10–5.11,
Qian eq. 4.21): ``Dm = [X1-X0, X2-X0, X3-X0]`` (columns), ``F = Ds Dm^-1``, rest volume
``V = det(Dm) / 6`` and lumped masses ``m_i = sum over incident tets of rho V / 4``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from sim.mesh.types import TetMesh


def lame_from_young_poisson(E: np.ndarray | float, nu: np.ndarray | float):
    """Lamé parameters ``(mu, lam)`` from Young's modulus ``E`` [Pa] and Poisson ratio ``nu``."""
    E = np.asarray(E, dtype=np.float64)
    nu = np.asarray(nu, dtype=np.float64)
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def rest_shape(points: np.ndarray, tets: np.ndarray):
    """Inverse rest shape matrices ``Dm_inv (m, 3, 3)`` and signed rest volumes ``(m,)``."""
    X = points[tets]  # (m, 4, 3)
    Dm = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2)
    det = np.linalg.det(Dm)
    volume = det / 6.0
    Dm_inv = np.linalg.inv(Dm)
    return np.ascontiguousarray(Dm_inv), volume


@njit(cache=True)
def ramp_fraction(t, t_start, t_end):
    """The share of a prescribed displacement applied at time ``t`` [s]: a linear ramp from 0 at ``t_start`` to 1
    at ``t_end``, a step at ``t_start`` when ``t_end <= t_start``. Compiled so that the EBM step kernel calls the
    same routine as NumPy code."""
    if t_end <= t_start:
        return 1.0 if t >= t_start else 0.0
    return min(max((t - t_start) / (t_end - t_start), 0.0), 1.0)


@dataclass
class PrescribedDisplacement:
    """Nodes moved by ``displacement`` [m], ramped linearly from ``t_start`` to ``t_end`` [s].

    ``held``: ``None`` (every component imposed: the nodes are kinematic) or ``(d, 3)`` directions (d = 1, 2) along
    which alone the motion is imposed; the nodes move freely in the directions orthogonal to them (a roller or a
    sliding face: ``held = [[0, 0, 1]]`` imposes z and leaves x, y free; a zero displacement with one ``held``
    normal is a symmetry plane). See :class:`PartialTargets`."""

    nodes: np.ndarray
    displacement: np.ndarray
    t_start: float = 0.0
    t_end: float = 0.0
    held: np.ndarray | None = None

    def fraction(self, t: float) -> float:
        return float(ramp_fraction(float(t), float(self.t_start), float(self.t_end)))


def free_projector(directions: np.ndarray) -> np.ndarray:
    """``P = I - Q Q^T`` (3, 3) with Q an orthonormal basis of the span of ``directions`` (d, 3): the motion a node
    held along ``directions`` may still make. Rank-deficient sets (two parallel normals) hold their span once."""
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    u, s, _ = np.linalg.svd(directions.T, full_matrices=True)
    rank = int(np.sum(s > 1e-9 * max(float(s.max(initial=0.0)), 1e-300)))
    Q = u[:, :rank]
    return np.eye(3) - Q @ Q.T


@dataclass(frozen=True)
class PartialTargets:
    """Nodes held in some components only (rollers, sliding faces, symmetry planes): node ``nodes[k]`` satisfies
    ``(I - P[k]) (x - target_k(t)) = 0`` with the free-motion projector ``P[k]`` (:func:`free_projector` of every
    direction its prescriptions hold) and ``target_k(t) = rest[k] + sum_g ramp_fraction(t, t_start[g], t_end[g])
    Q_g Q_g^T d_g`` over the prescriptions g listing it (``Q_g``: an orthonormal basis of g's held directions, ``d_g``
    its displacement; a node on a roller face and a symmetry plane takes its axial motion from the one and stays on
    the other). A node fully held by a fixed region or a prescription without ``held`` is kinematic
    (:class:`KinematicTargets`) and not listed here. Every integrator restricts these nodes through :meth:`place`
    (positions) and :meth:`velocity`, or, for the implicit reference, through the basis :meth:`free_bases` of the
    allowed motion."""

    nodes: np.ndarray  # (k,) int64, increasing
    P: np.ndarray  # (k, 3, 3) projector onto the free motion
    rest: np.ndarray  # (k, 3) [m]
    row: np.ndarray  # (p,) int64: the node (index into ``nodes``) of each (node, prescription) pair
    group: np.ndarray  # (p,) int64: the prescription of each pair
    displacement: np.ndarray  # (p, 3) [m]: Q_g Q_g^T d_g of each pair
    t_start: np.ndarray  # (g,) [s] per prescription (all of the model's, full ones included)
    t_end: np.ndarray  # (g,) [s]

    @property
    def empty(self) -> bool:
        return self.nodes.size == 0

    def at(self, t: float) -> np.ndarray:
        """Targets (k, 3) [m] at time ``t``."""
        target = self.rest.copy()
        fraction = np.array([ramp_fraction(float(t), a, b) for a, b in zip(self.t_start, self.t_end)])
        np.add.at(target, self.row, fraction[self.group][:, None] * self.displacement)
        return target

    def place(self, x: np.ndarray, t: float) -> None:
        """Project the nodes of ``x`` (in place) onto their constraint at time ``t``: x = target + P (x - target)."""
        if self.empty:
            return
        target = self.at(t)
        x[self.nodes] = target + np.einsum("kij,kj->ki", self.P, x[self.nodes] - target)

    def velocity(self, v: np.ndarray, t: float, h: float) -> None:
        """Velocities (in place): free components kept, held ones moving with the target over the last step h."""
        if self.empty:
            return
        target_speed = (self.at(t) - self.at(t - h)) / h
        free = np.einsum("kij,kj->ki", self.P, v[self.nodes])
        v[self.nodes] = free + target_speed - np.einsum("kij,kj->ki", self.P, target_speed)

    def project(self, a: np.ndarray) -> None:
        """Remove the held components of a nodal vector field (accelerations, position updates), in place."""
        if not self.empty:
            a[self.nodes] = np.einsum("kij,kj->ki", self.P, a[self.nodes])

    def free_bases(self) -> list[np.ndarray]:
        """Per node an orthonormal basis (3, r) of its free motion (r = rank P: 2 on a plane, 1 on a line, 0)."""
        bases = []
        for P in self.P:
            w, V = np.linalg.eigh(P)
            bases.append(np.ascontiguousarray(V[:, w > 0.5]))
        return bases

@dataclass(frozen=True)
class KinematicTargets:
    """The fixed and prescribed nodes of a model and where they are at any time: node ``nodes[k]`` sits at
    ``rest[k] + ramp_fraction(t, t_start[g], t_end[g]) displacement[k]`` with ``g = group[k]`` the last
    prescribed displacement that lists it, or at ``rest[k]`` when ``g = -1`` (fixed). The one kinematic-target
    routine: every integrator places its kinematic nodes through :meth:`at` (the blocked EBM kernel takes these
    arrays and calls :func:`ramp_fraction`)."""

    nodes: np.ndarray  # (k,) int64, increasing
    rest: np.ndarray  # (k, 3) [m]
    group: np.ndarray  # (k,) int64, -1 for fixed nodes
    displacement: np.ndarray  # (k, 3) [m], zero for fixed nodes
    t_start: np.ndarray  # (g,) [s] per prescribed displacement
    t_end: np.ndarray  # (g,) [s]

    def at(self, t: float) -> np.ndarray:
        """Targets (k, 3) [m] at time ``t``."""
        target = self.rest.copy()
        for g in range(self.t_start.size):
            rows = self.group == g
            target[rows] = self.rest[rows] + ramp_fraction(float(t), self.t_start[g], self.t_end[g]) * self.displacement[rows]
        return target


@dataclass
class Model:
    """Rest geometry, material fields and boundary conditions of one simulated body.

    Attributes
    ----------
    X : (n, 3) rest positions [m].
    tets : (m, 4) int32 positively oriented tets.
    Dm_inv : (m, 3, 3) inverse rest shape matrices.
    volume : (m,) rest volumes [m^3].
    mass : (n,) lumped masses [kg].
    E, nu : (m,) Young's modulus [Pa] and Poisson ratio per tet (heterogeneous fields allowed).
    mu, lam : (m,) Lamé parameters derived from E and nu.
    density : mass density [kg/m^3].
    fibre : (m, 3) unit fibre direction per tet, or ``None`` for isotropic materials.
    constitutive : name of the constitutive model (see ``sim.constitutive``).
    material_params : model-specific extras (e.g. ``eta`` for the fibre term, Prony terms).
    fixed : (n,) bool, nodes held at their rest position.
    prescribed : displacement ramps applied to node sets (all components, or only along ``held`` directions).
    gravity : (3,) [m/s^2].
    pressure : "element" (standard linear tets) or "anp" (average nodal pressure against locking).
    external_force : (n, 3) constant nodal forces [N] (surface tractions integrated on faces).
    """

    X: np.ndarray
    tets: np.ndarray
    Dm_inv: np.ndarray
    volume: np.ndarray
    mass: np.ndarray
    E: np.ndarray
    nu: np.ndarray
    mu: np.ndarray
    lam: np.ndarray
    density: float
    fibre: np.ndarray | None = None
    constitutive: str = "stable_neo_hookean"
    material_params: dict = field(default_factory=dict)
    fixed: np.ndarray | None = None
    prescribed: list[PrescribedDisplacement] = field(default_factory=list)
    gravity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    external_force: np.ndarray | None = None
    probes: list = field(default_factory=list)
    pressure: str = "element"  # "anp": volumetric energy on nodal volumes (sim.constitutive.anp), split models only

    @classmethod
    def from_mesh(
        cls,
        mesh: TetMesh,
        E: float | np.ndarray = 3000.0,
        nu: float | np.ndarray = 0.45,
        density: float = 1000.0,
        constitutive: str = "stable_neo_hookean",
        fibre: np.ndarray | None = None,
        **kwargs,
    ) -> "Model":
        Dm_inv, volume = rest_shape(mesh.points, mesh.tets)
        if np.any(volume <= 0.0):
            bad = int(np.flatnonzero(volume <= 0.0)[0])
            raise ValueError(
                f"{mesh.source}: tet {bad} has non-positive rest volume {volume[bad]:.3e} m^3; "
                "expected positively oriented tets"
            )
        m = mesh.n_tets
        E_t = np.broadcast_to(np.asarray(E, dtype=np.float64), (m,)).copy()
        nu_t = np.broadcast_to(np.asarray(nu, dtype=np.float64), (m,)).copy()
        mu, lam = lame_from_young_poisson(E_t, nu_t)
        mass = np.zeros(mesh.n_points)
        np.add.at(mass, mesh.tets.ravel(), np.repeat(density * volume / 4.0, 4))
        if fibre is not None:
            fibre = np.broadcast_to(np.asarray(fibre, dtype=np.float64), (m, 3)).copy()
            fibre /= np.linalg.norm(fibre, axis=1, keepdims=True)
        return cls(
            X=mesh.points.copy(),
            tets=mesh.tets.copy(),
            Dm_inv=Dm_inv,
            volume=volume,
            mass=mass,
            E=E_t,
            nu=nu_t,
            mu=mu,
            lam=lam,
            density=float(density),
            fibre=fibre,
            constitutive=constitutive,
            fixed=np.zeros(mesh.n_points, dtype=bool),
            **kwargs,
        )

    @property
    def n_nodes(self) -> int:
        return int(self.X.shape[0])

    @property
    def n_tets(self) -> int:
        return int(self.tets.shape[0])

    def inverse_mass(self) -> np.ndarray:
        """``1/m`` per node, zero for fixed and prescribed nodes (they are kinematic; nodes held in some components
        only keep their mass: :class:`PartialTargets` restricts them)."""
        w = np.where(self.mass > 0.0, 1.0 / np.maximum(self.mass, 1e-300), 0.0)
        w[self.kinematic_mask()] = 0.0
        return w

    def kinematic_mask(self) -> np.ndarray:
        """Nodes held in every component: fixed, or prescribed without ``held`` directions."""
        mask = np.zeros(self.n_nodes, dtype=bool) if self.fixed is None else self.fixed.copy()
        for p in self.prescribed:
            if p.held is None:
                mask[p.nodes] = True
        return mask

    def kinematic(self) -> KinematicTargets:
        """The fixed and prescribed nodes and their ramps (the last prescription of a node wins)."""
        nodes = np.flatnonzero(self.kinematic_mask()).astype(np.int64)
        group = np.full(self.n_nodes, -1, np.int64)
        displacement = np.zeros((self.n_nodes, 3))
        for g, p in enumerate(self.prescribed):
            if p.held is not None:
                continue
            group[p.nodes] = g
            displacement[p.nodes] = np.asarray(p.displacement, dtype=np.float64)
        return KinematicTargets(
            nodes=nodes, rest=np.ascontiguousarray(self.X[nodes], dtype=np.float64),
            group=np.ascontiguousarray(group[nodes]), displacement=np.ascontiguousarray(displacement[nodes]),
            t_start=np.array([float(p.t_start) for p in self.prescribed], dtype=np.float64),
            t_end=np.array([float(p.t_end) for p in self.prescribed], dtype=np.float64))

    def partial(self) -> PartialTargets:
        """The nodes held in some components only (prescriptions with ``held`` directions, not otherwise kinematic)."""
        kinematic = self.kinematic_mask()
        directions: dict[int, list] = {}
        pairs = []  # (node, prescription, displacement along the held directions)
        for g, p in enumerate(self.prescribed):
            if p.held is None:
                continue
            held = np.asarray(p.held, dtype=np.float64).reshape(-1, 3)
            along = (np.eye(3) - free_projector(held)) @ np.asarray(p.displacement, dtype=np.float64)
            for i in np.asarray(p.nodes).reshape(-1).tolist():
                if not kinematic[i]:
                    directions.setdefault(i, []).append(held)
                    pairs.append((i, g, along))
        nodes = np.array(sorted(directions), dtype=np.int64)
        row_of = {i: k for k, i in enumerate(nodes.tolist())}
        projectors = {}
        P = np.empty((nodes.size, 3, 3))
        for k, i in enumerate(nodes.tolist()):
            held = np.concatenate(directions[i])
            key = held.tobytes()
            if key not in projectors:
                projectors[key] = free_projector(held)
            P[k] = projectors[key]
        return PartialTargets(
            nodes=nodes, P=P, rest=np.ascontiguousarray(self.X[nodes], dtype=np.float64),
            row=np.array([row_of[i] for i, _, _ in pairs], dtype=np.int64),
            group=np.array([g for _, g, _ in pairs], dtype=np.int64),
            displacement=np.array([d for _, _, d in pairs], dtype=np.float64).reshape(-1, 3),
            t_start=np.array([float(p.t_start) for p in self.prescribed], dtype=np.float64),
            t_end=np.array([float(p.t_end) for p in self.prescribed], dtype=np.float64))

    def kinematic_targets(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Indices and target positions at time ``t`` of every fixed or prescribed node."""
        kinematic = self.kinematic()
        return kinematic.nodes, kinematic.at(t)

    def nodal_external_force(self) -> np.ndarray:
        """Gravity plus constant nodal forces, (n, 3) [N]."""
        f = self.mass[:, None] * np.asarray(self.gravity, dtype=np.float64)[None, :]
        if self.external_force is not None:
            f = f + self.external_force
        return f


@dataclass
class State:
    """Positions ``x (n, 3)``, velocities ``v (n, 3)``, time ``t`` and integrator-private state.

    ``private`` holds what a particular integrator carries between steps (Prony stress history,
    CNN saturation state, XPBD multipliers are *not* kept: they reset each substep).
    """

    x: np.ndarray
    v: np.ndarray
    t: float = 0.0
    private: dict = field(default_factory=dict)

    @classmethod
    def at_rest(cls, model: Model) -> "State":
        return cls(x=model.X.copy(), v=np.zeros_like(model.X), t=0.0)

    def copy(self) -> "State":
        return State(
            x=self.x.copy(),
            v=self.v.copy(),
            t=self.t,
            private={k: (v.copy() if hasattr(v, "copy") else v) for k, v in self.private.items()},
        )
