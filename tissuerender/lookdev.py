"""``tissuerender lookdev``: a material's look under the laparoscope light, and how its optical values move it.

A material preset is rendered on a stage (a sphere, or the liver or kidney shape, or any scene of the
user's) with some optical values replaced (``--set``) and up to two of them swept (``--sweep``), or several
presets side by side (a row each, one sweep across): one labelled cell per combination in a contact sheet (PNG), and a JSON file next to it with, per cell, the
values used, the ``[objects.optics]`` table that reproduces the look in a scene, and measured pixel
statistics of the object (mean linear radiance, mean display value, peak luminance, object pixels).

Every cell is an ordinary scene render (the same validation, plan, renderer and post-effects), so what
lookdev shows is what a scene with the printed table renders. Same arguments, same pixels.
"""
from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from pydantic import ValidationError

import materials
from materials.optics import OVERRIDABLE, optical_value, with_overrides
from tissuerender.errors import UserError
from tissuerender.files import output_folder, write_json, write_png
from tissuerender.pipeline import render_frame_arrays
from tissuerender.scene import load_scene
from tissuerender.scene.load import read_toml, scene_from_data, short_repr, tomllib
from tissuerender.scene.schema import OpticsOverride
from tissuerender.scene.shapes import ORGAN_SHAPES

SHAPES = ("sphere",) + ORGAN_SHAPES
MAX_CELLS = 64
LABEL_PX = 14  # height of the label strip under each cell
LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance of linear RGB


@dataclass(frozen=True)
class Cell:
    """One image of the sheet: a material with ``overrides`` (every optical key set for it), and its label."""

    material: str
    overrides: dict
    label: str


def _stage(shape: str, mesh_path: Path | None) -> dict:
    """The built-in lookdev scene for ``shape`` (tables as in a scene file; the object comes first)."""
    if shape == "sphere":
        obj = {"name": "sample", "kind": "surface", "mesh": str(mesh_path)}
        camera = {"position": [0.0, -0.16, 0.045], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0],
                  "fov_deg": 30.0, "near": 0.01, "far": 2.0}
        # a white Lambertian sphere's nearest point sees irradiance pi (radiance 1 with the light at the
        # camera): E = L A / d^2 with A = 0.012^2 m^2 and d = 0.166 - 0.03 m
        radiance = [400.0, 384.0, 360.0]
    else:
        size, half_width, height = (0.15, 0.15, 0.10) if shape == "liver" else (0.11, 0.055, 0.052)
        obj = {"name": "sample", "kind": "body", "shape": shape, "scale": size, "render_subdivision": 1}
        # the default scene's view direction, at the distance where the organ's width fills ~80 % of a
        # 50 degree field of view
        d = 2.6 * half_width
        camera = {"position": [0.0, -0.806 * d, height / 2 + 0.591 * d], "look_at": [0.0, 0.0, height / 2],
                  "up": [0.0, 0.0, 1.0], "fov_deg": 50.0, "near": 0.01, "far": 2.0}
        # about half the default scene's irradiance (its light is set for a liver seen from 0.37 m)
        radiance = [c * (d / 0.37) ** 2 * 0.5 for c in (5000.0, 4800.0, 4500.0)]
    return {
        "scene": {"name": f"lookdev_{shape}", "seed": 1},
        "objects": [obj],
        "camera": camera,
        "light": {"attach": "camera", "size": [0.012, 0.012], "offset": [0.0, -0.008, 0.0],
                  "radiance": radiance, "sampling": "adaptive", "samples": 16},
        # a convex sphere never shadows itself: no shadow rays for it (the organ shapes need them)
        "effects": {"shadows": shape != "sphere", "sss": True, "backend": "numpy", "tonemap": {}},
        "output": {"resolution": [240, 180], "frames": 1},
    }


