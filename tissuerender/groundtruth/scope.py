"""The laparoscope's scope mask as a segmentation class (issue 18 item 1; docs/ground-truth.md, "Segmentation
and the scope mask").

When the scene's effect chain ends in the ``laparoscope_mask`` post-effect (listed under ``[effects]`` or from
a camera preset), the pixels it blacks out, those whose mask weight (``postfx.laparoscope_mask.mask_weights``
at the output size, the very weights the effect multiplies the image by) is exactly 0, show no scene at all.
They get their own instance in ``labels.json`` (the last id, ``kind`` and ``class`` ``"scope_mask"``) and that
id in the segmentation pass, whatever the raster saw behind them; the other passes keep their values there.
"""
from __future__ import annotations

import numpy as np

from postfx.laparoscope_mask import mask_weights

SCOPE_MASK = "scope_mask"  # name, kind and class of the instance


def scope_mask_params(scene):
    """The scene's ``laparoscope_mask`` parameters, or None when its effect chain has no mask."""
    for name, params in scene.effect_chain():
        if name == "laparoscope_mask":
            return params
    return None


def scope_blacked_out(scene, height: int, width: int) -> np.ndarray | None:
    """(H, W) bool: the pixels the scene's mask effect zeroes (weight exactly 0), None without a mask."""
    params = scope_mask_params(scene)
    return None if params is None else mask_weights(int(height), int(width), params) == 0.0


def mark_scope_mask(passes: dict, scene, scope_id: int | None) -> None:
    """Give the blacked-out pixels the scope mask's id ``scope_id`` in ``passes["segmentation"]`` (in place;
    nothing without a segmentation pass or a mask)."""
    ids = passes.get("segmentation")
    if ids is None or scope_id is None:
        return
    out = scope_blacked_out(scene, ids.shape[0], ids.shape[1])
    if out is not None:
        ids = ids.copy()
        ids[out] = scope_id
        passes["segmentation"] = ids
