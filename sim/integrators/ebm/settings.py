"""The parameters of the ``ebm`` integrator, declared once.

``EBMSceneSettings`` is the scene's ``[simulation.ebm]`` table; ``EBMSettings`` adds what the scene sets in
``[simulation]`` (``substeps``, ``iterations``) and what only code and benchmarks choose (kernel, precision).

| name | default | unit | range | equation |
|---|---|---|---|---|
| ``substeps`` | 1 | – | >= 1 | h = dt / substeps (5.13) |
| ``iterations`` | 100 | – | >= 1 | Jacobi sweeps of 5.7–5.9 / 5.14 per substep |
| ``update`` | "average" | – | "average", "sum" | 5.9: per-node sum divided by the tet count, or the literal sum |
| ``kernel`` | "blocked" | – | "blocked", "numba", "numpy" | ``sim.integrators.ebm.blocked`` / ``.kernels`` / NumPy |
| ``precision`` | "float64" | – | "float64", "float32" | lane loops of the blocked kernel (docs/ebm.md) |
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from sim.settings import Settings

UPDATES = ("average", "sum")
KERNELS = ("blocked", "numba", "numpy")
PRECISIONS = ("float64", "float32")


class EBMSceneSettings(Settings):
    """The scene's ``[simulation.ebm]`` table."""

    update: Literal[UPDATES] = Field(  # type: ignore[valid-type]
        "average", description="a node's increments averaged over its tets, or summed (5.9 literally)")


class EBMSettings(EBMSceneSettings):
    """Every parameter of the ``ebm`` integrator (the table in the module docstring)."""

    substeps: int = Field(1, ge=1, le=1000, description="substeps per step [-]")
    iterations: int = Field(100, ge=1, le=10000, description="energy-balance sweeps per substep [-]")
    kernel: Literal[KERNELS] = Field("blocked", description="blocked, scalar numba or NumPy sweeps")  # type: ignore[valid-type]
    precision: Literal[PRECISIONS] = Field(  # type: ignore[valid-type]
        "float64", description="precision of the blocked kernel's lane loops")

    @field_validator("precision", mode="before")
    @classmethod
    def _precision(cls, value):
        if value not in PRECISIONS:
            raise ValueError(f"ebm: precision must be one of {', '.join(PRECISIONS)}, found {value!r}")
        return value
