"""Ray queries for shadows, thickness and ambient occlusion: our numba BVH or Intel Embree.

Both answer the same two questions with the same conventions (``tissuerender.renderer.bvh.BVH``):
``occluded(origins, targets, eps)`` (a triangle strictly between the two points, the segment shortened
by ``eps`` at both ends) and ``closest_hit(origins, directions, t_max)``.

Embree (through the ``embreex`` wheel) traces shadow rays and closest hits several times faster per core
than the numba BVH (median split, 4 triangles per leaf), and builds in comparable time
(docs/renderer.md, "How fast, and why"). So ``backend = "auto"`` takes Embree when ``embreex`` imports
and the numba BVH otherwise; both are tested to give the same answers.
Embree works in float32: the offsets the renderer uses (2e-4 of the scene size) are far above its
rounding at scene scale. Embree releases the GIL, so batches are split over ``numba.get_num_threads()``
Python threads, the same thread budget the numba kernels use.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from tissuerender.renderer.bvh import BVH

BACKENDS = ("auto", "embree", "numba")
MIN_RAYS_PER_THREAD = 20_000


def embree_available() -> bool:
    try:
        # embreex is an optional fast path: imported only here and in EmbreeRays, the numba BVH is the fallback
        import embreex.rtcore_scene  # noqa: F401
    except ImportError:
        return False
    return True


class EmbreeRays:
    """Embree scene over ``points[triangles]`` with the BVH query interface."""

    name = "embree"

    def __init__(self, points: np.ndarray, triangles: np.ndarray):
        # optional fast path (see embree_available): lazy so the renderer imports without embreex
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self._scene = rtcore_scene.EmbreeScene()
        if len(self.triangles):
            # embreex copies element by element through Python indexing: float64 / int64 arrays (converted to
            # Embree's float32 / uint32 on the way, the same values as a NumPy cast) copy faster than float32
            # / int32 ones (docs/renderer.md, "How fast, and why")
            TriangleMesh(self._scene, self.points, self.triangles)
            # Embree builds its BVH at the first query: one zero-length ray here, so the build is timed with
            # the construction (the renderer's "bvh" stage) rather than inside the first batch of rays
            self._scene.run(np.zeros((1, 3), np.float32), np.array([[0.0, 0.0, 1.0]], np.float32),
                            query="OCCLUDED", dists=np.zeros(1, np.float32))

    def _run(self, origins, directions, dists, query):
        n = origins.shape[0]
        if n == 0 or len(self.triangles) == 0:
            return np.full(n, -1, np.int32) if query == "OCCLUDED" else np.full(n, np.inf, np.float32)
        threads = max(1, min(numba.get_num_threads(), n // MIN_RAYS_PER_THREAD))
        args = (np.ascontiguousarray(origins, dtype=np.float32), np.ascontiguousarray(directions, dtype=np.float32),
                np.ascontiguousarray(dists, dtype=np.float32))
        if threads == 1:
            return np.asarray(self._scene.run(*args[:2], query=query, dists=args[2]))
        bounds = np.linspace(0, n, threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            parts = [pool.submit(self._scene.run, *(a[lo:hi] for a in args[:2]), query=query, dists=args[2][lo:hi])
                     for lo, hi in zip(bounds[:-1], bounds[1:])]
            return np.concatenate([np.asarray(p.result()) for p in parts])

    def occluded_rays(self, origins: np.ndarray, directions: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """True where a unit ray hits a triangle within its length (``lengths`` > 0)."""
        return self._run(origins, directions, lengths, "OCCLUDED") != -1

    def occluded(self, origins: np.ndarray, targets: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        d = np.asarray(targets, float) - np.asarray(origins, float)
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        ok = length > 2 * eps
        out = np.zeros(len(length), bool)
        if not ok.any():
            return out
        idx = np.flatnonzero(ok)
        dirs = d[idx] / length[idx, None]
        hit = self._run(origins[idx] + eps * dirs, dirs, length[idx] - 2 * eps, "OCCLUDED")
        out[idx] = hit != -1
        return out

    def closest_hit(self, origins: np.ndarray, directions: np.ndarray, t_max: float = np.inf) -> np.ndarray:
        n = origins.shape[0]
        dists = np.full(n, min(t_max, 3.0e38))
        t = self._run(origins, directions, dists, "DISTANCE").astype(np.float64)
        t[t >= min(t_max, 3.0e38) * (1.0 - 1e-7)] = np.inf  # Embree reports tfar unchanged on a miss
        return t


def ray_scene(points: np.ndarray, triangles: np.ndarray, backend: str = "auto"):
    """The ray-query structure for a frame's triangles: ``EmbreeRays`` or the numba ``BVH``."""
    if backend not in BACKENDS:
        raise ValueError(f"ray backend must be one of {', '.join(BACKENDS)}, found {backend!r}")
    if backend == "embree" and not embree_available():
        raise RuntimeError("ray backend 'embree' needs the Python package embreex (pip install embreex)")
    if backend in ("auto", "embree") and embree_available():
        return EmbreeRays(points, triangles)
    return BVH(points, triangles)
