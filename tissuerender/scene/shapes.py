"""Procedural body shapes: their names, default sizes, and the bounding box and cell size a scene gives them.

Validation needs a procedural body's extent and cell size (to refuse tet counts that would make a render
hang) before any mesh is built, and ``tissuerender.bodies`` builds the mesh from the same figures, so they
live here, with the scene description, rather than with the mesh builders.
"""
from __future__ import annotations

import math

# Bounding-box size [m] of each box-like procedural shape when the scene gives none.
DEFAULT_SIZE = {
    "box": (1.0, 1.0, 1.0),
    "beam": (2.0, 0.2, 0.2),
    "cube": (2.0, 2.0, 2.0),
    "cylinder": (1.0, 1.0, 2.0),  # diameter, diameter, length (axis z)
    "slab": (0.2, 0.2, 0.03),
}
# Default ``scale`` [m] of each organ shape; organ SDFs fit inside a box of about ORGAN_EXTENT * scale per side.
DEFAULT_SCALE = {"liver": 0.15, "kidney": 0.11, "gallbladder": 0.05}
ORGAN_EXTENT = 2.2
ORGAN_SHAPES = tuple(DEFAULT_SCALE)
SHAPES = tuple(DEFAULT_SIZE) + ORGAN_SHAPES


def procedural_extent(obj) -> tuple[tuple[float, float, float], float]:
    """Bounding-box extent [m] and cell size [m] of a procedural body (a ``schema.ObjectSpec`` with a shape)."""
    if obj.shape in DEFAULT_SCALE:
        if obj.size is not None:
            raise ValueError(f"shape {obj.shape!r} takes 'scale', not 'size'")
        scale = obj.scale if obj.scale is not None else DEFAULT_SCALE[obj.shape]
        extent = (ORGAN_EXTENT * scale,) * 3
        h = obj.cell_size if obj.cell_size is not None else scale / 6.0
        return extent, h
    if obj.scale is not None:
        raise ValueError(f"shape {obj.shape!r} takes 'size', not 'scale'")
    extent = tuple(obj.size) if obj.size is not None else DEFAULT_SIZE[obj.shape]
    if any(e <= 0.0 for e in extent):
        raise ValueError(f"size must be positive, found {list(extent)}")
    if obj.shape == "cube" and not (extent[0] == extent[1] == extent[2]):
        raise ValueError(f"a cube needs equal sides, found size {list(extent)}")
    if obj.shape == "cylinder" and extent[0] != extent[1]:
        raise ValueError(f"a cylinder's size is [diameter, diameter, length], found {list(extent)}")
    h = obj.cell_size if obj.cell_size is not None else min(extent) / 4.0
    return extent, h


def organ_render_pitch(obj) -> float:
    """Grid spacing [m] at which an organ shape's render surface is contoured: ``cell_size / 2**levels``
    (``levels = max(1, render_subdivision)``, finer than the tets), at most ``scale / 64`` and at least
    ``scale / 160`` (the liver's contour grid then has 6.8e6 samples, under sim.mesh.contour.MAX_SAMPLES).
    The cap keeps the angle between neighbouring faces below 10 degrees at the 99th percentile: that angle is about edge
    length / curvature radius, and the organs' tightest radii (the kidney's poles and hilum, the liver's thin
    edge) are about 0.1 scale, so edges of scale / 64 turn by about 9 degrees there (tests/test_mesh_smooth.py)."""
    scale = obj.scale if obj.scale is not None else DEFAULT_SCALE[obj.shape]
    h = obj.cell_size if obj.cell_size is not None else scale / 6.0
    return max(min(h / 2.0 ** max(1, obj.render_subdivision), scale / 64.0), scale / 160.0)


def estimated_tets(obj) -> int:
    """Upper estimate of a procedural body's tet count (6 tets per grid cell of its bounding box)."""
    extent, h = procedural_extent(obj)
    cells = 1.0
    for e in extent:
        cells *= max(1.0, math.ceil(e / h))
    return int(min(6.0 * cells, 1e18))
