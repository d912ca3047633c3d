"""The moving laparoscope and its lens (issue 18 items 2 and 3; docs/ground-truth.md, "Moving camera" and
"Lens"): the keys of ``[[camera.path]]`` and ``[camera.lens]``.

Kept apart from ``schema`` so that the camera's new tables are declared in one place; ``schema.Camera`` only
names them.
"""
from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


def degenerate_view(position, look_at, up) -> str | None:
    """Why a camera pose has no orientation (None when it has one): the view direction is zero, or ``up``
    is parallel to it."""
    d = [a - b for a, b in zip(look_at, position)]
    if sum(c * c for c in d) < 1e-18:
        return "look_at must differ from position"
    cross = [d[1] * up[2] - d[2] * up[1], d[2] * up[0] - d[0] * up[2], d[0] * up[1] - d[1] * up[0]]
    if sum(c * c for c in cross) < 1e-18 * max(sum(u * u for u in up), 1e-300):
        return f"up {list(up)} must not be parallel to the view direction"
    return None


class CameraKeyframe(_Strict):
    """One pose of the laparoscope's path; between keyframes position, look_at and up are interpolated
    linearly in time (held before the first keyframe and after the last)."""

    t: Annotated[float, Field(ge=0.0, le=1e6, description="time [s] (frame k shows time (k-1)/fps)")]
    position: Annotated[Vec3, Field(description="laparoscope tip at t [m]")]
    look_at: Annotated[Vec3, Field(description="point in the centre of the view at t [m] (not equal to position)")]
    up: Vec3 | None = Field(None, description="up direction at t (default: camera.up); not parallel to the view")


class CameraLens(_Strict):
    """The laparoscope's wide-angle lens: OpenCV's fisheye model (Kannala & Brandt 2006) and a cos^4
    vignetting. A ray at angle ``theta`` from the optical axis lands at radius
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` (normalised image units) from
    the principal point; ``camera.fov_deg`` is then the angle the image's width spans."""

    model: Literal["kannala_brandt"] = Field("kannala_brandt", description=(
        "OpenCV fisheye (Kannala-Brandt): theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)"))
    coefficients: Annotated[list[Annotated[float, Field(ge=-10.0, le=10.0)]], Field(
        min_length=4, max_length=4, description=(
            "[k1, k2, k3, k4]; [0, 0, 0, 0] is the equidistant fisheye (theta_d = theta); theta_d must increase "
            "with theta over the image"))]
    vignetting: Annotated[float, Field(ge=0.0, le=1.0, description=(
        "strength s of the natural falloff: linear radiance times 1 - s (1 - cos^4 theta), theta the pixel's ray "
        "angle from the optical axis; 1 the full cos^4 law, 0 none"))] = 0.0


def check_path(path: list[CameraKeyframe], default_up) -> None:
    """Keyframe times increase strictly and every keyframe's pose has an orientation."""
    times = [k.t for k in path]
    if any(b <= a for a, b in zip(times, times[1:])):
        raise ValueError(f"path: keyframe times must increase strictly, found {times}")
    for i, k in enumerate(path):
        problem = degenerate_view(k.position, k.look_at, k.up if k.up is not None else default_up)
        if problem:
            raise ValueError(f"path[{i}]: {problem}")
