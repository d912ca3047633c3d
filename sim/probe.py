"""Rigid tools: a sphere or capsule following a keyframed path, pushing tissue nodes out of itself.

Contact is resolved by projection (a unilateral position constraint, as in PBD): a node found inside
the probe is moved to the nearest point of its surface. :func:`resolve_contact_load` does the same and sums what
the projection did, ``sum_i m_i dx_i`` and ``sum_i (p_i - c) x m_i dx_i`` (``p_i`` the node's new position on the
surface, ``c`` the tool's centre): divided by the substep squared, the contact force and torque the tool exerts on
the tissue (the impulse ``m dx / h`` per substep h, Macklin et al. 2016 eq. 9: ``f = lambda grad C / h^2``). Integrators call it every substep with the
probe at the substep's time, so a probe moving less than its radius per substep cannot pass
through a node (no tunnelling at the speeds used in ``scenes/``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.wrench import add_wrench


@dataclass
class Probe:
    """``kind`` "sphere" or "capsule" (segment of ``length`` along ``axis`` centred on the path point)."""

    kind: str
    radius: float
    times: np.ndarray
    positions: np.ndarray
    axis: np.ndarray = None
    length: float = 0.0
    KINDS = ("sphere", "capsule")  # a subclass with other capsules (tissuerender.instruments) widens it

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        axis = np.array([0.0, 0.0, 1.0]) if self.axis is None else np.asarray(self.axis, dtype=np.float64)
        self.axis = axis / np.linalg.norm(axis)
        if self.kind not in self.KINDS:
            raise ValueError(f"probe kind must be one of {', '.join(self.KINDS)}, found {self.kind!r}")

    def position(self, t: float) -> np.ndarray:
        """Path point at time ``t`` (linear between keyframes, held before the first and after the last). The last
        one is kept: every sweep of a substep asks for the same time."""
        last = getattr(self, "_last", None)
        if last is None or last[0] != t:
            last = (t, np.array([np.interp(t, self.times, self.positions[:, k]) for k in range(3)]))
            self._last = last
        return last[1].copy()

    def segment(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        c = self.position(t)
        half = 0.5 * self.length * self.axis if self.kind == "capsule" else np.zeros(3)
        return c - half, c + half

    def capsules(self, t: float) -> list[tuple]:
        """The capsules (a, b, radius) the probe is made of at ``t``: here its one segment."""
        return [(*self.segment(t), float(self.radius))]

    def positions_at(self, ts) -> np.ndarray:
        """:meth:`position` at each of the times ``ts`` (n,): (n, 3), the same values."""
        ts = np.asarray(ts, dtype=np.float64).reshape(-1)
        return np.stack([np.interp(ts, self.times, self.positions[:, k]) for k in range(3)], axis=1)

    def capsule_rows(self, ts) -> np.ndarray:
        """:meth:`capsules` at each of the times ``ts`` (n,) as rows ``a, b, radius``: (n, capsules, 7), the same
        values (a subclass with other capsules overrides both, else its capsules are asked for one time at a time)."""
        ts = np.asarray(ts, dtype=np.float64).reshape(-1)
        if type(self).capsules is not Probe.capsules:
            return np.array([[[*a, *b, r] for a, b, r in self.capsules(float(t))] for t in ts],
                            dtype=np.float64).reshape(ts.size, -1, 7)
        c = self.positions_at(ts)
        half = 0.5 * self.length * self.axis if self.kind == "capsule" else np.zeros(3)
        return np.concatenate([c - half, c + half, np.full((ts.size, 1), float(self.radius))], axis=1)[:, None, :]

    def push_out(self, x: np.ndarray, t: float, inv_mass: np.ndarray, load: np.ndarray) -> int:
        """Project the free nodes out of the probe at ``t``, summing into ``load`` (:func:`resolve_contact_load`):
        every capsule in turn (a mesh tool, ``sim.contact_bodies.MeshProbe``, its triangles instead). The centre and
        capsules at ``t`` are kept: every sweep of a substep (``iterations`` of them) asks for the same time, and
        rebuilding them cost more than the kernel on a liver (issue 21, ``benchmarks/contact_cost.py``)."""
        kept = getattr(self, "_pushed", None)
        if kept is None or kept[0] != t:
            kept = (t, self.position(t), [(a, b, float(r)) for a, b, r in self.capsules(t)])
            self._pushed = kept
        _, centre, capsules = kept
        moved = 0
        for a, b, r in capsules:
            moved += push_out_of_capsule_load(x, inv_mass, a, b, r, centre, load)
        return int(moved)


def resolve_contact(x: np.ndarray, probe: Probe, t: float, inv_mass: np.ndarray) -> int:
    """Project the free nodes of ``x`` (in place) out of ``probe`` at time ``t``; returns how many moved
    (:func:`resolve_contact_load` with the load discarded: one kernel moves the nodes either way)."""
    return resolve_contact_load(x, probe, t, inv_mass, np.zeros(6))


@njit(cache=True, inline="always")
def _push_node(x, inv_mass, i, a, b, radius, centre, load):
    """Node i onto the capsule's surface if it is free and inside (:func:`push_out_of_capsule_load`); True if moved."""
    if inv_mass[i] == 0.0:
        return False
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    len2 = ab0 * ab0 + ab1 * ab1 + ab2 * ab2
    ap0, ap1, ap2 = x[i, 0] - a[0], x[i, 1] - a[1], x[i, 2] - a[2]
    s = 0.0
    if len2 > 0.0:
        s = min(max((ap0 * ab0 + ap1 * ab1 + ap2 * ab2) / len2, 0.0), 1.0)
    c0, c1, c2 = a[0] + s * ab0, a[1] + s * ab1, a[2] + s * ab2
    d0, d1, d2 = x[i, 0] - c0, x[i, 1] - c1, x[i, 2] - c2
    dist = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if not dist < radius:
        return False
    if dist < 1e-12:  # at the axis: push along +z (up, away from the tissue's support)
        d0, d1, d2, dist = 0.0, 0.0, 1.0, 1.0
    scale = radius / dist
    m = 1.0 / inv_mass[i]
    p0, p1, p2 = c0 + d0 * scale, c1 + d1 * scale, c2 + d2 * scale
    j0, j1, j2 = m * (p0 - x[i, 0]), m * (p1 - x[i, 1]), m * (p2 - x[i, 2])
    r0, r1, r2 = p0 - centre[0], p1 - centre[1], p2 - centre[2]
    add_wrench(load, 1.0, j0, j1, j2, r0, r1, r2)
    x[i, 0] = p0
    x[i, 1] = p1
    x[i, 2] = p2
    return True


