"""The parameters of the ``cnn`` integrator, declared once.

``CNNSceneSettings`` is the scene's ``[simulation.cnn]`` table (the force model's keys come from
``sim.forces.ForceSettings``); ``CNNSettings`` adds what the scene sets in ``[simulation]`` (``substeps``;
``iterations`` is accepted and ignored: the CNN has no inner iterations) and the kernel choice.

| name | default | unit | range | equation |
|---|---|---|---|---|
| ``substeps`` | 1 | – | >= 1 | h = dt / substeps |
| ``iterations`` | 1 | – | >= 1 | ignored |
| ``K`` | 4 | m/s | (0, 1e4] | Zhang 4.33 saturation bound |
| ``saturation`` | "state" | – | "state", "output" | 4.32–4.33 by forward Euler |
| ``force_model`` | "constitutive" | – | "constitutive", "linear_fem", "energy" | 4.31; 4.4–4.30 with "energy" |
| ``energy_rho`` | 1 | m^2/s | (0, 1e6] | 4.7 diffusion coefficient |
| ``energy_gradient`` | "median_dual" | – | "median_dual", "edge" | 4.8 / 4.21 |
| ``rayleigh_alpha`` | 0 | 1/s | [0, 1e3] | D = alpha M + beta K |
| ``rayleigh_beta`` | 0 | s | [0, 1] | D = alpha M + beta K |
| ``kernel`` | "numba" | – | "numba", "numpy" | forces and energy propagation |
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from sim.forces import ForceKernel, ForceSettings

SATURATIONS = ("state", "output")
FORCE_MODELS = ("constitutive", "linear_fem", "energy")
GRADIENTS = ("median_dual", "edge")


class CNNSceneSettings(ForceSettings):
    """The scene's ``[simulation.cnn]`` table."""

    K: float = Field(4.0, gt=0.0, le=1e4, description="saturation bound of a cell's speed [m/s] (Zhang 4.33)")
    saturation: Literal[SATURATIONS] = Field(  # type: ignore[valid-type]
        "state", description="clamp the cell state, or only the output's speed")
    force_model: Literal[FORCE_MODELS] = Field(  # type: ignore[valid-type]
        "constitutive", description="the model's material, linear FEM, or CNN energy propagation of the contact load")
    energy_rho: float = Field(1.0, gt=0.0, le=1e6, description="diffusion coefficient of the potential [m^2/s]")
    energy_gradient: Literal[GRADIENTS] = Field(  # type: ignore[valid-type]
        "median_dual", description="gradient at the dual faces: tet-linear, or along the edge")


class CNNSettings(CNNSceneSettings, ForceKernel):
    """Every parameter of the ``cnn`` integrator (the table in the module docstring); ``kernel`` applies to the
    forces and to the energy propagation."""

    substeps: int = Field(1, ge=1, le=1000, description="substeps per step [-]")
    iterations: int = Field(1, ge=1, le=10000, description="ignored: the CNN has no inner iterations")
