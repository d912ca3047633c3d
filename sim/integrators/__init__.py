"""The integrator interface and the registry the scene's ``simulation.integrator`` selects from.

Every integrator is a small class holding its parameters::

    integrator = make_integrator("xpbd", model, settings)
    state = integrator.step(state, dt)     # advances state.t by dt

``settings`` is the integrator's settings model (``settings_model(name)``) or a mapping of its keys: the
scene's ``[simulation.<name>]`` table plus ``substeps`` and ``iterations``. Each integrator declares its
parameters once, in that model; the scene schema composes their scene-visible part
(``scene_settings_model(name)``) and the plan asks :func:`supports` which features (``"prony"``,
``"fibres"``) an integrator evaluates. An integrator that detects a failure (non-finite positions, runaway
energy) raises :class:`sim.errors.SimulationDiverged`; the pipeline reports it and never writes NaN frames.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from sim.constitutive import models
from sim.integrators.chainmail import ChainMailSceneSettings, ChainMailSettings
from sim.integrators.cnn.settings import CNNSceneSettings, CNNSettings
from sim.integrators.ebm.settings import EBMSceneSettings, EBMSettings
from sim.integrators.explicit import ExplicitSceneSettings, ExplicitSettings
from sim.integrators.reference import ReferenceSceneSettings, ReferenceSettings
from sim.integrators.xpbd.settings import XPBDSceneSettings, XPBDSettings
from sim.model import Model, State
from sim.settings import Settings

FEATURES = ("prony", "fibres")


class Integrator(Protocol):
    name: str

    def step(self, state: State, dt: float) -> State: ...


def _always(settings: Settings) -> bool:
    return True


@dataclass(frozen=True)
class Entry:
    """One integrator: its class (``"module:Class"``, imported on first use: the xpbd, ebm and cnn solvers and
    their kernels load only when used), its settings model, the scene table's part of it, and the features it evaluates, each
    with a test on the settings (Prony series: ``"prony"``; fibre terms of anisotropic materials: ``"fibres"``)."""

    target: str
    settings: type[Settings]
    scene_settings: type[Settings]
    features: Mapping[str, Callable[[Settings], bool]] = field(default_factory=dict)


REGISTRY: dict[str, Entry] = {
    "xpbd": Entry("sim.integrators.xpbd.solver:XPBD", XPBDSettings, XPBDSceneSettings,
                  # Prony: Maxwell branches (sim.integrators.xpbd.prony); fibres only with the model's own energy
                  {"prony": _always, "fibres": lambda s: s.material == "model"}),
    "ebm": Entry("sim.integrators.ebm.solver:EBM", EBMSettings, EBMSceneSettings,
                 {"prony": _always, "fibres": _always}),
    "cnn": Entry("sim.integrators.cnn.solver:CNN", CNNSettings, CNNSceneSettings, {"fibres": _always}),
    "cnn_chainmail": Entry("sim.integrators.chainmail:CNNChainMail", ChainMailSettings, ChainMailSceneSettings),
    "explicit": Entry("sim.integrators.explicit:ExplicitEuler", ExplicitSettings, ExplicitSceneSettings,
                      {"fibres": _always}),
    "reference": Entry("sim.integrators.reference:ReferenceIntegrator", ReferenceSettings, ReferenceSceneSettings,
                       {"prony": _always, "fibres": _always}),
}


def _entry(name: str) -> Entry:
    if name not in REGISTRY:
        raise KeyError(f"unknown integrator {name!r}; expected one of {sorted(REGISTRY)}")
    return REGISTRY[name]


def settings_model(name: str) -> type[Settings]:
    """Every parameter of integrator ``name`` (what :func:`make_integrator` validates into)."""
    return _entry(name).settings


def scene_settings_model(name: str) -> type[Settings]:
    """The scene's ``[simulation.<name>]`` table of integrator ``name``."""
    return _entry(name).scene_settings


def supports(name: str, feature: str, settings: Settings | Mapping | None = None) -> bool:
    """Whether integrator ``name`` (with ``settings``; default: its defaults) evaluates ``feature``
    (one of ``FEATURES``). Unknown names (``"none"``) support nothing."""
    if feature not in FEATURES:
        raise KeyError(f"unknown integrator feature {feature!r}; expected one of {', '.join(FEATURES)}")
    entry = REGISTRY.get(name)
    if entry is None or feature not in entry.features:
        return False
    return entry.features[feature](entry.settings.of(settings))


def supported_by(feature: str) -> list[str]:
    """The integrators that evaluate ``feature`` with their default settings, sorted by name."""
    return sorted(name for name in REGISTRY if supports(name, feature))


def make_integrator(name: str, model: Model, settings: Settings | Mapping | None = None) -> Integrator:
    """Integrator ``name`` for ``model``; ``settings``: its settings model or a mapping of its keys (validated)."""
    entry = _entry(name)
    settings = entry.settings.of(settings)
    if model.constitutive == "stable_neo_hookean" and name != "cnn_chainmail":  # the ChainMail has no energy
        models.require_stable_rest(model, f"{name}: the stable Neo-Hookean energy")
    module_name, class_name = entry.target.split(":")
    cls = getattr(importlib.import_module(module_name), class_name)
    return cls(model, settings)
