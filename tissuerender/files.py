"""Output files written atomically: a temporary file in the target's folder, then ``os.replace`` onto the
target, so a reader (or a render interrupted mid-write) never sees a partial file.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` then rename onto ``path``. The temporary name keeps ``path``'s suffix, so
    writers that choose the format by suffix (meshio) write the right one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_png(path: Path, rgb: np.ndarray) -> None:
    """An 8-bit RGB image (H, W, 3) as PNG."""
    write_atomic(path, lambda tmp: Image.fromarray(rgb).save(tmp, format="PNG"))


def write_json(path: Path, data: dict) -> None:
    write_atomic(path, lambda tmp: Path(tmp).write_text(json.dumps(data, indent=2, sort_keys=False) + "\n"))


def write_npy(path: Path, array: np.ndarray) -> None:
    def write(tmp):
        with open(tmp, "wb") as f:
            np.save(f, array)

    write_atomic(path, write)
