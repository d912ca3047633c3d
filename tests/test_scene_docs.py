"""docs/scene-format.md documents every key the schema accepts."""
from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from tissuerender.scene import schema
from tissuerender.scene.load import SceneFile

DOC = (Path(__file__).resolve().parents[1] / "docs" / "scene-format.md").read_text()


def _keys(model: type[BaseModel], seen=None):
    seen = set() if seen is None else seen
    for name, field in model.model_fields.items():
        yield model.__name__, name
        for arg in getattr(field.annotation, "__args__", ()) + (field.annotation,):
            inner = getattr(arg, "__args__", (arg,))
            for cand in inner + (arg,):
                if isinstance(cand, type) and issubclass(cand, BaseModel) and cand not in seen:
                    seen.add(cand)
                    yield from _keys(cand, seen)


def test_every_schema_key_is_documented():
    missing = sorted({f"{m}.{k}" for m, k in _keys(SceneFile) if f"`{k}`" not in DOC})
    missing += sorted({f"EffectsBase.{k}" for k in schema.EffectsBase.model_fields if f"`{k}`" not in DOC})
    assert not missing, f"undocumented scene keys: {missing}"


def test_every_section_has_a_heading():
    for section in ("scene", "objects", "simulation", "tools", "camera", "light", "effects", "output"):
        assert f"`[{section}]`" in DOC or f"`[[{section}]]`" in DOC
