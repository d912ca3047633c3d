"""Laparoscopic instruments: a grasper (shaft and two jaws) and an L-hook (shaft and an L-shaped hook), built
procedurally from capsules, so the shape that is drawn is the shape that pushes tissue.

Tool frame (local coordinates, origin at the instrument's tip joint, the keyframed ``position``):

- ``+z`` points from the handle towards the tip (the tool's ``axis`` when a keyframe gives no orientation);
  the shaft is the capsule from ``(0, 0, -length)`` to the origin, of the tool's ``radius`` r;
- grasper: two jaws of radius ``0.45 r`` and length ``7 r``, starting at ``(+-0.45 r, 0, 0)`` (closed jaws
  touch along the axis) and pointing along ``(+-sin(theta/2), 0, cos(theta/2))``, theta the jaw opening
  angle (keyframe ``jaw_deg``, linear in time; 30 deg where no keyframe gives it); the jaws open in the
  local x-z plane;
- l_hook: a wire of radius ``0.35 r``: ``4 r`` along ``+z`` from the origin, then ``2.5 r`` along ``+x``.

Pose at time t: position linear between keyframes, orientation (keyframe ``orientation``, a unit quaternion
``(w, x, y, z)`` taking the tool frame to the world; default the shortest rotation from ``+z`` to ``axis``)
spherically interpolated (slerp, Shoemake 1985) along the shorter arc, both held before the first keyframe and
after the last. At a keyframe the pose is that keyframe's exactly.

Drawn: each capsule as a closed triangle mesh whose vertices lie on the capsule's surface (radius r from its
segment, to rounding) and whose faces are chords inside it; contact: the same capsules, resolved by
``sim.probe``'s capsule projection, so tissue is pushed to within the drawn surface's chord depth of it.

Material: the ``steel`` preset (``materials.optics``), the renderer's GGX lobe with Schlick's Fresnel
``F = F0 + (1 - F0)(1 - v.h)^5`` (Schlick 1994) with no diffuse lobe, F0 = :data:`STEEL_F0`, the exact
conductor reflectance at normal incidence (:func:`conductor_fresnel`) of the complex index :data:`STEEL_NK`.
"""
from __future__ import annotations

import numpy as np

from sim.pose import bracket, quat_matrix, slerp
from sim.probe import Probe

INSTRUMENT_KINDS = ("grasper", "l_hook")
DEFAULT_JAW_DEG = 30.0
JAW_RADIUS, JAW_LENGTH = 0.45, 7.0  # x the tool's radius
HOOK_RADIUS, HOOK_REACH, HOOK_BEND = 0.35, 4.0, 2.5  # x the tool's radius

# Stainless steel (iron-like) at 550 nm, n + i k: an approximate value (iron, Johnson & Christy 1974, is
# n ~ 2.9, k ~ 3.1 near 550 nm); F0 = ((n-1)^2 + k^2) / ((n+1)^2 + k^2) = 0.533, grey over the visible range.
STEEL_NK = (2.9, 3.1)


def conductor_fresnel(cos_i, n: float, k: float):
    """Unpolarised Fresnel reflectance of a conductor of complex index ``n + i k`` seen from air at incidence
    cosine ``cos_i`` (exact, e.g. pbrt-v4 ``FrComplex``): the mean of ``|r_s|^2`` and ``|r_p|^2`` with
    ``r_s = (cos_i - eta cos_t) / (cos_i + eta cos_t)``, ``r_p = (eta cos_i - cos_t) / (eta cos_i + cos_t)``
    and the complex ``cos_t = sqrt(1 - sin_i^2 / eta^2)``. 1 at grazing (cos_i = 0)."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    eta = complex(n, k)
    sin2 = 1.0 - c * c
    cos_t = np.sqrt(1.0 - sin2 / (eta * eta) + 0j)
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


STEEL_F0 = float(conductor_fresnel(1.0, *STEEL_NK))


def quat_from_axis(axis) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of the shortest rotation taking +z to ``axis`` (half-way vector form)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    if a[2] < -1.0 + 1e-12:  # opposite: half a turn about x
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([1.0 + a[2], -a[1], a[0], 0.0])  # (1 + z.a, z x a)
    return q / np.linalg.norm(q)


def _keyframe_orientations(tool) -> np.ndarray:
    default = quat_from_axis(tool.axis)
    out = []
    for k in tool.keyframes:
        q = getattr(k, "orientation", None)
        out.append(default if q is None else np.asarray(q, float) / np.linalg.norm(q))
    return np.array(out)


def pose(tool, t: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(position (3,), rotation matrix (3, 3) tool frame -> world, jaw opening angle [rad]) at time ``t``."""
    times = np.array([k.t for k in tool.keyframes], dtype=np.float64)
    positions = np.array([k.position for k in tool.keyframes], dtype=np.float64)
    position = np.array([np.interp(t, times, positions[:, c]) for c in range(3)])
    i, j, u = bracket(times, t)
    qs = _keyframe_orientations(tool)
    q = slerp(qs[i], qs[j], u)
    jaws = np.array([DEFAULT_JAW_DEG if getattr(k, "jaw_deg", None) is None else k.jaw_deg for k in tool.keyframes])
    return position, quat_matrix(q), float(np.radians(np.interp(t, times, jaws)))


