"""The camera model as vision code reads it: OpenCV intrinsics ``K`` and world-to-camera poses, and the table of
segmentation instance ids.

The renderer's pinhole (``tissuerender.renderer.raster.project``) maps a point at camera coordinates
``(xv, yv, zv)`` (``xv`` along the camera's right, ``yv`` along its up, ``zv`` along its forward axis) to the
continuous screen position ``sx = (xv / zv / tan_x + 1) W / 2``, ``sy = (1 - yv / zv / tan_y) H / 2``, with
``tan_x = tan(fov_deg / 2)`` (the field of view is horizontal) and ``tan_y = tan_x H / W``; pixel ``i`` spans
``[i, i + 1)`` and is sampled at its centre ``i + 0.5``. In OpenCV's convention (x right, y down, z forward;
pixel centres at integer coordinates) the same map is ``u = fx x / z + cx``, ``v = fy y / z + cy`` with

    fx = fy = W / (2 tan_x),    cx = W / 2 - 1/2,    cy = H / 2 - 1/2,

and ``(x, y, z) = (xv, -yv, zv)``: the rows of the world-to-camera rotation are the camera's right, down and
forward axes. With ``[camera.lens]`` the frame is a fisheye image: ``cameras.json`` then gives the distorted
camera's K and its Kannala-Brandt coefficients (``tissuerender.groundtruth.lens``). Along a camera path each
frame's entry holds that frame's pose.
"""
from __future__ import annotations

import numpy as np

from tissuerender.groundtruth.scope import SCOPE_MASK, scope_mask_params
from tissuerender.renderer.camera import Camera, camera_basis

CONVENTIONS = ("OpenCV pinhole camera: camera axes x right, y down, z forward; world_to_camera maps world "
               "metres to camera metres (X_cam = R X_world + t); K maps camera coordinates to pixels with the "
               "centre of pixel (column u, row v) at integer (u, v) and (0, 0) the top-left pixel; depth is camera "
               "z in metres (inf where nothing is seen); no lens distortion is applied to colour or passes.")
LENS_CONVENTIONS = (
    "OpenCV fisheye (Kannala-Brandt) camera: camera axes x right, y down, z forward; world_to_camera maps world "
    "metres to camera metres (X_cam = R X_world + t); a camera point (x, y, z) has a = x/z, b = y/z, "
    "r = sqrt(a^2 + b^2), theta = atan(r), theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) "
    "with distortion.coefficients = [k1, k2, k3, k4], and lands at pixel (u, v, 1) = K (theta_d / r a, "
    "theta_d / r b, 1) (K applies after the distortion, as in cv2.fisheye), the centre of pixel (column u, row v) "
    "at integer (u, v) and (0, 0) the top-left pixel; colour and every pass are distorted images (passes "
    "resampled at the nearest pinhole sample); depth is camera z in metres (inf where nothing is seen).")


def intrinsics(camera: Camera) -> np.ndarray:
    """K (3, 3) of the renderer's pinhole with horizontal field of view ``camera.fov_deg`` (square pixels)."""
    w, h = int(camera.width), int(camera.height)
    f = w / (2.0 * np.tan(np.radians(camera.fov_deg) / 2.0))
    return np.array([[f, 0.0, w / 2.0 - 0.5], [0.0, f, h / 2.0 - 0.5], [0.0, 0.0, 1.0]])


def world_to_camera(camera: Camera) -> np.ndarray:
    """The 4 x 4 rigid transform from world metres to OpenCV camera metres (x right, y down, z forward)."""
    r, u, f = camera_basis(camera.position, camera.look_at, camera.up)
    R = np.stack([r, -u, f])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.asarray(camera.position, float)
    return T


def camera_entry(camera: Camera, index: int, time: float) -> dict:
    """One frame's entry of ``cameras.json``."""
    return {"index": int(index), "time": float(time), "world_to_camera": world_to_camera(camera).tolist()}


def cameras_document(camera: Camera, frames: list[dict], lens=None) -> dict:
    """``cameras.json``: image size, K, distortion and one entry per frame written so far. With a ``lens``
    (``tissuerender.groundtruth.lens.FisheyeLens``) K is the distorted camera's and ``distortion`` its model."""
    if lens is None:
        K, distortion, conventions = intrinsics(camera), {"model": "none", "coefficients": []}, CONVENTIONS
    else:
        K, distortion = lens.K, {"model": "kannala_brandt", "coefficients": [float(c) for c in lens.k]}
        conventions = LENS_CONVENTIONS
    return {"width": int(camera.width), "height": int(camera.height), "K": np.asarray(K).tolist(),
            "distortion": distortion, "conventions": conventions, "frames": frames}


def labels(scene) -> list[dict]:
    """The segmentation instances in id order: 0 the background, then one per render object in the order
    ``tissuerender.render_inputs.render_objects`` draws them (bodies, static surfaces, visible tools; bodies
    and surfaces each in scene order, as ``tissuerender.world.build_world`` builds them), so the instance id
    of render object ``k`` is ``k + 1``. ``class`` is the semantic class: the tissue's material preset for
    bodies and surfaces, ``"tool"`` for tools; last, ``"scope_mask"`` when the effect chain has the
    laparoscope mask (``tissuerender.groundtruth.scope``)."""
    table = [{"id": 0, "name": "background", "kind": "background", "class": "background"}]
    for kind in ("body", "surface"):
        for obj in scene.objects:
            if obj.kind == kind:
                table.append({"id": len(table), "name": obj.name, "kind": kind, "class": obj.material})
    for tool in scene.tools:
        if tool.visible:
            table.append({"id": len(table), "name": tool.name, "kind": "tool", "class": "tool"})
    if scope_mask_params(scene) is not None:  # the pixels the laparoscope mask blacks out (groundtruth.scope)
        table.append({"id": len(table), "name": SCOPE_MASK, "kind": SCOPE_MASK, "class": SCOPE_MASK})
    return table


def scope_mask_id(scene) -> int | None:
    """The scope mask's instance id (the last one), None when the effect chain has no laparoscope mask."""
    last = labels(scene)[-1]
    return last["id"] if last["kind"] == SCOPE_MASK else None
