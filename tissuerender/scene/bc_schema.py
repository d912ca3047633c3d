"""Boundary conditions per component in the scene format (issue 21 item 1): a ``fixed`` or ``prescribed`` region
may hold its nodes in some components only.

- ``components = ["z"]``: only z is held (fixed at rest, or moved by the prescribed displacement's z); x and y are
  free: a roller (a face that slides sideways), ``["x", "y"]`` a node free to move along z only;
- ``normal = [nx, ny, nz]``: held along that direction only (need not be an axis): a sliding face or symmetry plane
  whose plane is normal to it; a prescribed displacement moves the nodes by its component along the normal.

Without either key every component is held, as before. The model's form: ``sim.model.PrescribedDisplacement.held``
(``sim.model.PartialTargets``), honoured by every integrator.
"""
from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, Field, model_validator

AXIS_NAMES = ("x", "y", "z")
Normal = Annotated[list[float], Field(min_length=3, max_length=3)]


class HeldComponents(BaseModel):
    """The keys a ``fixed`` or ``prescribed`` region gains: which of its nodes' components are held."""

    components: Annotated[list[Literal[AXIS_NAMES]], Field(min_length=1, max_length=3)] | None = Field(  # type: ignore[valid-type]
        None, description=("hold only these components (\"x\", \"y\", \"z\"), the others free: [\"z\"] is a roller "
                           "that slides in x and y; default: all (a clamp)"))
    normal: Normal | None = Field(None, description=(
        "hold only the component along this direction (need not be an axis): a sliding face or symmetry plane "
        "normal to it; not with components"))

    @model_validator(mode="after")
    def _one_way(self):
        if self.components is not None and self.normal is not None:
            raise ValueError("give either 'components' or 'normal', not both")
        if self.components is not None and len(set(self.components)) != len(self.components):
            raise ValueError(f"'components' lists a component twice: {self.components}")
        if self.normal is not None and sum(a * a for a in self.normal) < 1e-12:
            raise ValueError(f"'normal' must be a non-zero vector, found {self.normal}")
        return self

    def held_directions(self) -> np.ndarray | None:
        """``None`` (every component held) or the held directions (d, 3) for ``PrescribedDisplacement.held``."""
        if self.normal is not None:
            n = np.asarray(self.normal, dtype=np.float64)
            return (n / np.linalg.norm(n))[None, :]
        if self.components is not None and len(self.components) < 3:
            return np.eye(3)[[AXIS_NAMES.index(c) for c in self.components]]
        return None
