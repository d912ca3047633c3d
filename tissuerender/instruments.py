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

from sim.pose import brackets, quat_matrices, quat_matrix, slerp, slerps  # noqa: F401 (quat_matrix, slerp: re-exported)
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


def keyframe_arrays(tool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tool's keyframes as arrays: times (k,), positions (k, 3), unit orientations (k, 4), jaw angles [deg]."""
    times = np.array([k.t for k in tool.keyframes], dtype=np.float64)
    positions = np.array([k.position for k in tool.keyframes], dtype=np.float64)
    default = quat_from_axis(tool.axis)
    qs = []
    for k in tool.keyframes:
        q = getattr(k, "orientation", None)
        qs.append(default if q is None else np.asarray(q, float) / np.linalg.norm(q))
    jaws = np.array([DEFAULT_JAW_DEG if getattr(k, "jaw_deg", None) is None else k.jaw_deg for k in tool.keyframes])
    return times, positions, np.array(qs), jaws


def pose_track(tool, ts, keys=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`pose` at each of the times ``ts`` (n,): positions (n, 3), rotations (n, 3, 3), jaw angles (n,) [rad],
    each row the one-time call's bit for bit (``sim.pose``); ``keys``: :func:`keyframe_arrays` of the tool."""
    times, positions, qs, jaws = keyframe_arrays(tool) if keys is None else keys
    ts = np.asarray(ts, dtype=np.float64).reshape(-1)
    position = np.stack([np.interp(ts, times, positions[:, c]) for c in range(3)], axis=1)
    i, j, u = brackets(times, ts)
    return position, quat_matrices(slerps(qs[i], qs[j], u)), np.radians(np.interp(ts, times, jaws))


def pose(tool, t: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(position (3,), rotation matrix (3, 3) tool frame -> world, jaw opening angle [rad]) at time ``t``."""
    position, R, jaw = pose_track(tool, [t])
    return position[0], R[0], float(jaw[0])


def local_capsule_track(kind: str, radius: float, length: float, jaw) -> list[tuple]:
    """The instrument's capsules (a (n, 3), b (n, 3), radius) in the tool frame (module docstring) at the jaw
    angles ``jaw`` (n,) [rad]."""
    jaw = np.asarray(jaw, dtype=np.float64).reshape(-1)
    n = jaw.size
    row = lambda v: np.tile(np.asarray(v, dtype=np.float64), (n, 1))  # noqa: E731
    o = row([0.0, 0.0, 0.0])
    caps = [(row([0.0, 0.0, -length]), o, radius)]
    if kind == "grasper":
        rj, lj = JAW_RADIUS * radius, JAW_LENGTH * radius
        for side in (1.0, -1.0):
            a = row([side * rj, 0.0, 0.0])
            tip = np.stack([side * np.sin(0.5 * jaw), np.zeros(n), np.cos(0.5 * jaw)], axis=1)
            caps.append((a, a + lj * tip, rj))
    elif kind == "l_hook":
        rh = HOOK_RADIUS * radius
        bend = row([0.0, 0.0, HOOK_REACH * radius])
        caps += [(o, bend, rh), (bend, bend + row([HOOK_BEND * radius, 0.0, 0.0]), rh)]
    else:
        raise ValueError(f"instrument kind must be one of {', '.join(INSTRUMENT_KINDS)}, found {kind!r}")
    return caps


def local_capsules(kind: str, radius: float, length: float, jaw: float = 0.0) -> list[tuple]:
    """The instrument's capsules (a (3,), b (3,), radius) in the tool frame (module docstring)."""
    return [(a[0], b[0], r) for a, b, r in local_capsule_track(kind, radius, length, [jaw])]


def capsule_track(tool, ts, keys=None) -> np.ndarray:
    """The instrument's capsules in world coordinates at each of the times ``ts`` (n,): (n, capsules, 7), rows
    ``a, b, radius`` (``p + R a`` per time: one BLAS product per time, as :func:`capsules`)."""
    p, R, jaw = pose_track(tool, ts, keys)
    rows = []
    for a, b, r in local_capsule_track(tool.kind, tool.radius, tool.length, jaw):
        world_a = p + np.matmul(R, np.ascontiguousarray(a)[:, :, None])[:, :, 0]
        world_b = p + np.matmul(R, np.ascontiguousarray(b)[:, :, None])[:, :, 0]
        rows.append(np.concatenate([world_a, world_b, np.full((p.shape[0], 1), float(r))], axis=1))
    return np.ascontiguousarray(np.stack(rows, axis=1))


def capsules(tool, t: float) -> list[tuple]:
    """The instrument's capsules in world coordinates at time ``t``."""
    return [(row[0:3], row[3:6], float(row[6])) for row in capsule_track(tool, [t])[0]]


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
        self.keys = keyframe_arrays(tool)  # the keyframes do not change: read once
        times, positions = self.keys[0], self.keys[1]
        super().__init__(kind=tool.kind, radius=tool.radius, times=times, positions=positions,
                         axis=np.asarray(tool.axis, dtype=np.float64), length=tool.length)

    def capsules(self, t: float) -> list[tuple]:
        return [(row[0:3], row[3:6], float(row[6])) for row in self.capsule_rows([t])[0]]

    def capsule_rows(self, ts) -> np.ndarray:
        return capsule_track(self.tool, ts, self.keys)
