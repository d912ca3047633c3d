"""The parameters of the ``xpbd`` integrator, declared once.

``XPBDSceneSettings`` is the scene's ``[simulation.xpbd]`` table; ``XPBDSettings`` adds what the scene sets in
``[simulation]`` (``substeps``, ``iterations``) and what only code and benchmarks choose (kernels, domains).

| name | default | unit | range | equation |
|---|---|---|---|---|
| ``substeps`` | 10 | – | >= 1 | Qian 4.36 (h = dt / substeps) |
| ``iterations`` | 10 | – | >= 1 | Qian 4.42–4.44 sweeps per substep |
| ``solver`` | "gauss_seidel" | – | "gauss_seidel", "jacobi" | Qian 4.42–4.44 |
| ``material`` | "stable_neo_hookean" | – | "stable_neo_hookean", "model" | Macklin & Müller 2021; C = sqrt(2 V Psi) |
| ``coupled`` | true | – | bool | 2x2 solve of both tet constraints |
| ``coupling`` | none (from ``coupled``) | – | "coupled", "sequential" | overrides ``coupled`` |
| ``damping`` | 0 | 1/s | [0, 1e3] | v *= exp(-damping h) |
| ``relaxation`` | 1 | – | (0, 2] | Jacobi step scale |
| ``strain_min`` / ``strain_max`` | none | – | (0, 1] / [1, 100] | Qian 4.21 on stretches |Fa| |
| ``limit_frame`` | "rest" | – | "rest", "fibre" | Qian 4.21–4.22 (``sim.integrators.xpbd.strain``) |
| ``limit_axes`` | [1, 2, 3] | – | frame axes | Green-strain stretch bounds |
| ``green_stretch_min`` / ``green_stretch_max`` | none | – | (-0.5, 0] / [0, 1e3] | E'_ii bounds |
| ``shear_max`` | none | – | [0, 1e3] | abs(E'_ij) bound, i != j |
| ``strain_hold`` | {} | – | entries 11..23, value > -0.5 on the diagonal | E'_ij held |
| ``limit_compliance`` | 0 | 1/Pa | [0, 1] | alpha = limit_compliance / V |
| ``kernel`` | "blocked" | – | "blocked", "scalar" | Gauss–Seidel kernel |
| ``energy_kernel`` | none (numba where available) | – | "numba", "numpy" | ``material = "model"`` |
| ``domains`` | 2 | – | >= 1 | slabs swept concurrently; fixes the sweep order, whatever the threads |
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from sim.settings import Settings

ENTRIES = {"11": (0, 0), "22": (1, 1), "33": (2, 2), "12": (0, 1), "13": (0, 2), "23": (1, 2)}
SOLVERS = ("gauss_seidel", "jacobi")
MATERIALS = ("stable_neo_hookean", "model")
COUPLINGS = ("coupled", "sequential")
FRAMES = ("rest", "fibre")
KERNELS = ("blocked", "scalar")
ENERGY_KERNELS = ("numba", "numpy")


class XPBDSceneSettings(Settings):
    """The scene's ``[simulation.xpbd]`` table."""

    solver: Literal[SOLVERS] = Field("gauss_seidel", description="coloured Gauss–Seidel or Jacobi sweeps")  # type: ignore[valid-type]
    material: Literal[MATERIALS] = Field(  # type: ignore[valid-type]
        "stable_neo_hookean", description="the two Macklin–Müller constraints, or the model's own energy")
    coupled: bool = Field(True, description="solve a tet's two constraints together (2x2) or in turn")
    damping: float = Field(0.0, ge=0.0, le=1e3, description="velocity decay rate [1/s]")
    relaxation: float = Field(1.0, gt=0.0, le=2.0, description="Jacobi relaxation [-]")
    strain_min: float | None = Field(None, gt=0.0, le=1.0, description="lowest stretch |F a| along rest axes and fibre [-]")
    strain_max: float | None = Field(None, ge=1.0, le=100.0, description="highest stretch |F a| [-]")
    limit_frame: Literal[FRAMES] = Field("rest", description="frame of the Green-strain limits")  # type: ignore[valid-type]
    limit_axes: Annotated[list[Literal[1, 2, 3]], Field(min_length=1, max_length=3)] = Field(
        [1, 2, 3], description="frame axes whose Green stretch is bounded")
    green_stretch_min: float | None = Field(None, gt=-0.5, le=0.0, description="lower bound on E'_ii [-]")
    green_stretch_max: float | None = Field(None, ge=0.0, le=1e3, description="upper bound on E'_ii [-]")
    shear_max: float | None = Field(None, ge=0.0, le=1e3, description="bound on |E'_ij|, i != j [-]")
    strain_hold: dict[Literal["11", "22", "33", "12", "13", "23"], Annotated[float, Field(gt=-0.5, le=1e3)]] = Field(
        {}, description="Green-strain entries held at a value [-]")
    limit_compliance: float = Field(0.0, ge=0.0, le=1.0, description="compliance of the strain limits [1/Pa]")

    @model_validator(mode="after")
    def _limits(self):
        limit_boxes(self)
        return self


