"""``tissuerender show DIR -o sheet.png|video.mp4``: the ground truth of a render folder drawn over its frames,
so that errors show before anyone trains on the data (issue 18 item 5; docs/ground-truth.md, "Looking at it").

One contact sheet per frame, panels in a grid, each labelled:

- ``colour + outlines``: the PNG frame with every boundary between instance ids outlined (a pixel whose id
  differs from its right or lower neighbour), in yellow (white would vanish on a specular highlight);
- ``depth``: matplotlib's ``viridis`` over the frame's depth range, near bright, far dark; black where nothing
  is seen. The map is linear in depth, so its colour index is monotone in depth;
- ``normal``: ``(n + 1) / 2`` as RGB in camera axes (x right = red, y down = green, z forward = blue);
- ``segmentation``: one colour per instance id (golden-angle hues), the background black;
- ``material_coords``: rest positions normalised over the frame's box, as RGB;
- ``flow_forward`` / ``flow_backward``: the Middlebury colour coding (``flow_colours``);
- ``tracks`` (when ``DIR/tracks.npz`` exists): each track's position in this frame over the colour frame, a
  filled dot where visible and a hollow ring where occluded.

Panels are scaled up by a whole factor (nearest) so a small render stays legible. ``-o *.mp4`` encodes one
sheet per frame (``tissuerender.groundtruth.formats.write_video``).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from tissuerender.errors import UserError
from tissuerender.files import write_png
from tissuerender.groundtruth.formats import write_video
from tissuerender.groundtruth.output import PASSES_FOLDER

PASS_FILE = re.compile(r"^(?P<name>[a-z_]+)_(?P<index>\d{4,})\.npy$")
MIN_PANEL_WIDTH = 256  # [px] panels are scaled up by a whole factor to at least this width
LABEL_HEIGHT = 14  # [px] the label strip above each panel
COLUMNS = 3


# --- the Middlebury flow colour coding (Baker et al., "A database and evaluation methodology for optical flow",
# IJCV 2011; flow-code/colorcode.cpp): 55 hues around the wheel, saturation by magnitude ---------------------

def colour_wheel() -> np.ndarray:
    """(55, 3) float in [0, 1]: red -> yellow -> green -> cyan -> blue -> magenta -> red, in the code's segment
    lengths RY 15, YG 6, GC 4, CB 11, BM 13, MR 6 (chosen for perceptually even steps)."""
    segments = [(15, (1, 0, 0), (1, 1, 0)), (6, (1, 1, 0), (0, 1, 0)), (4, (0, 1, 0), (0, 1, 1)),
                (11, (0, 1, 1), (0, 0, 1)), (13, (0, 0, 1), (1, 0, 1)), (6, (1, 0, 1), (1, 0, 0))]
    rows = []
    for n, start, end in segments:
        s = np.arange(n)[:, None] / n
        rows.append((1 - s) * np.array(start, float) + s * np.array(end, float))
    return np.concatenate(rows)


def flow_colours(flow: np.ndarray, max_radius: float | None = None) -> np.ndarray:
    """uint8 RGB (H, W, 3) of a flow field (H, W, 2) in pixels: the hue is the direction, ``atan2(-v, -u)``
    around the wheel, the saturation the magnitude over ``max_radius`` (default: the largest finite one);
    white is no motion, magnitudes beyond the radius are darkened to 75 %, NaN (no flow) is black."""
    flow = np.asarray(flow, float)
    u, v = flow[..., 0], flow[..., 1]
    known = np.isfinite(u) & np.isfinite(v)
    u, v = np.where(known, u, 0.0), np.where(known, v, 0.0)
    radius = np.hypot(u, v)
    if max_radius is None:
        max_radius = radius[known].max() if known.any() else 0.0
    rad = radius / max_radius if max_radius > 0 else np.zeros_like(radius)
    wheel = colour_wheel()
    n = len(wheel)
    a = np.arctan2(-v, -u) / np.pi  # in [-1, 1]
    fk = (a + 1) / 2 * (n - 1)
    k0 = np.floor(fk).astype(int)
    k1 = (k0 + 1) % n
    f = (fk - k0)[..., None]
    col = (1 - f) * wheel[k0] + f * wheel[k1]
    inside = (rad <= 1)[..., None]
    col = np.where(inside, 1 - rad[..., None] * (1 - col), col * 0.75)
    col[~known] = 0.0
    return np.rint(255 * col).astype(np.uint8)


def depth_colours(depth: np.ndarray) -> np.ndarray:
    """uint8 RGB: ``viridis`` at ``(d_max - d) / (d_max - d_min)`` over the finite depths (near bright), black
    where nothing is seen."""
    depth = np.asarray(depth, float)
    seen = np.isfinite(depth)
    out = np.zeros(depth.shape + (3,), np.uint8)
    if seen.any():
        lo, hi = depth[seen].min(), depth[seen].max()
        x = (hi - depth[seen]) / (hi - lo) if hi > lo else np.ones(int(seen.sum()))
        out[seen] = depth_lut()[np.rint(x * 255).astype(int)]
    return out


def depth_lut() -> np.ndarray:
    """The 256 uint8 colours of the depth panel, index 0 the farthest depth."""
    from matplotlib import colormaps

    return np.rint(colormaps["viridis"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)


def _normal_colours(normal):
    n = np.nan_to_num(np.asarray(normal, float), nan=-1.0)  # unseen: (-1 + 1) / 2 = black
    return np.rint((n + 1) / 2 * 255).clip(0, 255).astype(np.uint8)


def _id_colours(ids):
    hues = (np.arange(int(ids.max()) + 1) * 0.381966) % 1.0  # golden angle: neighbours' ids far apart in hue
    import colorsys

    table = np.array([colorsys.hsv_to_rgb(h, 0.7, 0.95) for h in hues]) * 255
    table[0] = 0
    return np.rint(table[ids]).astype(np.uint8)


def _coords_colours(coords):
    c = np.asarray(coords, float)
    known = np.isfinite(c).all(axis=-1)
    out = np.zeros(c.shape[:2] + (3,), np.uint8)
    if known.any():
        lo, hi = c[known].min(axis=0), c[known].max(axis=0)
        out[known] = np.rint((c[known] - lo) / np.where(hi > lo, hi - lo, 1.0) * 255).astype(np.uint8)
    return out


def outlines(colour: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """``colour`` with yellow on every pixel whose id differs from its right or lower neighbour's."""
    edge = np.zeros(ids.shape, bool)
    edge[:, :-1] |= ids[:, :-1] != ids[:, 1:]
    edge[:-1, :] |= ids[:-1, :] != ids[1:, :]
    out = colour.copy()
    out[edge] = (255, 255, 0)
    return out


