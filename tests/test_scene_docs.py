"""docs/scene-format.md and the schema agree in both directions, defaults and ranges included: the key tables
of the document are the ones generated from the schema (``tissuerender.scene.doc_tables``), whole."""
from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from tissuerender.scene import doc_tables, schema
from tissuerender.scene.load import SceneFile

DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "scene-format.md"
DOC = DOC_PATH.read_text()


def _models(model: type[BaseModel], seen: set) -> set:
    """Every pydantic model a scene file reaches from ``model`` (field types, through lists, unions, Annotated)."""
    def walk(annotation):
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            if annotation not in seen:
                seen.add(annotation)
                for field in annotation.model_fields.values():
                    walk(field.annotation)
        for arg in getattr(annotation, "__args__", ()):
            walk(arg)

    walk(model)
    return seen


def test_the_key_tables_are_the_generated_ones():
    problems = doc_tables.problems(DOC)
    assert not problems, "\n".join(problems)


def test_every_table_a_scene_can_hold_has_a_section():
    reached = _models(SceneFile, set()) | _models(schema.Effects, set())
    covered = {s.model for s in doc_tables.SECTIONS} | {s.base for s in doc_tables.SECTIONS if s.base}
    assert reached - covered == set()
    assert len(reached) >= 30  # 13 scene tables, 6 integrator tables, 10 post-effects, the file itself


def test_every_key_of_the_scene_and_integrator_tables_has_a_description():
    # The post-effects' own parameters are documented in docs/postfx.md.
    missing = [f"{s.name}.{k}" for s in doc_tables.SECTIONS if not s.name.startswith("effects.")
               for k, f in s.fields().items() if not f.description]
    assert not missing, f"fields without Field(description=...): {missing}"


def _replace_once(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def test_a_doc_that_disagrees_with_the_schema_is_caught_by_name():
    row = next(line for line in DOC.splitlines() if line.startswith("| `fov_deg` |"))
    assert row == "| `fov_deg` | float | 70 | 1 < x < 179 | horizontal field of view [deg] |"
    undocumented = _replace_once(DOC, row + "\n", "")
    assert "camera.fov_deg: a key of the schema, not documented" in doc_tables.problems(undocumented)
    unknown = _replace_once(DOC, row, row + "\n| `fov_vertical` | float | 50 | — | not a key |")
    assert "camera.fov_vertical: documented, but not a key of the schema" in doc_tables.problems(unknown)
    for wrong in (row.replace("| 70 |", "| 60 |"), row.replace("1 < x < 179", "0 < x < 180")):
        found = doc_tables.problems(_replace_once(DOC, row, wrong))
        assert len(found) == 1 and found[0].startswith("keys:camera: stale") and repr(wrong) in found[0]
    gone = _replace_once(DOC, "<!-- BEGIN keys:light.importance -->", "")
    assert any(p.startswith("keys:light.importance: no region") for p in doc_tables.problems(gone))


def test_write_regenerates_the_tables_and_keeps_the_prose(tmp_path):
    row = next(line for line in DOC.splitlines() if line.startswith("| `fov_deg` |"))
    stale = _replace_once(DOC, row + "\n", "")
    stale = _replace_once(stale, "Tools push tissue (contact)", "Tools push tissue (contact, edited prose)")
    path = tmp_path / "scene-format.md"
    path.write_text(stale)
    assert doc_tables.main([str(path), "--check"]) == 1
    assert doc_tables.main([str(path), "--write"]) == 0
    assert path.read_text() == DOC.replace("Tools push tissue (contact)", "Tools push tissue (contact, edited prose)")


def test_every_section_has_a_heading():
    for section in ("scene", "objects", "simulation", "tools", "camera", "light", "effects", "output"):
        assert f"`[{section}]`" in DOC or f"`[[{section}]]`" in DOC
