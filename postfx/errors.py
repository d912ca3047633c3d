"""Errors shared by the post-effect chain and its GL backend."""
from __future__ import annotations

import numpy as np


class OSMesaUnavailable(RuntimeError):
    """The off-screen OpenGL backend cannot run here (message names what to install)."""


class NonFiniteOutput(ValueError):
    """An effect gave non-finite values (NaN, ±inf): ``effect`` (its name, or the names of a fused run
    joined by "+"; None where the backend cannot tell which one), ``count`` pixels, the first at ``first``
    (row, column) with ``value``."""

    def __init__(self, effect: str | None, count: int, first: tuple[int, int], value):
        self.effect, self.count, self.first, self.value = effect, int(count), first, value
        super().__init__(f"{effect or 'the chain'}: {count} pixel(s) with non-finite values "
                         f"(first at pixel {first}: {value})")


def check_output(effect: str | None, image: np.ndarray) -> None:
    """Raise :class:`NonFiniteOutput` when ``image`` (H, W[, C]) holds a non-finite value."""
    image = np.asarray(image)
    bad = ~np.isfinite(image)
    if not bad.any():
        return
    per_pixel = bad.reshape(image.shape[0], image.shape[1], -1).any(axis=2)
    first = tuple(int(i) for i in np.argwhere(per_pixel)[0])
    raise NonFiniteOutput(effect, int(per_pixel.sum()), first, image[first].tolist())
