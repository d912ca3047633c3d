"""The key tables of ``docs/scene-format.md``, generated from the schema (issue 16 item 3).

Each table of the scene file is one pydantic model (``schema``, the integrators' scene settings, the
post-effects' parameters); its documentation table lists every field with its type, default, range and
description (``Field(description=...)``), so the schema is the one place a key is declared. In the document
each table sits between markers, and the prose around them is the author's::

    <!-- BEGIN keys:camera -->
    | key | type | default | range | meaning |
    ...
    <!-- END keys:camera -->

``python -m tissuerender.scene.doc_tables --write docs/scene-format.md`` rewrites the marked regions;
``--check`` lists what differs (``tests/test_scene_docs.py`` runs the same comparison).
"""
from __future__ import annotations

import argparse
import re
import sys
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Union, get_args, get_origin

import annotated_types as at
from pydantic import BaseModel
from pydantic.fields import FieldInfo

import postfx
from sim.integrators import REGISTRY
from tissuerender.files import write_atomic
from tissuerender.scene import schema
from tissuerender.scene.load import SceneFile

HEADER = "| key | type | default | range | meaning |\n|---|---|---|---|---|"
REGION = re.compile(r"<!-- BEGIN keys:(?P<name>[\w.]+) -->\n(?P<body>.*?)<!-- END keys:(?P=name) -->", re.S)


@dataclass(frozen=True)
class Section:
    """One documented table: its marker name, its model, and the base model whose keys it leaves to another
    section (a prescribed region's side/box keys are documented once, with the region)."""

    name: str
    model: type[BaseModel]
    base: type[BaseModel] | None = None

    def fields(self) -> dict[str, FieldInfo]:
        skip = set(self.base.model_fields) if self.base is not None else set()
        return {k: f for k, f in self.model.model_fields.items() if k not in skip}


SECTIONS: tuple[Section, ...] = (
    Section("top", SceneFile),
    Section("scene", schema.SceneInfo),
    Section("objects", schema.ObjectSpec),
    Section("objects.override", schema.MaterialOverride),
    Section("objects.optics", schema.OpticsOverride),
    Section("region", schema.Region),
    Section("objects.fixed", schema.FixedRegion, base=schema.Region),
    Section("objects.prescribed", schema.Prescribed, base=schema.Region),
    Section("objects.tractions", schema.Traction, base=schema.Region),
    Section("objects.paint", schema.PaintStroke),
    Section("objects.floor", schema.FloorSpec),
    Section("objects.field_colours", schema.FieldColours),
    Section("simulation", schema.Simulation),
    *(Section(f"simulation.{name}", entry.scene_settings) for name, entry in REGISTRY.items()),
    Section("tools", schema.Tool),
    Section("tools.keyframes", schema.Keyframe),
    Section("tools.grasp", schema.GraspSpec),
    Section("tools.cut", schema.CutSpec),
    Section("contacts", schema.ContactSpec),
    Section("camera", schema.Camera),
    Section("camera.path", schema.CameraKeyframe),
    Section("camera.lens", schema.CameraLens),
    Section("light", schema.Light),
    Section("light.importance", schema.ImportanceStroke),
    Section("effects", schema.Effects),
    *(Section(f"effects.{name}", model) for name, model in postfx.EFFECTS.items()),
    Section("output", schema.Output),
)


# --- one field -> one row -----------------------------------------------------------------------------------


def _unwrap(annotation) -> tuple[object, list, bool]:
    """(the type inside Annotated/Optional, its constraints, whether None is allowed)."""
    constraints: list = []
    optional = False
    while True:
        origin = get_origin(annotation)
        if origin is Annotated:
            annotation, *meta = get_args(annotation)
            for m in meta:
                constraints += list(m.metadata) if isinstance(m, FieldInfo) else [m]
        elif origin in (Union, types.UnionType):
            args = [a for a in get_args(annotation) if a is not type(None)]
            optional = optional or len(args) < len(get_args(annotation))
            if len(args) != 1:
                return annotation, constraints, optional
            annotation = args[0]
        else:
            return annotation, constraints, optional


