"""The field a body's ``[objects.field_colours]`` draws (``tissuerender.scene.field_schema``), per render-surface
vertex, as the vertex albedo of ``tissuerender.renderer.fieldmap``; and the colour bars the manifest records."""
from __future__ import annotations

import numpy as np

from tissuerender.renderer.fieldmap import colormap_albedo


def vertex_field(spec, rest_points: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The field's value (n,) at each render-surface vertex: ``displacement`` = ``|x - X|`` [m], the distance of
    the vertex (embedded in the tets, so moved as they are) from its rest position."""
    if spec.field == "displacement":
        return np.linalg.norm(points - rest_points, axis=1)
    raise ValueError(f"unknown field {spec.field!r}")  # the schema admits no other


def vertex_albedo(spec, rest_points: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Linear-RGB albedo (n, 3) of the field through the colormap over ``spec.range`` (default 0 to the
    frame's largest value; a body at rest, all zero, is drawn at the colormap's low end)."""
    values = vertex_field(spec, rest_points, points)
    if spec.range is not None:
        low, high = spec.range
    else:
        low, high = 0.0, float(values.max()) if values.size and values.max() > 0.0 else 1.0
    return colormap_albedo(values, low, high, spec.colormap)


def legends(scene) -> dict:
    """``{"field_colours": {object name: colour bar}}`` for the bodies with a field colour map, else ``{}``."""
    bars = {o.name: o.field_colours.legend() for o in scene.objects if o.field_colours is not None}
    return {"field_colours": bars} if bars else {}