def _sphere_mesh(directory: Path) -> Path:
    """A smooth unit-sampled sphere of radius 3 cm (icosphere, 5,120 faces) as a PLY file in ``directory``."""
    import trimesh  # heavy (pulls in scipy.spatial) and needed only by the sphere stage: kept lazy

    path = directory / "lookdev_sphere.ply"
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.03)
    sphere.export(path)
    return path


def parse_value(option: str, key: str, text: str):
    """A ``--set``/``--sweep`` value written as TOML (``0.3``, ``[0.5, 0.1, 0.1]``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        raise UserError(f"{option} {key}: expected a TOML value (a number, or [r, g, b]), found {text!r}") from None


def _split(option: str, item: str) -> tuple[str, str]:
    key, sep, value = item.partition("=")
    key = key.strip()
    if not sep or not key or not value.strip():
        raise UserError(f"{option}: expected KEY=VALUE (e.g. roughness=0.3), found {item!r}")
    return key, value.strip()


def check_overrides(option: str, values: dict, optics) -> None:
    """Validate optical values as a scene's ``[objects.optics]`` table would be, naming the option and key."""
    try:
        OpticsOverride.model_validate(values)
    except ValidationError as e:
        first = e.errors(include_url=False)[0]
        key = str(first["loc"][0]) if first["loc"] else "?"
        if first["type"] == "extra_forbidden":
            raise UserError(f"{option} {key}: not an optical key; expected one of {', '.join(OVERRIDABLE)}") from None
        msg = first["msg"][0].lower() + first["msg"][1:]
        raise UserError(f"{option} {key}: expected {msg}, found {short_repr(values.get(key))}") from None
    try:
        with_overrides(optics, values)
    except ValueError as e:
        raise UserError(f"{option} {e}") from None


def _label(key: str, value) -> str:
    if isinstance(value, list):
        return f"{key}=[{', '.join(f'{v:g}' for v in value)}]"
    return f"{key}={value:g}"


def make_cells(names: list[str], sets: list[str], sweeps: list[str]) -> tuple[list[Cell], int, int, dict]:
    """The cells (row-major), the grid's rows and columns, and the fixed ``--set`` values. Several materials:
    one row each (and at most one ``--sweep``, the columns); one material: up to two sweeps (columns, rows)."""
    for name in names:
        if name not in materials.PRESET_NAMES:
            raise UserError(f"material: expected one of {', '.join(materials.PRESET_NAMES)}, found {name!r}")
    if len(set(names)) != len(names):
        raise UserError(f"material: each material once, found {' '.join(names)}")
    optics = [materials.get_preset(name).optics for name in names]
    fixed = {}
    for item in sets:
        key, text = _split("--set", item)
        if key in fixed:
            raise UserError(f"--set {key}: given twice")
        fixed[key] = parse_value("--set", key, text)
    for o in optics:
        check_overrides("--set", fixed, o)
    most = 2 if len(names) == 1 else 1
    if len(sweeps) > most:
        raise UserError(f"--sweep: at most {most} {'(rows and columns)' if most == 2 else '(columns; the materials are the rows)'}, "
                        f"found {len(sweeps)}")
    axes = []
    for item in sweeps:
        key, text = _split("--sweep", item)
        if key in fixed or any(key == k for k, _ in axes):
            raise UserError(f"--sweep {key}: the key is already set or swept")
        values = parse_value("--sweep", key, text)
        if not isinstance(values, list) or not values:
            raise UserError(f"--sweep {key}: expected a non-empty TOML list of values (e.g. [0.1, 0.3]), found {text!r}")
        for v in values:
            for o in optics:
                check_overrides("--sweep", {key: v}, o)
        axes.append((key, values))
    cols = axes[0] if axes else ("", [None])
    rows = axes[1] if len(axes) > 1 else ("", [None])
    n = len(cols[1]) * len(rows[1]) * len(names)
    if n > MAX_CELLS:
        raise UserError(f"--sweep: at most {MAX_CELLS} cells, found {len(names) * len(rows[1])} x {len(cols[1])} = {n}")
    cells = []
    for name, rv, cv in itertools.product(names, rows[1], cols[1]):
        over = dict(fixed)
        parts = [name] if len(names) > 1 else []
        for (key, _), v in ((rows, rv), (cols, cv)):
            if v is not None:
                over[key] = v
                parts.append(_label(key, v))
        if len(parts) == 0 or parts == [name]:
            parts = [name] + [_label(k, v) for k, v in fixed.items()]
        cells.append(Cell(name, over, "  ".join(parts)))
    return cells, len(names) * len(rows[1]), len(cols[1]), fixed