def number(value) -> str:
    """A number as the tables print it: integers plainly, other floats in %g (six significant digits)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e6:
        return str(int(value))
    if isinstance(value, float):
        return re.sub(r"e([+-])0*(\d)", lambda m: f"e{'-' if m[1] == '-' else ''}{m[2]}", f"{value:g}")  # 1e+09 -> 1e9
    return str(value)


def _bounds(constraints: list) -> str:
    lo = hi = ""
    for c in constraints:
        if isinstance(c, at.Gt):
            lo = f"{number(c.gt)} <"
        elif isinstance(c, at.Ge):
            lo = f"{number(c.ge)} <="
        elif isinstance(c, at.Lt):
            hi = f"< {number(c.lt)}"
        elif isinstance(c, at.Le):
            hi = f"<= {number(c.le)}"
    return " ".join(p for p in (lo, "x" if lo or hi else "", hi) if p)


def _lengths(constraints: list) -> tuple[int | None, int | None]:
    lo = next((c.min_length for c in constraints if isinstance(c, at.MinLen)), None)
    hi = next((c.max_length for c in constraints if isinstance(c, at.MaxLen)), None)
    return lo, hi


def _literal(value) -> str:
    return f'`"{value}"`' if isinstance(value, str) else f"`{value}`"


def describe(annotation, field_constraints: list = ()) -> tuple[str, str]:
    """(type, range) of an annotation, as the tables print them."""
    inner, constraints, _ = _unwrap(annotation)
    constraints = list(field_constraints) + constraints
    origin = get_origin(inner)
    if origin is Literal:
        return " | ".join(_literal(v) for v in get_args(inner)), ""
    if origin is list:
        element_type, element_range = describe(get_args(inner)[0])
        lo, hi = _lengths(constraints)
        if lo is not None and lo == hi:
            kind = f"[{element_type} × {lo}]"
            size = ""
        else:
            kind = "array of tables" if element_type == "table" else f"list of {element_type}"
            size = (f"{lo} to {hi} entries" if lo and hi is not None else f"at most {hi} entries" if hi is not None
                    else f"at least {lo} entr{'y' if lo == 1 else 'ies'}" if lo else "")
        each = element_range if element_range.startswith("each") else f"each {element_range}"
        parts = [p for p in (size, each if element_range else "") if p]
        return kind, ", ".join(parts)
    if origin is dict:
        key_type, _ = describe(get_args(inner)[0])
        value_type, value_range = describe(get_args(inner)[1])
        return f"table of {key_type} = {value_type}", f"each value {value_range}" if value_range else ""
    if inner is dict or (isinstance(inner, type) and issubclass(inner, BaseModel)):
        return "table", ""
    names = {bool: "bool", int: "integer", float: "float", str: "string"}
    kind = names.get(inner, getattr(inner, "__name__", str(inner)))
    if inner is str:
        lo, hi = _lengths(constraints)
        return kind, f"{lo} to {hi} characters" if lo is not None and hi is not None else ""
    return kind, _bounds(constraints)


def _value(value) -> str:
    """A default as TOML writes it (lists nested)."""
    if value is None:
        return "none"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_value(v)}" for k, v in value.items()) + "}"
    return number(value)


def default(field: FieldInfo) -> str:
    if field.is_required():
        return "required"
    value = field.get_default(call_default_factory=True)
    if isinstance(value, BaseModel):
        return "defaults"
    return f"`{_value(value)}`" if isinstance(value, str) else _value(value)


def _cell(text: str) -> str:
    """A table cell: a pipe inside it escaped, on one line."""
    return text.replace("|", "\\|").replace("\n", " ")


def row(key: str, field: FieldInfo) -> str:
    kind, bounds = describe(field.annotation, field.metadata)
    return f"| `{key}` | {_cell(kind)} | {_cell(default(field))} | {_cell(bounds) or '—'} | {_cell(field.description or '—')} |"


def table(section: Section) -> str:
    return "\n".join([HEADER, *(row(k, f) for k, f in section.fields().items())]) + "\n"


# --- the document ----------------------------------------------------------------------------------------


def regions(text: str) -> dict[str, str]:
    """Marker name -> the text between its BEGIN and END markers."""
    return {m["name"]: m["body"] for m in REGION.finditer(text)}


def documented_keys(body: str) -> list[str]:
    """The keys a region's rows name (the first cell of each row, in backticks)."""
    return re.findall(r"^\| `([^`]+)` \|", body, re.M)


def problems(text: str) -> list[str]:
    """What differs between the document and the schema: missing or unknown regions, keys documented but not in
    the schema or in the schema but not documented, and regions whose text is not the generated one."""
    found = regions(text)
    out = []
    expected = {s.name: s for s in SECTIONS}
    for name in found:
        if name not in expected:
            out.append(f"keys:{name}: a region for a table the schema does not have")
    for name, section in expected.items():
        if name not in found:
            out.append(f"keys:{name}: no region in the document (add <!-- BEGIN keys:{name} --> ... <!-- END keys:{name} -->)")
            continue
        doc_keys, schema_keys = documented_keys(found[name]), list(section.fields())
        out += [f"{name}.{k}: documented, but not a key of the schema" for k in doc_keys if k not in schema_keys]
        out += [f"{name}.{k}: a key of the schema, not documented" for k in schema_keys if k not in doc_keys]
        if found[name] != table(section):
            want, have = table(section).splitlines(), found[name].splitlines()
            diff = next((f"{h!r} should read {w!r}" for h, w in zip(have, want) if h != w),
                        f"{len(have)} lines, expected {len(want)}")
            out.append(f"keys:{name}: stale ({diff}); run python -m tissuerender.scene.doc_tables --write")
    return out


def rewrite(text: str) -> str:
    """``text`` with every marked region replaced by its generated table."""
    known = {s.name: s for s in SECTIONS}
    return REGION.sub(lambda m: (f"<!-- BEGIN keys:{m['name']} -->\n{table(known[m['name']])}<!-- END keys:{m['name']} -->"
                                 if m["name"] in known else m[0]), text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tissuerender.scene.doc_tables", description=__doc__.splitlines()[0])
    parser.add_argument("document", type=Path)
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="rewrite the marked regions in place")
    mode.add_argument("--check", action="store_true", help="list the differences; exit 1 if any")
    args = parser.parse_args(argv)
    text = args.document.read_text()
    if args.write:
        new = rewrite(text)
        if new != text:
            write_atomic(args.document, lambda tmp: Path(tmp).write_text(new))
    left = problems(args.document.read_text() if args.write else text)
    for line in left:
        print(f"{args.document}: {line}", file=sys.stderr)
    return 1 if left else 0


if __name__ == "__main__":
    sys.exit(main())
