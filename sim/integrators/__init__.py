"""The integrator interface and the registry the scene's ``simulation.integrator`` selects from.

Every integrator is a small class holding its parameters::

    integrator = make_integrator("xpbd", model, settings)
    state = integrator.step(state, dt)     # advances state.t by dt

``settings`` is a plain dict of the integrator-specific keys of the scene's
``[simulation.<name>]`` table plus ``substeps`` and ``iterations``. An integrator that detects a
failure (non-finite positions, runaway energy) raises :class:`sim.errors.SimulationDiverged`; the pipeline
reports it and never writes NaN frames.
"""
from __future__ import annotations

import importlib
from typing import Protocol

from sim.model import Model, State


class Integrator(Protocol):
    name: str

    def step(self, state: State, dt: float) -> State: ...


# name -> "module:Class"; modules are imported lazily so an unused integrator is never compiled.
REGISTRY: dict[str, str] = {
    "xpbd": "sim.integrators.xpbd.solver:XPBD",
    "reference": "sim.integrators.reference:ReferenceIntegrator",
    "ebm": "sim.integrators.ebm.solver:EBM",
    "cnn": "sim.integrators.cnn.solver:CNN",
    "cnn_chainmail": "sim.integrators.chainmail:CNNChainMail",
    "explicit": "sim.integrators.explicit:ExplicitEuler",
}


def make_integrator(name: str, model: Model, settings: dict | None = None) -> Integrator:
    if name not in REGISTRY:
        raise KeyError(f"unknown integrator {name!r}; expected one of {sorted(REGISTRY)}")
    module_name, class_name = REGISTRY[name].split(":")
    module = importlib.import_module(module_name)
    cls = getattr(module, class_name)
    return cls(model, dict(settings or {}))
