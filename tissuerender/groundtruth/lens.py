"""The laparoscope's wide-angle lens (issue 18 item 3; docs/ground-truth.md, "Lens"): OpenCV's fisheye model
(Kannala & Brandt 2006, "A generic camera model and calibration method for conventional, wide-angle, and
fish-eye lenses"; OpenCV ``cv::fisheye``), cos^4 vignetting, and the one remap that turns a pinhole render
into the distorted image for colour and every pass.

The model, in OpenCV's fisheye convention (K applies after the distortion of theta). A point at camera
coordinates ``(x, y, z)`` (OpenCV axes: x right, y down, z forward) has

    a = x / z,  b = y / z,  r = sqrt(a^2 + b^2),  theta = atan(r),
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8),
    (x_d, y_d) = (theta_d / r) (a, b),   u = fx x_d + cx,   v = fy y_d + cy.

*Undistorted pixels* are ``(fx a + cx, fy b + cy)``: the pinhole with the same ``K`` (OpenCV's
``fisheye.undistortPoints(..., P=K)``). ``distort`` maps undistorted pixels to distorted ones, ``undistort``
inverts it by Newton's method on ``theta`` (``theta_d(theta) = r_d``; ``theta_d`` is checked to increase over
the image, so the root is unique).

``camera.fov_deg`` is the angle the distorted image's width spans: ``fx = fy = (W / 2) / theta_d(fov / 2)``,
``cx = W / 2 - 1/2``, ``cy = H / 2 - 1/2`` (pixel centres at integer coordinates, as for the pinhole).

**The remap.** A frame is rendered with a pinhole of focal length ``fx`` (so the centre of the image is
sampled one to one) and a size just large enough that the undistorted position of every distorted pixel
centre lies inside it with a pixel to spare: ``W_p = ceil(2 fx max|a| + 1) + 2`` (likewise ``H_p``). Each
distorted pixel centre is undistorted once into the pinhole (``map_u``, ``map_v``); colour is resampled
there bilinearly, every pass at the nearest pinhole pixel (see ``remap_nearest``).

**Vignetting** multiplies the linear HDR colour by ``1 - s (1 - cos^4 theta)`` after the remap and before the
post-effects (``theta`` the distorted pixel's ray angle, ``s`` the strength): the natural falloff of image
irradiance (cos^4 law) scaled by ``s``. It touches no pass.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tissuerender.groundtruth.cameras import intrinsics
from tissuerender.renderer.camera import Camera

# Most the pinhole may grow per side relative to the output before a lens is refused: beyond it the corner rays
# approach 90 degrees from the axis, where a pinhole cannot follow (tan theta diverges).
MAX_PINHOLE_SCALE = 4.0
NEWTON_ITERATIONS = 60


def theta_distorted(theta: np.ndarray, k) -> np.ndarray:
    """``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``."""
    t2 = theta * theta
    return theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))


def theta_distorted_slope(theta: np.ndarray, k) -> np.ndarray:
    """``d theta_d / d theta = 1 + 3 k1 theta^2 + 5 k2 theta^4 + 7 k3 theta^6 + 9 k4 theta^8``."""
    t2 = theta * theta
    return 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))


def distort_normalised(ab: np.ndarray, k) -> np.ndarray:
    """Undistorted normalised coordinates ``(a, b)`` (..., 2) -> distorted ``(x_d, y_d)`` (..., 2)."""
    ab = np.asarray(ab, float)
    r = np.hypot(ab[..., 0], ab[..., 1])
    theta = np.arctan(r)
    scale = np.ones_like(r)  # theta_d / r -> 1 on the axis
    off_axis = r > 0.0
    scale[off_axis] = theta_distorted(theta[off_axis], k) / r[off_axis]
    return ab * scale[..., None]


def solve_theta(theta_d: np.ndarray, k, theta_max: float = np.pi / 2) -> np.ndarray:
    """``theta`` in [0, theta_max] with ``theta_distorted(theta) = theta_d``, by Newton's method kept inside a
    bisection bracket (``theta_distorted`` increases on the bracket). Converges to a few ulps of theta."""
    theta_d = np.asarray(theta_d, float)
    lo = np.zeros_like(theta_d)
    hi = np.full_like(theta_d, theta_max)
    theta = np.clip(theta_d, 0.0, theta_max)
    for _ in range(NEWTON_ITERATIONS):
        residual = theta_distorted(theta, k) - theta_d
        lo = np.where(residual < 0.0, theta, lo)
        hi = np.where(residual > 0.0, theta, hi)
        slope = theta_distorted_slope(theta, k)
        step = np.where(slope > 0.0, residual / np.where(slope > 0.0, slope, 1.0), np.inf)
        candidate = theta - step
        inside = (candidate > lo) & (candidate < hi)
        new = np.where(inside, candidate, 0.5 * (lo + hi))
        if np.array_equal(new, theta):
            break
        theta = new
    return theta


def undistort_normalised(xy_d: np.ndarray, k) -> np.ndarray:
    """Distorted normalised coordinates (..., 2) -> undistorted ``(a, b)`` (..., 2)."""
    xy_d = np.asarray(xy_d, float)
    r_d = np.hypot(xy_d[..., 0], xy_d[..., 1])
    theta = solve_theta(r_d, k)
    scale = np.ones_like(r_d)
    off_axis = r_d > 0.0
    scale[off_axis] = np.tan(theta[off_axis]) / r_d[off_axis]
    return xy_d * scale[..., None]


def _pixels_to_normalised(p: np.ndarray, K: np.ndarray) -> np.ndarray:
    p = np.asarray(p, float)
    return np.stack([(p[..., 0] - K[0, 2]) / K[0, 0], (p[..., 1] - K[1, 2]) / K[1, 1]], axis=-1)


def _normalised_to_pixels(xy: np.ndarray, K: np.ndarray) -> np.ndarray:
    return np.stack([K[0, 0] * xy[..., 0] + K[0, 2], K[1, 1] * xy[..., 1] + K[1, 2]], axis=-1)


def distort(points_undistorted_px: np.ndarray, K: np.ndarray, k) -> np.ndarray:
    """Undistorted pixels (..., 2) (the pinhole with the same ``K``) -> distorted pixels (..., 2)."""
    return _normalised_to_pixels(distort_normalised(_pixels_to_normalised(points_undistorted_px, K), k), K)


def undistort(points_distorted_px: np.ndarray, K: np.ndarray, k) -> np.ndarray:
    """Distorted pixels (..., 2) -> undistorted pixels (..., 2), the inverse of :func:`distort`."""
    return _normalised_to_pixels(undistort_normalised(_pixels_to_normalised(points_distorted_px, K), k), K)


def fisheye_intrinsics(fov_deg: float, width: int, height: int, k) -> np.ndarray:
    """K (3, 3) of the distorted camera whose width spans ``fov_deg``: ``fx = fy = (W / 2) / theta_d(fov / 2)``."""
    f = (width / 2.0) / float(theta_distorted(np.radians(fov_deg) / 2.0, k))
    return np.array([[f, 0.0, width / 2.0 - 0.5], [0.0, f, height / 2.0 - 0.5], [0.0, 0.0, 1.0]])


def check_lens(fov_deg: float, width: int, height: int, k) -> float:
    """The largest ray angle [rad] the distorted image sees (at its corner pixels' centres); ValueError with
    the reason when ``theta_d`` does not increase up to it, or it is too close to 90 degrees for a pinhole."""
    half = np.radians(fov_deg) / 2.0
    grid = np.linspace(0.0, np.pi / 2, 9001)
    slope = theta_distorted_slope(grid, k)
    turn = grid[np.argmax(slope <= 0.0)] if (slope <= 0.0).any() else np.pi / 2
    if turn <= half:
        raise ValueError(f"theta_d stops increasing at theta = {np.degrees(turn):.1f} deg, inside the image "
                         f"(half the field of view is {np.degrees(half):.1f} deg): no one-to-one image")
    f = (width / 2.0) / float(theta_distorted(half, k))
    r_corner = np.hypot((width - 1) / 2.0, (height - 1) / 2.0) / f
    reach = theta_distorted(grid, k)
    seen = (reach >= r_corner) & (grid < turn)
    if not seen.any():
        raise ValueError(f"the image corners need rays beyond {np.degrees(turn):.1f} deg from the axis, where "
                         "theta_d stops increasing or a pinhole cannot follow; lower camera.fov_deg or change "
                         "the coefficients")
    return float(solve_theta(np.array([r_corner]), k, float(grid[np.argmax(seen)]))[0])


def distort_pixels(uv: np.ndarray, lens: "FisheyeLens | None") -> np.ndarray:
    """Pixel positions ``uv`` (..., 2) computed through ``K`` as a pinhole (flow end points, point tracks) -> where
    the frame shows them: ``lens.distort_pixels(uv)``, or ``uv`` itself without a lens (None)."""
    return np.asarray(uv, float) if lens is None else lens.distort_pixels(uv)


@dataclass(frozen=True)
class FisheyeLens:
    """A Kannala-Brandt lens on a ``width`` x ``height`` image: distorted intrinsics ``K``, coefficients
    ``k`` = (k1, k2, k3, k4), vignetting strength; ``pinhole`` the camera the frame is rendered with and
    ``map_u``, ``map_v`` (H, W) where each distorted pixel centre lands in it (pinhole pixels, centres at
    integers); ``theta`` (H, W) each distorted pixel's ray angle [rad]."""

    K: np.ndarray
    k: tuple
    vignetting: float
    pinhole: Camera
    map_u: np.ndarray
    map_v: np.ndarray
    theta: np.ndarray

    @property
    def width(self) -> int:
        return self.map_u.shape[1]

    @property
    def height(self) -> int:
        return self.map_u.shape[0]

    def distort(self, points_undistorted_px: np.ndarray) -> np.ndarray:
        return distort(points_undistorted_px, self.K, self.k)

    def undistort(self, points_distorted_px: np.ndarray) -> np.ndarray:
        return undistort(points_distorted_px, self.K, self.k)

    def distort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Pixel positions ``uv`` (..., 2) projected through ``K`` as a pinhole (undistorted pixels, e.g. flow
        end points or point tracks) -> where the distorted image shows them. NaN stays NaN."""
        return self.distort(uv)

    def project(self, points_camera: np.ndarray) -> np.ndarray:
        """Camera coordinates (..., 3) (OpenCV axes, z > 0) -> distorted pixels (..., 2)."""
        p = np.asarray(points_camera, float)
        return _normalised_to_pixels(distort_normalised(p[..., :2] / p[..., 2:3], self.k), self.K)

    def vignette(self) -> np.ndarray:
        """(H, W) factor ``1 - s (1 - cos^4 theta)`` on linear colour."""
        return 1.0 - self.vignetting * (1.0 - np.cos(self.theta) ** 4)

    def remap_bilinear(self, image: np.ndarray) -> np.ndarray:
        """Colour (H_p, W_p, C) of the pinhole -> (H, W, C) of the distorted image, bilinear in the pinhole
        pixel grid (float64 weights, the result in the input's dtype)."""
        u0 = np.floor(self.map_u).astype(np.intp)
        v0 = np.floor(self.map_v).astype(np.intp)
        wu = (self.map_u - u0)[..., None]
        wv = (self.map_v - v0)[..., None]
        img = np.asarray(image, float)
        out = ((1.0 - wv) * ((1.0 - wu) * img[v0, u0] + wu * img[v0, u0 + 1])
               + wv * ((1.0 - wu) * img[v0 + 1, u0] + wu * img[v0 + 1, u0 + 1]))
        return out.astype(image.dtype)

    def remap_nearest(self, array: np.ndarray) -> np.ndarray:
        """A pass (H_p, W_p, ...) -> (H, W, ...): each distorted pixel takes the value of the pinhole pixel whose
        centre is nearest to its ray (ties round half to even). Ids and masks are never blended, and depth,
        normal and material coordinates stay the values of one real surface point, the same one for every
        pass at a pixel (a blend across an edge would invent a point between foreground and background); that
        point lies on the ray of a pinhole pixel centre at most half a pinhole pixel from the distorted
        pixel's own ray."""
        return np.asarray(array)[np.rint(self.map_v).astype(np.intp), np.rint(self.map_u).astype(np.intp)]

    def apply(self, result) -> None:
        """Turn a pinhole ``FrameResult`` into the distorted frame in place: colour bilinear times the
        vignetting, view depth and every ground-truth pass nearest. The G-buffer stays the pinhole's."""
        hdr = self.remap_bilinear(result.hdr)
        if self.vignetting > 0.0:
            hdr = (hdr * self.vignette()[..., None]).astype(result.hdr.dtype)
        result.hdr = hdr
        result.depth = self.remap_nearest(result.depth)
        result.passes = {name: self.remap_nearest(array) for name, array in result.passes.items()}


def fisheye_lens(camera: Camera, k, vignetting: float = 0.0) -> FisheyeLens:
    """The lens for ``camera`` (its ``fov_deg`` the distorted image's horizontal field, its size the output's)
    with coefficients ``k``; ValueError (``check_lens``) when the model cannot image the field."""
    k = tuple(float(c) for c in k)
    width, height = int(camera.width), int(camera.height)
    check_lens(camera.fov_deg, width, height, k)
    K = fisheye_intrinsics(camera.fov_deg, width, height, k)
    f = K[0, 0]
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    ab = _pixels_to_normalised(undistort(np.stack([u, v], axis=-1), K, k), K)
    theta = np.arctan(np.hypot(ab[..., 0], ab[..., 1]))
    # the pinhole: focal length f, centred, one pixel to spare around the furthest sample (bilinear reads i + 1)
    width_p = int(np.ceil(2.0 * f * np.abs(ab[..., 0]).max() + 1.0)) + 2
    height_p = int(np.ceil(2.0 * f * np.abs(ab[..., 1]).max() + 1.0)) + 2
    if width_p > MAX_PINHOLE_SCALE * width or height_p > MAX_PINHOLE_SCALE * height:
        raise ValueError(f"the corner rays reach {np.degrees(theta.max()):.1f} deg from the axis: the pinhole render "
                         f"would need {width_p} x {height_p} pixels (more than {MAX_PINHOLE_SCALE:g} times the "
                         f"image per side); lower camera.fov_deg or change the coefficients")
    fov_p = float(np.degrees(2.0 * np.arctan(width_p / (2.0 * f))))
    pinhole = replace(camera, width=width_p, height=height_p, fov_deg=fov_p)
    # the renderer's own K of the pinhole (f_p = W_p / (2 tan(fov_p / 2)), f up to rounding) places the samples
    K_p = intrinsics(pinhole)
    map_u = K_p[0, 0] * ab[..., 0] + K_p[0, 2]
    map_v = K_p[1, 1] * ab[..., 1] + K_p[1, 2]
    return FisheyeLens(K=K, k=k, vignetting=float(vignetting), pinhole=pinhole, map_u=map_u, map_v=map_v, theta=theta)