def _stage_data(shape: str, scene_path: str | None, workdir: Path) -> tuple[dict, Path]:
    """The stage's scene tables (the built-in stage's object without its material) and the path naming it."""
    if scene_path is None:
        return _stage(shape, _sphere_mesh(workdir) if shape == "sphere" else None), workdir / f"lookdev_{shape}.toml"
    path = Path(scene_path)
    return read_toml(path), path


def _objects_of(data: dict, path: Path, material: str) -> list[int]:
    """Indices of the scene's objects made of ``material`` (a clear error when there is none)."""
    objects = data.get("objects") if isinstance(data.get("objects"), list) else []
    idx = [i for i, o in enumerate(objects) if isinstance(o, dict) and o.get("material") == material]
    if not idx:
        found = sorted({str(o.get("material")) for o in objects if isinstance(o, dict)})
        raise UserError(f"{path}: no object is made of {material!r} (materials in the scene: {', '.join(found) or 'none'})")
    return idx


def _toml_table(values: dict) -> str:
    def fmt(v):
        return "[" + ", ".join(f"{c:g}" for c in v) + "]" if isinstance(v, list) else f"{v:g}"

    return "[objects.optics]\n" + "".join(f"{k} = {fmt(v)}\n" for k, v in values.items())


def render_cells(cells: list[Cell], shape: str = "sphere", scene_path: str | None = None,
                 resolution: tuple[int, int] | None = None, samples: int | None = None, exposure: float = 0.0,
                 frame: int = 1):
    """Render every cell; returns ``(images, stats)``: uint8 (H, W, 3) per cell and one dict per cell.
    On the built-in stage the object is made of the cell's material; on a scene (``scene_path``), every
    object made of it gets the cell's values."""
    with tempfile.TemporaryDirectory(prefix="tissuerender_lookdev_") as tmp:
        base, path = _stage_data(shape, scene_path, Path(tmp))
        if scene_path is not None:  # the scene as it is must be valid, and hold every material, before anything renders
            load_scene(path)
            for cell in cells:
                _objects_of(base, path, cell.material)
        images, stats = [], []
        for cell in cells:
            data = copy.deepcopy(base)
            if scene_path is None:
                data["objects"][0]["material"] = cell.material
                idx = [0]
            else:
                idx = _objects_of(data, path, cell.material)
            for i in idx:
                data["objects"][i]["optics"] = {**data["objects"][i].get("optics", {}), **cell.overrides}
            if samples is not None:
                data.setdefault("light", {})["samples"] = samples
            if scene_path is None and exposure:
                data["effects"]["tonemap"]["exposure"] = exposure
            text = json.dumps(data, sort_keys=True).encode()
            scene = scene_from_data(data, path, hashlib.sha256(text).hexdigest())
            start = time.perf_counter()
            image, result = render_frame_arrays(scene, frame=frame, resolution=resolution)
            seconds = time.perf_counter() - start
            images.append(image)
            stats.append(_cell_stats(cell, image, result.hdr, _object_mask(result, scene, idx), seconds))
    return images, stats


