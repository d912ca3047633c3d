"""The laparoscope's camera: a pinhole with a horizontal field of view (thin-lens focus and aperture are
carried for the depth-of-field post-effect)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Camera:
    """Pinhole laparoscope: ``fov_deg`` is horizontal; thin-lens focus/aperture feed depth of field."""

    position: tuple
    look_at: tuple
    up: tuple
    fov_deg: float
    near: float
    far: float
    width: int
    height: int
    focus_distance: float | None = None
    aperture: float = 0.0


def camera_basis(position, look_at, up):
    """Orthonormal (right, up, forward) of a camera looking from ``position`` at ``look_at``."""
    f = np.asarray(look_at, float) - np.asarray(position, float)
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, float))
    r /= np.linalg.norm(r)
    return r, np.cross(r, f), f