class XPBDSettings(XPBDSceneSettings):
    """Every parameter of the ``xpbd`` integrator (the table in the module docstring)."""

    substeps: int = Field(10, ge=1, le=1000, description="substeps per step [-]")
    iterations: int = Field(10, ge=1, le=10000, description="constraint sweeps per substep [-]")
    coupling: Literal[COUPLINGS] | None = Field(None, description="overrides coupled")  # type: ignore[valid-type]
    kernel: Literal[KERNELS] = Field("blocked", description="Gauss–Seidel kernel")  # type: ignore[valid-type]
    energy_kernel: Literal[ENERGY_KERNELS] | None = Field(  # type: ignore[valid-type]
        None, description="kernel of material = 'model'; none: numba where the material has one")
    # a constant, not the thread count: the sweep order, hence the positions, depends on it (docs/xpbd.md, domains)
    domains: int = Field(2, ge=1, description="slabs swept concurrently [-]")


def limit_boxes(settings: XPBDSceneSettings | Mapping):
    """``(entry_i, entry_j, lo, hi)`` arrays of the limited Green-strain entries, or ``None`` when no
    Green-strain limit is asked for. ``settings``: the xpbd settings, or a mapping of their keys (checked
    here, not by the model)."""
    s = XPBDSceneSettings.model_construct(**settings) if isinstance(settings, Mapping) else settings
    gmin, gmax, shear, hold, axes = (s.green_stretch_min, s.green_stretch_max, s.shear_max, dict(s.strain_hold),
                                     s.limit_axes)
    if gmin is None and gmax is None and shear is None and not hold:
        return None
    if any(int(a) not in (1, 2, 3) for a in axes):
        raise ValueError(f"xpbd limit_axes must be frame axes 1, 2 or 3, found {list(axes)}")
    if gmin is not None and not -0.5 < float(gmin) <= 0.0:
        raise ValueError(f"xpbd green_stretch_min must lie in (-0.5, 0] (E_ii >= -1/2 always), found {gmin}")
    if gmax is not None and not float(gmax) >= 0.0:
        raise ValueError(f"xpbd green_stretch_max must be >= 0, found {gmax}")
    if shear is not None and not float(shear) >= 0.0:
        raise ValueError(f"xpbd shear_max must be >= 0, found {shear}")
    boxes = {}
    if gmin is not None or gmax is not None:
        for a in sorted({int(a) for a in axes}):
            boxes[f"{a}{a}"] = (-np.inf if gmin is None else float(gmin), np.inf if gmax is None else float(gmax))
    if shear is not None:
        for key in ("12", "13", "23"):
            boxes[key] = (-float(shear), float(shear))
    for key, value in hold.items():
        key = str(key)
        if key not in ENTRIES:
            raise ValueError(f"xpbd strain_hold entries are {', '.join(ENTRIES)}, found {key!r}")
        if key in boxes:
            raise ValueError(f"xpbd strain_hold[{key!r}] conflicts with a bound on the same entry")
        value = float(value)
        if key[0] == key[1] and not value > -0.5:
            raise ValueError(f"xpbd strain_hold[{key!r}] = {value}: a stretch entry must be > -0.5")
        boxes[key] = (value, value)
    keys = sorted(boxes, key=list(ENTRIES).index)
    ij = np.array([ENTRIES[k] for k in keys], dtype=np.int64)
    lo = np.array([boxes[k][0] for k in keys])
    hi = np.array([boxes[k][1] for k in keys])
    return ij[:, 0].copy(), ij[:, 1].copy(), lo, hi