def _object_mask(result, scene, idx: list[int]) -> np.ndarray:
    """Pixels wholly covered by the objects ``idx`` of the scene (all supersamples on them)."""
    h, w = result.hdr.shape[:2]
    # the shading points are the covered (super)samples in row-major order, as the raster lists them
    depth, material = result.gbuffer["depth"], result.gbuffer["material_id"]
    index = np.full(depth.shape, -1, np.int64)
    index[np.isfinite(depth)] = material
    # render objects: bodies first, then static surfaces, then tools (tissuerender.render_inputs.render_objects)
    order = [i for i, o in enumerate(scene.objects) if o.kind == "body"]
    order += [i for i, o in enumerate(scene.objects) if o.kind == "surface"]
    wanted = np.isin(index, [k for k, i in enumerate(order) if i in idx])
    ss = index.shape[0] // h
    return wanted.reshape(h, ss, w, ss).all(axis=(1, 3))


def _cell_stats(cell: Cell, image: np.ndarray, hdr: np.ndarray, mask: np.ndarray, seconds: float) -> dict:
    n = int(mask.sum())
    lum = hdr[mask].astype(np.float64) @ LUMA if n else np.zeros(0)
    return {
        "label": cell.label,
        "material": cell.material,
        "overrides": cell.overrides,
        "optics_toml": _toml_table(cell.overrides) if cell.overrides else "",
        "object_pixels": n,
        "mean_linear_rgb": [round(float(v), 6) for v in hdr[mask].astype(np.float64).mean(axis=0)] if n else None,
        "mean_display_rgb": [round(float(v), 6) for v in (image[mask] / 255.0).mean(axis=0)] if n else None,
        "peak_luminance": round(float(lum.max()), 6) if n else None,
        "p99_luminance": round(float(np.percentile(lum, 99)), 6) if n else None,
        "seconds": round(seconds, 3),
    }


