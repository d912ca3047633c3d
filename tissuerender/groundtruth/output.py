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

from tissuerender.files import write_atomic, write_json

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


def write_passes(out: Path, index: int, passes: dict, body_ids: list[int]) -> list[Path]:
    """Write frame ``index``'s passes; ``body_ids`` are the instance ids of simulated bodies (where material
    coordinates must be finite). Returns the paths written."""
    written = []
    ids = passes.get("segmentation")
    depth = passes.get("depth")
    seen = ids > 0 if ids is not None else (np.isfinite(depth) if depth is not None else None)
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