# --- reading a render folder ---------------------------------------------------------------------------------

def pass_frames(folder: Path) -> dict[int, dict[str, Path]]:
    """``{frame: {pass name: .npy path}}`` of ``folder/passes``; a user error naming the folder when there are
    none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: expected a render output folder, found "
                        f"{'a file' if folder.exists() else 'nothing'}")
    frames: dict[int, dict[str, Path]] = {}
    if (folder / PASSES_FOLDER).is_dir():
        for path in sorted((folder / PASSES_FOLDER).iterdir()):
            m = PASS_FILE.match(path.name)
            if m:
                frames.setdefault(int(m["index"]), {})[m["name"]] = path
    if not frames:
        raise UserError(f"{folder}: no ground-truth passes (expected {PASSES_FOLDER}/<pass>_0001.npy); render a "
                        "scene whose [output] passes lists some, e.g. passes = [\"depth\", \"segmentation\"]")
    return frames


def _load(path: Path) -> np.ndarray:
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise UserError(f"{path}: cannot read the pass: {e}") from None


def _tracks(folder: Path):
    path = Path(folder) / "tracks.npz"
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in ("points_2d", "occluded")}
    except (OSError, ValueError, KeyError) as e:
        raise UserError(f"{path}: expected points_2d (N, T, 2) and occluded (N, T): {e}") from None


def panels(folder: Path, frame: int, files: dict[str, Path], tracks=None) -> list[tuple[str, np.ndarray]]:
    """The frame's panels as (label, uint8 RGB (H, W, 3)), in sheet order."""
    arrays = {name: _load(path) for name, path in files.items()}
    shape = next(iter(arrays.values())).shape[:2]
    png = Path(folder) / f"frame_{frame:04d}.png"
    colour = np.asarray(Image.open(png).convert("RGB")) if png.exists() else np.zeros(shape + (3,), np.uint8)
    for name, a in arrays.items():
        if a.shape[:2] != shape or colour.shape[:2] != shape:
            raise UserError(f"{files[name]}: expected {shape[1]} x {shape[0]} pixels like the frame's other files, "
                            f"found {a.shape[1]} x {a.shape[0]}")
    out = []
    ids = arrays.get("segmentation")
    out.append(("colour + outlines" if ids is not None else "colour",
                outlines(colour, ids) if ids is not None else colour))
    if "depth" in arrays:
        out.append(("depth (near bright)", depth_colours(arrays["depth"])))
    if "normal" in arrays:
        out.append(("normal (camera axes)", _normal_colours(arrays["normal"])))
    if ids is not None:
        out.append(("segmentation", _id_colours(ids)))
    if "material_coords" in arrays:
        out.append(("material_coords", _coords_colours(arrays["material_coords"])))
    for key in ("flow_forward", "flow_backward"):
        if key in arrays:
            out.append((key, flow_colours(arrays[key])))
    if tracks is not None:
        out.append(("tracks (ring: occluded)", colour))
    return out