def _fit(draw, font, text: str, width: int) -> str:
    """``text`` cut to ``width`` pixels (with an ellipsis) if it is wider."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "...", font=font) > width:
        text = text[:-1]
    return text + "..."


def contact_sheet(images: list[np.ndarray], labels: list[str], rows: int, cols: int) -> tuple[np.ndarray, int]:
    """The cells in a rows x cols grid, each with its label in a strip underneath (uint8 RGB), and the strip's
    height: one line per label, or one line per part of the label (parts are separated by two spaces) when
    a label is wider than a cell."""
    h, w = images[0].shape[:2]
    font = ImageFont.load_default()
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    split = any(probe.textlength(text, font=font) > w - 4 for text in labels)
    lines = [text.split("  ") if split else [text] for text in labels]
    strip = LABEL_PX * max(len(part) for part in lines)
    sheet = Image.new("RGB", (cols * w, rows * (h + strip)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for k, (img, parts) in enumerate(zip(images, lines)):
        r, c = divmod(k, cols)
        sheet.paste(Image.fromarray(img), (c * w, r * (h + strip)))
        for j, text in enumerate(parts):
            draw.text((c * w + 3, r * (h + strip) + h + 1 + j * LABEL_PX), _fit(draw, font, text, w - 4),
                      fill=(230, 230, 230), font=font)
    return np.asarray(sheet), strip


def sheet_path(text: str) -> Path:
    """The contact sheet's path from ``-o``, checked before any cell renders: a ``.png`` name, neither it nor
    its ``.json`` report an existing folder, in a folder that exists (or can be created) and is writable."""
    out = Path(text)
    if out.suffix.lower() != ".png":
        raise UserError(f"-o {out}: expected a .png file name for the contact sheet, found suffix {out.suffix or 'none'!r}")
    for path in (out, out.with_suffix(".json")):
        if path.is_dir():
            raise UserError(f"-o {out}: {path} is an existing folder; expected a file name")
    try:
        output_folder(out.parent)
    except UserError as e:
        raise UserError(f"-o {out}: {e}") from None
    return out


def _write_outputs(out: Path, sheet: np.ndarray, report: dict) -> Path:
    write_png(out, sheet)
    side = out.with_suffix(".json")
    write_json(side, report)
    return side


def _resolution(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit()) or not (8 <= int(w) <= 4096 and 8 <= int(h) <= 4096):
        raise UserError(f"--resolution: expected WxH with 8 <= W, H <= 4096 (e.g. 240x180), found {text!r}")
    return int(w), int(h)


def _cmd_lookdev(args) -> int:
    if args.scene is not None and args.shape != "sphere":
        raise UserError("--shape: the stage is the scene given with --scene; leave --shape out")
    if args.frame < 1:
        raise UserError(f"--frame: expected a frame number >= 1, found {args.frame}")
    if args.samples is not None and not 1 <= args.samples <= 1024:
        raise UserError(f"--samples: expected 1 ... 1024 light samples, found {args.samples}")
    if not math.isfinite(args.exposure) or abs(args.exposure) > 20:
        raise UserError(f"--exposure: expected -20 ... 20 stops, found {args.exposure}")
    out = sheet_path(args.out)
    cells, rows, cols, fixed = make_cells(args.material, args.set or [], args.sweep or [])
    images, stats = render_cells(cells, args.shape, args.scene, _resolution(args.resolution), args.samples,
                                 args.exposure, args.frame)
    sheet, strip = contact_sheet(images, [c.label for c in cells], rows, cols)
    report = {"materials": args.material, "stage": args.scene or args.shape, "rows": rows, "columns": cols,
              "cell_size": [int(images[0].shape[1]), int(images[0].shape[0])], "label_px": strip,
              "preset_optics": {m: {k: optical_value(materials.get_preset(m).optics, k) for k in OVERRIDABLE
                                    if optical_value(materials.get_preset(m).optics, k) is not None}
                                for m in args.material},
              "set": fixed, "cells": stats}
    side = _write_outputs(out, sheet, report)
    if not args.quiet:
        print(f"{'cell':<40} {'pixels':>7} {'mean linear rgb':>26} {'peak lum':>9} {'s':>6}")
        for s in stats:
            rgb = " ".join(f"{v:8.4f}" for v in s["mean_linear_rgb"]) if s["mean_linear_rgb"] else "-"
            peak = f"{s['peak_luminance']:9.4f}" if s["peak_luminance"] is not None else "-"
            print(f"{s['label'][:40]:<40} {s['object_pixels']:>7} {rgb:>26} {peak:>9} {s['seconds']:6.2f}")
        print(f"wrote {args.out} ({rows} x {cols} cells) and {side}")
        if len(cells) == 1 and cells[0].overrides:
            print("to use this look in a scene, add under the object:\n" + stats[0]["optics_toml"].rstrip())
    return 0


def add_cli(subparsers) -> None:
    p = subparsers.add_parser(
        "lookdev", help="render a material on a lookdev stage, with optical values set or swept",
        description="Render MATERIAL(s) under the laparoscope light; --set replaces optical values, --sweep varies "
                    "one (columns) or two (columns, rows); several materials are rows; writes a labelled contact sheet and a JSON report.")
    p.add_argument("material", nargs="+",
                   help=f"material preset(s): {', '.join(materials.PRESET_NAMES)} (several: a row each)")
    p.add_argument("-o", "--out", default="lookdev.png", help="contact sheet (.png); the report goes next to it (.json)")
    p.add_argument("--shape", choices=SHAPES, default="sphere", help="the built-in stage's object (default: sphere)")
    p.add_argument("--scene", help="use this scene as the stage: every object made of MATERIAL gets the values")
    p.add_argument("--frame", type=int, default=1, help="with --scene: the frame to render (default 1)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="an optical or layer value for every cell, as TOML (roughness=0.3, albedo=[0.5,0.1,0.1], "
                        "coat_roughness=0.05, granular_weight=0.1); repeatable")
    p.add_argument("--sweep", action="append", metavar="KEY=[V1,V2,...]",
                   help="values of one key, one per column (a second --sweep, with one material: rows); a TOML list")
    p.add_argument("--resolution", metavar="WxH", help="size of one cell (default: the stage's, 240x180)")
    p.add_argument("--samples", type=int, help="light samples per pixel (default: the stage's)")
    p.add_argument("--exposure", type=float, default=0.0, help="built-in stage: tone-map exposure [stops]")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_cmd_lookdev)
