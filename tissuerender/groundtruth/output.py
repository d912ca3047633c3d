"""The ground-truth files: ``passes/<pass>_NNNN.npy`` per frame, ``cameras.json`` and ``labels.json`` per
sequence, each written atomically (``tissuerender.files.write_atomic``).

The pass arrays hold non-finite values by design (inf depth and NaN normals where nothing is seen, NaN
material coordinates off the simulated tissue), so they bypass ``write_npy``'s refusal of non-finite values;
instead every value is checked against where it may occur: a non-finite value on a pixel that sees something
(or, for material coordinates, sees a body) is refused like any other.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tissuerender.errors import UserError
from tissuerender.files import write_atomic, write_json
from tissuerender.groundtruth.motion import Geometry
from tissuerender.renderer.camera import Camera

PASSES_FOLDER = "passes"


def pass_path(out: Path, name: str, index: int) -> Path:
    return Path(out) / PASSES_FOLDER / f"{name}_{index:04d}.npy"


def _check(path: Path, name: str, array: np.ndarray, seen: np.ndarray, tissue: np.ndarray) -> None:
    """Non-finite values only where the pass documents them."""
    if not np.issubdtype(array.dtype, np.floating):
        return
    finite = np.isfinite(array) if array.ndim == 2 else np.isfinite(array).all(axis=2)
    allowed = ~(tissue if name == "material_coords" else seen)
    bad = ~finite & ~allowed
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(f"{path}: refusing to write {int(bad.sum())} non-finite values where a surface is seen "
                         f"(first at row {row}, column {col})")


def write_passes(out: Path, index: int, passes: dict, body_ids: list[int], scope_id: int | None = None) -> list[Path]:
    """Write frame ``index``'s passes; ``body_ids`` are the instance ids of simulated bodies (where material
    coordinates must be finite), ``scope_id`` the scope mask's (its pixels may see nothing). Returns the paths
    written."""
    written = []
    ids = passes.get("segmentation")
    depth = passes.get("depth")
    seen = (ids > 0) & (ids != scope_id) if ids is not None else (np.isfinite(depth) if depth is not None else None)
    tissue = np.isin(ids, body_ids) if ids is not None else None
    for name, array in passes.items():
        path = pass_path(out, name, index)
        if seen is not None and (name != "material_coords" or tissue is not None):
            _check(path, name, array, seen, tissue)

        def write(tmp, array=array):
            with open(tmp, "wb") as f:
                np.save(f, array)

        write_atomic(path, write)
        written.append(path)
    return written


def write_cameras(out: Path, document: dict) -> Path:
    path = Path(out) / "cameras.json"
    write_json(path, document)
    return path


def write_labels(out: Path, table: list[dict]) -> Path:
    """``labels.json``: ``{"instances": [{"id", "name", "kind", "class"}, ...]}`` in id order."""
    path = Path(out) / "labels.json"
    write_json(path, {"background_id": 0, "instances": table})
    return path


# ---- motion ground truth (docs/ground-truth.md, "Flow, scene flow and tracks") ----

TOPOLOGY_FILE = "geometry_topology.npz"
CAMERA_KEYS = ("position", "look_at", "up", "fov_deg", "near", "far", "width", "height")


def geometry_path(out: Path, index: int) -> Path:
    return Path(out) / PASSES_FOLDER / f"geometry_{index:04d}.npz"


def _write_npz(path: Path, arrays: dict) -> None:
    # stored, not deflated: float32 vertex positions shrink by 7 % only, for twice the writing time (the
    # topology, once per sequence, is read back by every frame's write_geometry to compare)
    def write(tmp):
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)

    write_atomic(path, write)


def write_geometry(out: Path, index: int, geometry, time: float) -> list[Path]:
    """Frame ``index``'s render geometry (``motion.Geometry``): ``passes/geometry_NNNN.npz`` with ``points``
    (n, 3) float32 [m], the frame's ``time`` [s] and the camera (``camera_<field>`` of
    ``tissuerender.renderer.camera.Camera``) and, through a lens, its coefficients ``lens_k`` (4,); the sequence's triangles once in ``passes/geometry_topology.npz``
    (``triangles`` (t, 3) int32, ``tri_object`` (t,) int32), rewritten only when they differ (another scene
    rendered into the folder before)."""
    written = []
    topology = Path(out) / PASSES_FOLDER / TOPOLOGY_FILE
    triangles = np.asarray(geometry.triangles, np.int32)
    tri_object = np.asarray(geometry.tri_object, np.int32)
    same = False
    if topology.exists():
        try:
            with np.load(topology) as old:
                same = np.array_equal(old["triangles"], triangles) and np.array_equal(old["tri_object"], tri_object)
        except (OSError, ValueError, KeyError):
            same = False
    if not same:
        _write_npz(topology, {"triangles": triangles, "tri_object": tri_object})
        written.append(topology)
    cam = geometry.camera
    arrays = {"points": np.asarray(geometry.points, np.float32), "time": np.float64(time)}
    arrays.update({f"camera_{k}": np.asarray(getattr(cam, k), float) for k in CAMERA_KEYS})
    if geometry.lens_k is not None:
        arrays["lens_k"] = np.asarray(geometry.lens_k, float)
    path = geometry_path(out, index)
    _write_npz(path, arrays)
    return written + [path]


def read_geometry(out: Path, index: int):
    """``motion.Geometry`` of frame ``index`` from ``passes/`` (a UserError naming the file when it is missing
    or unreadable)."""
    path = geometry_path(out, index)
    topology = Path(out) / PASSES_FOLDER / TOPOLOGY_FILE
    for p in (path, topology):
        if not p.exists():
            raise UserError(f"{p}: no such file: frame {index}'s render geometry is written by a render whose "
                            "output.passes lists flow, scene_flow or tracks")
    try:
        with np.load(topology) as top, np.load(path) as g:
            triangles, tri_object = top["triangles"], top["tri_object"]
            points = g["points"]
            values = {k: g[f"camera_{k}"] for k in CAMERA_KEYS}
            lens_k = tuple(g["lens_k"].tolist()) if "lens_k" in g.files else None
    except (OSError, ValueError, KeyError) as e:
        raise UserError(f"{path}: expected a render geometry file (points, camera_*), found an unreadable one: "
                        f"{e}") from None
    camera = Camera(position=tuple(values["position"].tolist()), look_at=tuple(values["look_at"].tolist()),
                    up=tuple(values["up"].tolist()), fov_deg=float(values["fov_deg"]), near=float(values["near"]),
                    far=float(values["far"]), width=int(values["width"]), height=int(values["height"]))
    if triangles.size and int(triangles.max()) >= points.shape[0]:
        raise UserError(f"{path}: expected {int(triangles.max()) + 1} or more vertices for {topology.name}, "
                        f"found {points.shape[0]}")
    return Geometry(points, triangles, tri_object, camera, lens_k)


def write_array(path: Path, array: np.ndarray) -> Path:
    """One ``.npy`` file (NaN allowed: motion passes are NaN where nothing is seen)."""
    def write(tmp):
        with open(tmp, "wb") as f:
            np.save(f, array)

    write_atomic(path, write)
    return path
