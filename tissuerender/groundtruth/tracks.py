"""Long-range point tracks through the deformation: query points on the tissue seen in frame 1, followed as
material points (triangle and barycentrics of the render surface) through every frame's geometry.

Query points are given in the scene (``[output] track_queries = [[t, y, x], ...]``: frame index from 0, pixel
row and column of a pixel that sees a surface in that frame; the track starts at the point that pixel sees, as
every pass shows it), or else ``n`` pixel centres drawn without replacement (``numpy.random.default_rng(seed)``, the
scene seed) from the pixels of frame 1 that see a simulated body, in the raster of ``motion.frame_raster`` (pixel
centres, as every pass). Each query's material point is the point that pixel sees; in frame ``k`` it is
``X_k = sum_i b_i P_k,i`` over the same triangle (``motion`` module docstring, step 1), projected through
``motion.points_motion`` (through the lens, if any: distorted pixels), which also makes the flow's occlusion
test. Each frame's raster is made once and shared with the flows (``sequence.finish_sequence``).

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
from tissuerender.groundtruth.motion import FrameRaster, Geometry, carried_through_cut, lens_of, points_motion

def sample_queries(first: FrameRaster, body_objects, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(indices into frame 1's covered pixels (row-major) of the chosen queries (N,), their (row, col) (N, 2)):
    ``n`` pixels seeing a render object in ``body_objects``, drawn without replacement, in pixel order."""
    covered = first.covered
    rows, cols = np.nonzero(covered)
    tissue = np.flatnonzero(np.isin(first.tri_object[first.tri_id[covered]], list(body_objects)))
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(tissue, size=min(int(n), tissue.size), replace=False)) if tissue.size else tissue
    return chosen, np.stack([rows[chosen], cols[chosen]], axis=1)


class Tracks:
    """Tracks through a sequence of ``frames`` frames, filled one frame at a time (:meth:`add_frame`, any order)
    from each frame's :class:`motion.FrameRaster`, which the flows share; :meth:`arrays` gives the ``tracks.npz``
    arrays (module docstring).

    ``raster_of(t)`` gives the raster of frame index ``t`` (from 0) for the frames that hold query points:
    frame 0 when ``n`` queries are sampled on its visible tissue, else the frames of the given ``queries``
    ([t, y, x]: frame index from 0, pixel row and column; ``[output] track_queries``). A given query whose
    pixel sees nothing is a ValueError."""

    def __init__(self, frames: int, raster_of, body_objects, n: int, seed: int, queries=None):
        self.groups = []  # (query frame's raster, rows of the queries, their clipped triangle (N,), barycentrics)
        if queries is None or len(queries) == 0:
            first = raster_of(0)
            chosen, pixels = sample_queries(first, body_objects, n, seed)
            self._add_group(first, np.arange(chosen.size), chosen)
            query = np.concatenate([np.zeros((chosen.size, 1)), pixels.astype(float)], axis=1)
        else:
            query = np.asarray(queries, float).reshape(-1, 3)
            for t in np.unique(query[:, 0]).astype(int):
                rows = np.flatnonzero(query[:, 0] == t)
                source = raster_of(t)
                covered = source.covered
                y, x = query[rows, 1].astype(np.int64), query[rows, 2].astype(np.int64)
                blank = ~covered[y, x]
                if blank.any():
                    i = rows[np.argmax(blank)]
                    raise ValueError(f"track_queries[{i}] = {query[i].astype(int).tolist()}: the pixel sees nothing "
                                     f"in frame index {t}")
                order = np.cumsum(covered.ravel()) - 1  # pixel -> index among the covered pixels (row-major)
                self._add_group(source, rows, order[y * covered.shape[1] + x])
        count = query.shape[0]
        self.query = query
        self.points_2d = np.zeros((count, frames, 2))
        self.points_3d = np.zeros((count, frames, 3))
        self.occluded = np.zeros((count, frames), bool)

    def _add_group(self, source: FrameRaster, rows: np.ndarray, chosen: np.ndarray) -> None:
        covered = source.covered
        self.groups.append((source, rows, np.ascontiguousarray(source.tri_id[covered][chosen]),
                            np.ascontiguousarray(source.bary[covered][chosen])))

    def add_frame(self, k: int, target: FrameRaster) -> None:
        """Column ``k`` (frame index from 0) from that frame's raster: each query's material point
        ``X_k = sum_i b_i P_k,i``, its pixel and its occlusion (``motion.points_motion``)."""
        for source, rows, tri, bary in self.groups:
            points_k = carried_through_cut(source, target.geometry.points, source.triangles[tri])
            _, uv2, _, X2, occluded = points_motion(source, tri, bary, points_k, target)
            self.points_3d[rows, k] = X2
            self.points_2d[rows, k] = uv2
            self.occluded[rows, k] = occluded

    def arrays(self) -> dict:
        return {"query_points": self.query.astype(np.float32), "points_2d": self.points_2d.astype(np.float32),
                "points_3d": self.points_3d.astype(np.float32), "occluded": self.occluded}


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