def contact_sheet(folder, frame: int | None = None):
    """One frame's sheet: (uint8 RGB image, {panel label: (x0, y0, x1, y1) of its pixels in the sheet}, the
    whole scale factor of the panels). ``frame`` defaults to the first with passes."""
    frames = pass_frames(folder)
    if frame is None:
        frame = min(frames)
    if frame not in frames:
        raise UserError(f"{folder}: --frame {frame}: no passes for it (frames with passes: "
                        f"{min(frames)}-{max(frames)})")
    tracks = _tracks(folder)
    items = panels(folder, frame, frames[frame], tracks)
    h, w = items[0][1].shape[:2]
    s = max(1, -(-MIN_PANEL_WIDTH // w))
    cols = min(COLUMNS, len(items))
    rows = -(-len(items) // cols)
    sheet = Image.new("RGB", (cols * w * s, rows * (h * s + LABEL_HEIGHT)), (32, 32, 32))
    draw = ImageDraw.Draw(sheet)
    layout = {}
    for i, (label, rgb) in enumerate(items):
        x0, y0 = (i % cols) * w * s, (i // cols) * (h * s + LABEL_HEIGHT) + LABEL_HEIGHT
        sheet.paste(Image.fromarray(np.repeat(np.repeat(rgb, s, 0), s, 1)), (x0, y0))
        draw.text((x0 + 3, y0 - LABEL_HEIGHT + 1), f"{label}  frame {frame}", fill=(230, 230, 230))
        layout[label] = (x0, y0, x0 + w * s, y0 + h * s)
        if label.startswith("tracks"):
            _draw_tracks(draw, tracks, frame, (x0, y0), s)
    return np.asarray(sheet), layout, s


def _draw_tracks(draw, tracks, frame: int, origin, s: int) -> None:
    """Track ``i`` at frame ``k`` (index ``k - 1`` of its T frames): a dot of its own hue, hollow if occluded."""
    import colorsys

    points, occluded = tracks["points_2d"], tracks["occluded"]
    t = frame - 1
    if t >= points.shape[1]:
        return
    r = max(2, s)
    for i, ((x, y), hidden) in enumerate(zip(points[:, t], occluded[:, t])):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        cx, cy = origin[0] + (x + 0.5) * s, origin[1] + (y + 0.5) * s  # pixel centres at integer (x, y)
        colour = tuple(int(255 * c) for c in colorsys.hsv_to_rgb((i * 0.381966) % 1.0, 0.9, 1.0))
        box = (cx - r, cy - r, cx + r, cy + r)
        draw.ellipse(box, outline=colour, width=1) if hidden else draw.ellipse(box, fill=colour)


def show(folder, out, frame: int | None = None, fps: float = 24.0) -> Path:
    """Write ``out``: a ``.png`` contact sheet of ``frame`` or an ``.mp4`` of every frame's sheet."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".mp4"):
        raise UserError(f"{out}: -o: expected a .png (contact sheet) or .mp4 (video of the sheets), found "
                        f"{out.suffix or 'no suffix'}")
    if suffix == ".png":
        write_png(out, contact_sheet(folder, frame)[0])
        return out
    frames = sorted(pass_frames(folder)) if frame is None else [frame]
    write_video(out, (contact_sheet(folder, k)[0] for k in frames), _fps(folder, fps))
    return out


def _fps(folder: Path, default: float) -> float:
    """Frames per second from ``cameras.json`` (the time step between frames), else ``default``."""
    try:
        times = [f["time"] for f in json.loads((Path(folder) / "cameras.json").read_text())["frames"]]
        return 1.0 / (times[1] - times[0]) if len(times) > 1 and times[1] > times[0] else default
    except (OSError, ValueError, KeyError, TypeError):
        return default


def add_cli(sub) -> None:
    p = sub.add_parser("show", help="draw a render folder's ground truth (depth, flow, tracks, outlines)")
    p.add_argument("folder", help="a render output folder with passes/")
    p.add_argument("-o", "--out", required=True, help="sheet.png (one frame) or video.mp4 (every frame)")
    p.add_argument("--frame", type=int, default=None, help="the frame to draw (default: the first)")
    p.set_defaults(func=_cmd_show)


def _cmd_show(args) -> int:
    path = show(args.folder, args.out, args.frame)
    print(f"wrote {path}")
    return 0