def local_capsules(kind: str, radius: float, length: float, jaw: float = 0.0) -> list[tuple]:
    """The instrument's capsules (a (3,), b (3,), radius) in the tool frame (module docstring)."""
    o = np.zeros(3)
    caps = [(np.array([0.0, 0.0, -length]), o, radius)]
    if kind == "grasper":
        rj, lj = JAW_RADIUS * radius, JAW_LENGTH * radius
        for side in (1.0, -1.0):
            a = np.array([side * rj, 0.0, 0.0])
            caps.append((a, a + lj * np.array([side * np.sin(0.5 * jaw), 0.0, np.cos(0.5 * jaw)]), rj))
    elif kind == "l_hook":
        rh = HOOK_RADIUS * radius
        bend = np.array([0.0, 0.0, HOOK_REACH * radius])
        caps += [(o, bend, rh), (bend, bend + np.array([HOOK_BEND * radius, 0.0, 0.0]), rh)]
    else:
        raise ValueError(f"instrument kind must be one of {', '.join(INSTRUMENT_KINDS)}, found {kind!r}")
    return caps


def capsules(tool, t: float) -> list[tuple]:
    """The instrument's capsules in world coordinates at time ``t``."""
    p, R, jaw = pose(tool, t)
    return [(p + R @ a, p + R @ b, r) for a, b, r in local_capsules(tool.kind, tool.radius, tool.length, jaw)]


def capsule_mesh(a, b, radius: float, count: int = 16):
    """A closed triangle mesh (vertices (n, 3), triangles (m, 3) int32, outward) of the capsule a-b of
    ``radius``: vertices on its surface, faces chords inside it."""
    import trimesh  # heavy: only scenes with visible tools need it (as render_inputs.tool_surface)

    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b - a
    h = float(np.linalg.norm(d))
    # built at unit radius and scaled: trimesh merges the seam's vertices with an absolute tolerance (1e-8),
    # which leaves a millimetre capsule built at its own size open
    m = trimesh.creation.capsule(height=h / radius, radius=1.0, count=[count, count])
    R = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / h)[:3, :3] if h > 0.0 else np.eye(3)
    return radius * (np.asarray(m.vertices) @ R.T) + 0.5 * (a + b), np.asarray(m.faces, dtype=np.int32)


def instrument_surface(tool, t: float):
    """The drawn instrument at time ``t``: (vertices, triangles, vertex normals), the union of its capsules'
    closed meshes (each capsule its own closed shell)."""
    pts, tris, nrm, offset = [], [], [], 0
    for a, b, r in capsules(tool, t):
        v, f = capsule_mesh(a, b, r)
        c = _closest_on_segment(v, a, b)
        pts.append(v)
        tris.append(f + offset)
        nrm.append((v - c) / r)  # exact normals of the capsule at its surface vertices
        offset += len(v)
    return np.concatenate(pts), np.concatenate(tris).astype(np.int32), np.concatenate(nrm)


def _closest_on_segment(p, a, b):
    ab = b - a
    len2 = float(ab @ ab)
    s = np.zeros(len(p)) if len2 == 0.0 else np.clip((p - a) @ ab / len2, 0.0, 1.0)
    return a + s[:, None] * ab


class InstrumentProbe(Probe):
    """The simulation's contact shape of an instrument: its capsules (:func:`capsules`) at every time."""

    KINDS = INSTRUMENT_KINDS

    def __init__(self, tool):
        self.tool = tool
        times = np.array([k.t for k in tool.keyframes], dtype=np.float64)
        positions = np.array([k.position for k in tool.keyframes], dtype=np.float64)
        super().__init__(kind=tool.kind, radius=tool.radius, times=times, positions=positions,
                         axis=np.asarray(tool.axis, dtype=np.float64), length=tool.length)

    def capsules(self, t: float) -> list[tuple]:
        return capsules(self.tool, t)
