"""Grasping (attachment of tissue nodes to a tool) and contact with static planes with Coulomb friction, for XPBD.

Both are position constraints solved inside XPBD's Gauss-Seidel sweeps (``sim.integrators.xpbd.solver``):

- **Grasp** (issue 21 item 2): at ``t_close`` the free nodes within ``radius`` of the tool's path point attach to
  it with their current offset ``o_i = x_i - c(t_close)``; until ``t_release`` each is held by the vector
  constraint ``C_i = x_i - (c(t) + o_i)`` with compliance ``alpha`` (0: rigid). XPBD's update per sweep,
  ``dlambda = (-C - alpha~ lambda) / (w + alpha~)``, ``x += w dlambda`` (Macklin et al. 2016, eqs. 17-18,
  ``alpha~ = alpha / h^2``). The tool's paths translate (no rotation), so the nodes follow the jaws rigidly.
  The constraint force on node i is ``lambda_i / h^2``; a node whose force exceeds ``tear_force`` [N] at the end
  of a substep is released for good (the attachment tears).
- **Plane contact**: ``n . (x - p) >= 0``; a node below is moved onto the plane (the plane is static, infinite
  mass). Its normal corrections over the substep ``d_n`` are summed; after the sweeps, Coulomb friction on the
  tangential motion ``dx_t`` since the substep began (Macklin et al. 2014 §6.1, Müller et al. 2020 §3.5): static
  (``|dx_t| < mu d_n``: undone whole), else kinetic (reduced by ``mu d_n``).

The loads (sum of ``m dx`` the constraints applied, and their moments) are the impulses ``m dx / h``; over a
step of ``dt`` the force on the tool / plane is minus their sum divided by ``h dt`` (as ``sim.probe``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.wrench import add_wrench


@dataclass
class Grasp:
    """Tool ``probe`` (index into ``Model.probes``) grasps at ``t_close`` and lets go at ``t_release`` [s] the
    nodes within ``radius`` [m] of its path point; ``compliance`` [m/N]; ``tear_force`` [N] per node (None: never)."""

    probe: int
    t_close: float
    t_release: float
    radius: float
    compliance: float = 0.0
    tear_force: float | None = None


@dataclass
class ContactPlane:
    """Static plane through ``point`` with unit outward ``normal``; Coulomb coefficient ``friction``; acting on
    ``nodes`` only (None: every node; a body's own nodes in a merged model, ``sim.contact_bodies``)."""

    point: np.ndarray
    normal: np.ndarray
    friction: float = 0.0
    nodes: np.ndarray | None = None

    def __post_init__(self):
        self.point = np.asarray(self.point, dtype=np.float64).reshape(3)
        n = np.asarray(self.normal, dtype=np.float64).reshape(3)
        length = np.linalg.norm(n)
        if not length > 0.0:
            raise ValueError(f"contact plane normal must be non-zero, found {list(n)}")
        self.normal = n / length
        if not self.friction >= 0.0:
            raise ValueError(f"contact plane friction must be >= 0, found {self.friction}")


class GraspState:
    """The run-time state of one grasp: the attached nodes, their offsets, multipliers (n, 3)."""

    def __init__(self, grasp: Grasp, probe):
        self.grasp = grasp
        self.probe = probe
        self.nodes = np.zeros(0, dtype=np.int64)
        self.offsets = np.zeros((0, 3))
        self.lam = np.zeros((0, 3))
        self.closed = False  # closed once: nodes torn or released stay free
        self.torn = 0

    def update(self, x: np.ndarray, w: np.ndarray, t_start: float, t: float) -> None:
        """At the start of a substep from ``t_start`` (positions ``x``) to ``t``: close in the first substep ending at
        or after ``t_close`` (offsets from the tool at ``t_start``); release in the first ending at or after
        ``t_release``."""
        g = self.grasp
        if not self.closed and g.t_close <= t < g.t_release:
            c = self.probe.position(t_start)
            near = (np.linalg.norm(x - c, axis=1) <= g.radius) & (w > 0.0)
            self.nodes = np.flatnonzero(near)
            self.offsets = x[self.nodes] - c
            self.lam = np.zeros((self.nodes.size, 3))
            self.closed = True
        elif self.nodes.size and t >= g.t_release:
            self.detach(np.ones(self.nodes.size, dtype=bool))

    def detach(self, which: np.ndarray) -> None:
        keep = ~which
        self.nodes, self.offsets, self.lam = self.nodes[keep], self.offsets[keep], self.lam[keep]

    def reset(self) -> None:
        self.lam[:] = 0.0

    def project(self, x: np.ndarray, w: np.ndarray, t: float, inv_dt2: float, load: np.ndarray) -> None:
        """One XPBD pass over the attachments; adds ``sum m dx`` and its moment about the tool's centre to ``load``."""
        if not self.nodes.size:
            return
        c = self.probe.position(t)
        target = c + self.offsets
        wi = w[self.nodes][:, None]
        alpha = self.grasp.compliance * inv_dt2
        C = x[self.nodes] - target
        dlam = (-C - alpha * self.lam) / (wi + alpha)
        self.lam += dlam
        dx = wi * dlam
        x[self.nodes] += dx
        j = dlam  # m dx = dlambda (w dlambda = dx)
        load[:3] += j.sum(axis=0)
        load[3:] += np.cross(x[self.nodes] - c, j).sum(axis=0)

    def tear(self, inv_dt2: float) -> None:
        """Release the nodes whose constraint force ``|lambda| / h^2`` exceeded ``tear_force``."""
        limit = self.grasp.tear_force
        if limit is None or not self.nodes.size:
            return
        over = np.linalg.norm(self.lam, axis=1) * inv_dt2 > limit
        if over.any():
            self.torn += int(over.sum())
            self.detach(over)

    @property
    def held(self) -> np.ndarray:
        return self.nodes


class PlaneState:
    """One static plane's contact over a substep: the summed normal corrections per node."""

    def __init__(self, plane: ContactPlane, n_nodes: int):
        self.plane = plane
        self.dn = np.zeros(n_nodes)
        self.acts = None  # (n,) bool: the nodes it acts on, None: all
        if plane.nodes is not None:
            self.acts = np.zeros(n_nodes, dtype=bool)
            self.acts[np.asarray(plane.nodes, dtype=np.int64)] = True

    def reset(self) -> None:
        self.dn[:] = 0.0

    def project(self, x: np.ndarray, w: np.ndarray, load: np.ndarray) -> None:
        """Move the free nodes below the plane onto it; adds ``sum m dx`` to ``load[:3]`` and its moment about the
        plane's ``point`` to ``load[3:]`` (:func:`project_onto_plane`)."""
        p = self.plane
        acts = self.acts if self.acts is not None else np.ones(0, dtype=bool)
        project_onto_plane(x, w, p.point, p.normal, acts, self.dn, load)

    def friction(self, x: np.ndarray, x_prev: np.ndarray, w: np.ndarray, load: np.ndarray) -> None:
        """Coulomb friction on the nodes that touched the plane this substep (static or kinetic)."""
        mu = self.plane.friction
        touched = np.flatnonzero(self.dn > 0.0)
        if mu == 0.0 or not touched.size:
            return
        n = self.plane.normal
        dx = x[touched] - x_prev[touched]
        dx_t = dx - (dx @ n)[:, None] * n
        slip = np.linalg.norm(dx_t, axis=1)
        limit = mu * self.dn[touched]
        # static: undo the whole tangential motion; kinetic: remove mu d_n of it
        scale = np.where(slip < limit, 1.0, limit / np.where(slip > 0.0, slip, 1.0))
        corr = -scale[:, None] * dx_t
        x[touched] += corr
        j = corr / w[touched][:, None]
        load[:3] += j.sum(axis=0)
        load[3:] += np.cross(x[touched] - self.plane.point, j).sum(axis=0)


@njit(cache=True)
def project_onto_plane(x, w, point, normal, acts, dn, load):
    """Every free node (``w > 0``; of ``acts`` if not empty) below the plane ``n . (x - point) >= 0`` moved onto it
    along ``n``; its depth added to ``dn``, its impulse ``m dx`` to ``load[:3]`` and its moment about ``point`` to
    ``load[3:]``. A kernel: it runs in every sweep."""
    for i in range(x.shape[0]):
        if w[i] <= 0.0 or (acts.size and not acts[i]):
            continue
        d = ((x[i, 0] - point[0]) * normal[0] + (x[i, 1] - point[1]) * normal[1]
             + (x[i, 2] - point[2]) * normal[2])
        if d >= 0.0:
            continue
        depth = -d
        x[i, 0] += depth * normal[0]
        x[i, 1] += depth * normal[1]
        x[i, 2] += depth * normal[2]
        dn[i] += depth
        m = depth / w[i]
        jx, jy, jz = m * normal[0], m * normal[1], m * normal[2]
        rx, ry, rz = x[i, 0] - point[0], x[i, 1] - point[1], x[i, 2] - point[2]
        add_wrench(load, 1.0, jx, jy, jz, rx, ry, rz)
