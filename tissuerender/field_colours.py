"""The field a body's ``[objects.field_colours]`` draws (``tissuerender.scene.field_schema``), per render-surface
vertex, as the vertex albedo of ``tissuerender.renderer.fieldmap``; and the colour bars the manifest records.

Fields (units in ``field_schema.FIELDS``):

- ``displacement``: ``|x - X|`` [m] of each render-surface vertex (embedded in the tets, so moved as they are);
  ``displacement_x`` / ``_y`` / ``_z``: one signed component of ``x - X`` [m].
- ``von_mises``: the von Mises equivalent of the Cauchy stress [Pa], ``sqrt(3/2 s:s)`` with ``s`` the deviator of
  ``sigma = P F^T / J`` (Bonet & Wood, Nonlinear Continuum Mechanics, eq. 5.33): ``F = Ds Dm^-1`` of every tet and
  ``P`` the first Piola stress of the body's constitutive model (``sim.constitutive.models.first_piola``: the
  elastic stress; a Prony series' viscous part, which lives in the integrator's state, is not included). The
  tensors are averaged onto the tet-mesh nodes weighted by each tet's rest volume, then interpolated to the
  render-surface vertices with their embedding's barycentric weights, and the von Mises value taken last (of the
  averaged tensor: a uniform stress gives its own value at every vertex).
"""
from __future__ import annotations

import numpy as np

from sim.constitutive.models import first_piola, model_curves, model_params
from sim.constitutive.tensor import deformation_gradients, det
from tissuerender.renderer.fieldmap import colormap_albedo

SIGNED = {"displacement_x": 0, "displacement_y": 1, "displacement_z": 2}  # signed fields: component of x - X


def cauchy_stress(model, x: np.ndarray) -> np.ndarray:
    """Cauchy stress ``sigma = P F^T / J`` (m, 3, 3) [Pa] of every tet of ``model`` at node positions ``x``."""
    F = deformation_gradients(x, model.tets, model.Dm_inv)
    name, mu, lam, eta, a0 = model_params(model)
    P = first_piola(name, F, mu, lam, eta, a0, vl=model_curves(model))
    return P @ np.transpose(F, (0, 2, 1)) / det(F)[:, None, None]


def nodal_average(model, per_tet: np.ndarray) -> np.ndarray:
    """Per-tet values (m, ...) averaged onto the nodes (n, ...), each tet weighted by its rest volume."""
    flat = per_tet.reshape(per_tet.shape[0], -1)
    weights = np.repeat(model.volume, 4)
    nodes = model.tets.ravel()
    n = model.X.shape[0]
    total = np.bincount(nodes, weights=weights, minlength=n)
    out = np.stack([np.bincount(nodes, weights=weights * np.repeat(flat[:, c], 4), minlength=n)
                    for c in range(flat.shape[1])], axis=1)
    return (out / np.maximum(total, np.finfo(float).tiny)[:, None]).reshape((n,) + per_tet.shape[1:])


def von_mises(sigma: np.ndarray) -> np.ndarray:
    """``sqrt(3/2 s:s)`` (k,) of Cauchy stresses (k, 3, 3), ``s = sigma - tr(sigma) / 3 I``."""
    s = sigma - np.einsum("kii->k", sigma)[:, None, None] / 3.0 * np.eye(3)
    return np.sqrt(1.5 * np.einsum("kij,kij->k", s, s))


def surface_von_mises(body, x: np.ndarray) -> np.ndarray:
    """The von Mises stress (p,) [Pa] at the body's render-surface vertices for node positions ``x``."""
    nodal = nodal_average(body.model, cauchy_stress(body.model, x))
    emb = body.embedding
    at_vertex = np.einsum("pk,pkij->pij", emb.bary, nodal[body.mesh.tets[emb.tet_index]])
    return von_mises(at_vertex)


def vertex_field(spec, body, x: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The field's value (p,) at each render-surface vertex of ``body`` (at its positions ``points``, the nodes at
    ``x``)."""
    if spec.field == "displacement":
        return np.linalg.norm(points - body.surface.points, axis=1)
    if spec.field in SIGNED:
        return points[:, SIGNED[spec.field]] - body.surface.points[:, SIGNED[spec.field]]
    if spec.field == "von_mises":
        return surface_von_mises(body, x)
    raise ValueError(f"unknown field {spec.field!r}")  # the schema admits no other


def frame_range(values: np.ndarray) -> tuple[float, float]:
    """The colour bar of a frame without ``range``: from ``min(0, smallest)`` to ``max(0, largest)`` (0 to the
    maximum for the non-negative fields); ``(0, 1)`` when every value is 0 (a body at rest)."""
    low = min(0.0, float(values.min())) if values.size else 0.0
    high = max(0.0, float(values.max())) if values.size else 0.0
    return (0.0, 1.0) if high <= low else (low, high)


def vertex_albedo(spec, body, x: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Linear-RGB albedo (p, 3) of the field through the colormap over ``spec.range`` (default
    :func:`frame_range`; a body at rest, all zero, is drawn at the colormap's low end)."""
    values = vertex_field(spec, body, x, points)
    low, high = spec.range if spec.range is not None else frame_range(values)
    return colormap_albedo(values, low, high, spec.colormap)


def legends(scene) -> dict:
    """``{"field_colours": {object name: colour bar}}`` for the bodies with a field colour map, else ``{}``."""
    bars = {o.name: o.field_colours.legend() for o in scene.objects if o.field_colours is not None}
    return {"field_colours": bars} if bars else {}
