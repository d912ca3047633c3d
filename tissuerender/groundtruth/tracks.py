"""Long-range point tracks through the deformation: query points on the tissue seen in frame 1, followed as
material points (triangle and barycentrics of the render surface) through every frame's geometry.

Query points are given in the scene (``[output] track_queries = [[t, y, x], ...]``: frame index from 0, pixel
row and column of a pixel that sees a surface in that frame; the track starts at the point that pixel sees, as
every pass shows it), or else ``n`` pixel centres drawn without replacement (``numpy.random.default_rng(seed)``, the
scene seed) from the pixels of frame 1 that see a simulated body, in the raster of ``motion.carry`` (pixel
centres, as every pass). Each query's material point is the point that pixel sees; in frame ``k`` it is
``X_k = sum_i b_i P_k,i`` over the same triangle (``motion`` module docstring, step 1), projected through
``motion._project`` (through the lens, if any: distorted pixels); it is occluded in frame ``k`` by ``motion.occluded_in`` (the flow's occlusion test).

Files (``write_tracks``), in the output folder:

- ``tracks.npz``: ``query_points`` (N, 3) float32 ``[t, y, x]`` (frame index from 0, pixel row and column,
  OpenCV pixel centres at integers), ``points_2d`` (N, T, 2) float32 pixels ``(x, y)``, ``points_3d`` (N, T, 3)
  float32 world metres, ``occluded`` (N, T) bool.
- ``tracks_tapvid.pkl``: the TAP-Vid DAVIS layout, ``{scene name: {"video": (T, H, W, 3) uint8, "points":
  (N, T, 2) float32, "occluded": (N, T) bool}}`` with points normalised to [0, 1] by TAP-Vid's corner
  convention, ``((x + 0.5) / W, (y + 0.5) / H)`` (0 the image's left/top edge, 1 its right/bottom edge). The
  video is the written ``frame_NNNN.png`` frames (black where PNGs are not written).
- ``tracks_tapvid3d.npz``: the TAPVid-3D layout, ``tracks_XYZ`` (T, N, 3) float32 in each frame's OpenCV camera
  coordinates [m], ``visibility`` (T, N) bool, ``fx_fy_cx_cy`` (4,) float64 of ``K``, ``queries_xyt`` (N, 3)
  float32 ``[x, y, t]``; no ``images_jpeg_bytes`` (the frames are the PNGs). Through ``[camera.lens]`` the 2D
  points are distorted pixels, ``fx_fy_cx_cy`` is the distorted camera's ``K`` and the file adds
  ``fisheye_k1_k4`` (4,) float64 and a ``lens_note`` string saying that the lens applies.
"""
from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np
from PIL import Image

from tissuerender.files import write_atomic
from tissuerender.groundtruth.cameras import intrinsics, world_to_camera
from tissuerender.groundtruth.motion import Geometry, _project, carry, lens_of, occluded_in, visible_surface

CHUNK = 8  # frames carried per re-raster of frame 1 (each adds 3 float64 attributes per vertex)


