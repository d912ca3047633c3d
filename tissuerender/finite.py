"""Non-finite values (NaN, ±inf) are caught where they arise, never written: the renderer's stages check
their outputs (vertex positions at ``raster``, ``thickness``, radiance at ``shade``, the image at
``resolve``), the pipeline checks the post-effects' output (``postfx.<effect>``), and the writers refuse
what slips through (``tissuerender.files``). Each check names the stage, the object the first bad value
belongs to and how many there are; :func:`tissuerender.pipeline.render_hdr` and ``postprocess`` add the
scene file and the frame (:meth:`NonFiniteError.located`). A user error (exit 2): the values come from
the scene (a material or light override, a simulation that blew up, a mesh).
"""
from __future__ import annotations

import numpy as np

from tissuerender.errors import UserError


class NonFiniteError(UserError):
    """Non-finite values in ``what`` at ``stage``: ``count`` of them, the first at ``first`` (an index
    tuple, or a pixel for image stages) with ``value``; ``object_index`` is the render object (the frame's
    object list) the first one belongs to, None where unknown. ``object_name``, ``frame`` and ``scene_path``
    are filled in by :meth:`located`."""

    def __init__(self, stage: str, what: str, count: int, first, value, object_index: int | None = None,
                 object_name: str | None = None, frame: int | None = None, scene_path=None, pixels: bool = False):
        self.stage, self.what, self.count, self.first, self.value = stage, what, int(count), first, value
        self.pixels = pixels  # count and first are of pixels (row, column), not of entries
        self.object_index, self.object_name, self.frame, self.scene_path = object_index, object_name, frame, scene_path
        super().__init__(self._message())

    def _message(self) -> str:
        where = f"{self.scene_path}: " if self.scene_path is not None else ""
        frame = f"frame {self.frame}: " if self.frame is not None else ""
        if self.object_name is not None:
            obj = f", object {self.object_name!r}"
        elif self.object_index is not None:
            obj = f", object #{self.object_index}"
        else:
            obj = ""
        if self.pixels:
            counted, at = f"{self.count} pixel(s) with non-finite {self.what}", f"pixel {_index(self.first)}"
        else:
            counted, at = f"{self.count} non-finite {self.what}", _index(self.first)
        return (f"{where}{frame}stage {self.stage}: {counted} (first at {at}{obj}: {self.value}); "
                "nothing of this frame was written")

    def located(self, scene_path, frame: int, object_names=()) -> "NonFiniteError":
        """The same error naming the scene file, the frame and the object (``object_names`` in the order of
        the frame's render objects)."""
        name = self.object_name
        if name is None and self.object_index is not None and 0 <= self.object_index < len(object_names):
            name = object_names[self.object_index] or None
        return NonFiniteError(self.stage, self.what, self.count, self.first, self.value, self.object_index, name,
                              frame, scene_path, self.pixels)


def frame_at(t: float, fps: float) -> int:
    """The 1-based number of the frame drawn at time ``t`` [s] (frame k is drawn at (k - 1) / fps)."""
    return int(round(t * fps)) + 1


def _index(first) -> str:
    return "(" + ", ".join(str(int(i)) for i in first) + ")" if isinstance(first, tuple) else str(first)


def non_finite(values: np.ndarray, allow_inf: bool = False) -> np.ndarray:
    """Mask of the bad entries of ``values`` (NaN or ±inf; only NaN and -inf with ``allow_inf``)."""
    values = np.asarray(values)
    return np.isnan(values) | (values == -np.inf) if allow_inf else ~np.isfinite(values)


def check_finite(values: np.ndarray, what: str, stage: str, object_of=None, pixel_of=None,
                 allow_inf: bool = False) -> None:
    """Raise :class:`NonFiniteError` when ``values`` holds a non-finite entry.

    ``object_of(i)`` gives the object index of row ``i`` (the first bad row); ``pixel_of(rows)`` maps the
    bad rows to pixels (a (n, 2) array of (row, column)): then the count is of distinct pixels and the
    first is a pixel. ``allow_inf``: +inf is a valid value (a thickness ray that left nothing within reach).
    """
    values = np.asarray(values)
    if values.size == 0 or not np.issubdtype(values.dtype, np.floating):
        return
    bad = non_finite(values, allow_inf)
    if not bad.any():
        return
    rows = np.flatnonzero(bad.reshape(values.shape[0], -1).any(axis=1)) if values.ndim > 1 else np.flatnonzero(bad)
    first_entry = tuple(int(i) for i in np.argwhere(bad)[0])
    value = values[first_entry]
    first: tuple = first_entry if values.ndim > 1 else (first_entry[0],)
    count = int(bad.sum())
    if pixel_of is not None:
        pixels = np.asarray(pixel_of(rows)).reshape(-1, 2)
        count = int(np.unique(pixels, axis=0).shape[0])
        first = tuple(int(i) for i in pixels[0])
    object_index = object_of(int(rows[0])) if object_of is not None else None
    object_index = int(object_index) if object_index is not None else None
    raise NonFiniteError(stage, what, count, first, value, object_index, pixels=pixel_of is not None)


def check_image(image: np.ndarray, what: str, stage: str, object_at=None) -> None:
    """:func:`check_finite` for an image (H, W[, C]): counts pixels, names the first by (row, column);
    ``object_at(row, column)`` gives the object index covering a pixel (None: not known)."""
    image = np.asarray(image)
    width = image.shape[1]
    rows = image.reshape(image.shape[0] * width, -1)
    object_of = (lambda r: object_at(*divmod(r, width))) if object_at is not None else None
    check_finite(rows, what, stage, object_of, lambda r: np.stack(np.divmod(r, width), axis=1))
