"""Material presets: each pairs the mechanics of a tissue (``materials.mechanics``) with its optics
(``materials.optics``: the multi-layer mucosa stack or the plain ``plastic`` reference).

>>> get_preset("liver").mechanics.E
4600.0
"""
from __future__ import annotations

from dataclasses import dataclass

from materials.mechanics import MECHANICS, Mechanics
from materials.optics import OPTICS, OpticalMaterial

PRESET_NAMES: tuple[str, ...] = tuple(MECHANICS)


@dataclass(frozen=True)
class MaterialPreset:
    name: str
    mechanics: Mechanics

    @property
    def optics(self) -> OpticalMaterial:
        """The optical description (``materials.optics``)."""
        return OPTICS[self.name]


def get_preset(name: str) -> MaterialPreset:
    """The preset called ``name``; ``KeyError`` naming the known presets otherwise."""
    if name not in MECHANICS:
        raise KeyError(f"unknown material preset {name!r}; expected one of {', '.join(PRESET_NAMES)}")
    return MaterialPreset(name=name, mechanics=MECHANICS[name])