def sample_queries(first: Geometry, body_objects, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(indices into frame 1's covered pixels (row-major) of the chosen queries (N,), their (row, col) (N, 2)):
    ``n`` pixels seeing a render object in ``body_objects``, drawn without replacement, in pixel order."""
    carried = carry(first, [])
    rows, cols = np.nonzero(carried.covered)
    tissue = np.flatnonzero(np.isin(carried.obj, list(body_objects)))
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(tissue, size=min(int(n), tissue.size), replace=False)) if tissue.size else tissue
    return chosen, np.stack([rows[chosen], cols[chosen]], axis=1)


def compute_tracks(geometries: list[Geometry], body_objects, n: int, seed: int, queries=None) -> dict:
    """Tracks through ``geometries`` (frames 1..T) of ``n`` query points sampled on frame 1's visible tissue, or
    of the given ``queries`` ([t, y, x]: frame index from 0, pixel row and column; ``[output] track_queries``):
    the ``tracks.npz`` arrays (module docstring). A given query whose pixel sees nothing is a ValueError."""
    frames = len(geometries)
    if queries is None or len(queries) == 0:
        chosen, pixels = sample_queries(geometries[0], body_objects, n, seed)
        groups = [(0, np.arange(chosen.size), chosen)]
        query = np.concatenate([np.zeros((chosen.size, 1)), pixels.astype(float)], axis=1)
    else:
        query = np.asarray(queries, float).reshape(-1, 3)
        groups = []
        for t in np.unique(query[:, 0]).astype(int):
            rows = np.flatnonzero(query[:, 0] == t)
            covered = carry(geometries[t], []).covered
            y, x = query[rows, 1].astype(np.int64), query[rows, 2].astype(np.int64)
            blank = ~covered[y, x]
            if blank.any():
                i = rows[np.argmax(blank)]
                raise ValueError(f"track_queries[{i}] = {query[i].astype(int).tolist()}: the pixel sees nothing in "
                                 f"frame index {t}")
            order = np.cumsum(covered.ravel()) - 1  # pixel -> index among the covered pixels (row-major)
            groups.append((t, rows, order[y * covered.shape[1] + x]))
    count = query.shape[0]
    points_2d = np.zeros((count, frames, 2))
    points_3d = np.zeros((count, frames, 3))
    occluded = np.zeros((count, frames), bool)
    for start in range(0, frames, CHUNK):
        chunk = geometries[start:start + CHUNK]
        visible = [visible_surface(geom) for geom in chunk]
        for t, rows, chosen in groups:
            carried = carry(geometries[t], [g.points for g in chunk])
            for j, geom in enumerate(chunk):
                X = carried.targets[j][chosen]
                points_3d[rows, start + j] = X
                points_2d[rows, start + j] = _project(X, geom.camera, lens_of(geom.camera, geom.lens_k))[0]
                occluded[rows, start + j] = occluded_in(X, carried.corners[j][chosen], visible[j], geom.camera)
    return {"query_points": query.astype(np.float32), "points_2d": points_2d.astype(np.float32),
            "points_3d": points_3d.astype(np.float32), "occluded": occluded}


def _video(out: Path, frames: int, width: int, height: int) -> np.ndarray:
    """(T, H, W, 3) uint8 of the written frame PNGs (black for a frame without one)."""
    video = np.zeros((frames, height, width, 3), np.uint8)
    for k in range(frames):
        path = Path(out) / f"frame_{k + 1:04d}.png"
        if path.exists():
            with Image.open(path) as im:
                video[k] = np.asarray(im.convert("RGB"))
    return video


def _write_bytes(path: Path, data: bytes) -> Path:
    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(data)

    write_atomic(path, write)
    return path


def write_tracks(out: Path, tracks: dict, geometries: list[Geometry], name: str) -> list[Path]:
    """``tracks.npz``, ``tracks_tapvid.pkl`` and ``tracks_tapvid3d.npz`` in ``out`` (module docstring)."""
    out = Path(out)
    camera = geometries[0].camera
    w, h = int(camera.width), int(camera.height)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **tracks)
    written = [_write_bytes(out / "tracks.npz", buffer.getvalue())]
    normalised = (tracks["points_2d"] + 0.5) / np.array([w, h], np.float32)
    tapvid = {name: {"video": _video(out, len(geometries), w, h), "points": normalised.astype(np.float32),
                     "occluded": tracks["occluded"]}}
    written.append(_write_bytes(out / "tracks_tapvid.pkl", pickle.dumps(tapvid, protocol=4)))
    xyz = np.stack([tracks["points_3d"][:, k].astype(float) @ world_to_camera(g.camera)[:3, :3].T
                    + world_to_camera(g.camera)[:3, 3] for k, g in enumerate(geometries)])
    lens = lens_of(camera, geometries[0].lens_k)
    K = intrinsics(camera) if lens is None else lens.K
    q = tracks["query_points"]
    extra = {} if lens is None else {"fisheye_k1_k4": np.asarray(lens.k, float),
                                     "lens_note": np.array("fx_fy_cx_cy are the Kannala-Brandt (OpenCV fisheye) "
                                                           "camera's: project through fisheye_k1_k4 as well")}
    buffer = io.BytesIO()
    np.savez_compressed(buffer, tracks_XYZ=xyz.astype(np.float32).reshape(len(geometries), -1, 3),
                        visibility=~tracks["occluded"].T, fx_fy_cx_cy=np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]),
                        queries_xyt=np.stack([q[:, 2], q[:, 1], q[:, 0]], axis=1).astype(np.float32), **extra)
    written.append(_write_bytes(out / "tracks_tapvid3d.npz", buffer.getvalue()))
    return written
