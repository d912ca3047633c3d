"""The base of every integrator's settings model.

Each integrator declares its parameters once, in one pydantic model (name, default, unit in the Field
description, range by ge/le/gt/lt); the scene schema composes the scene-visible part of these models
(``tissuerender.scene.schema``) and the integrator reads the validated model, never a dict with a second
default. The config matches the scene file's: unknown keys are errors (a typo must never silently switch
a setting off), numbers must be finite, types are strict (``"70"`` is not a number).
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Settings(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)

    @classmethod
    def of(cls, settings=None):
        """``settings`` when it already is this model; else the mapping (or another settings model's values)
        validated into it. ``None`` gives the defaults."""
        if isinstance(settings, cls):
            return settings
        if isinstance(settings, BaseModel):
            settings = settings.model_dump()
        return cls.model_validate(dict(settings or {}))