@njit(cache=True)
def push_out_of_capsule_load(x, inv_mass, a, b, radius, centre, load):
    """Move every free node (inverse mass > 0) inside the capsule a-b of ``radius`` onto its surface (a sphere is
    the capsule with a == b), adding to ``load`` (6,) ``sum m dx`` [kg m] of the nodes it moves (``load[:3]``)
    and their moment ``sum (p - centre) x m dx`` about ``centre`` (``load[3:]``), p the node's new position.
    Returns the number of nodes moved."""
    moved = 0
    for i in range(x.shape[0]):
        if _push_node(x, inv_mass, i, a, b, radius, centre, load):
            moved += 1
    return moved


@njit(cache=True)
def push_nodes_out_of_capsule(x, inv_mass, nodes, a, b, radius, centre, load):
    """:func:`push_out_of_capsule_load` over ``nodes`` (ascending) only: the same result when no other node is
    inside (``sim.integrators.xpbd.sweeps`` lists the nodes near the capsule once per substep)."""
    moved = 0
    for k in range(nodes.size):
        if _push_node(x, inv_mass, nodes[k], a, b, radius, centre, load):
            moved += 1
    return moved


def resolve_contact_load(x: np.ndarray, probe: Probe, t: float, inv_mass: np.ndarray, load: np.ndarray) -> int:
    """:func:`resolve_contact`, summing into ``load`` (6,) the mass-weighted displacement and its moment about the
    probe's centre at ``t`` (:func:`push_out_of_capsule_load`), over every capsule of the probe."""
    return probe.push_out(x, t, inv_mass, load)
