"""The ground truth in the file formats other tools read (docs/ground-truth.md, "Other formats"), each written
atomically (``tissuerender.files.write_atomic``); the ``passes/*.npy`` masters stay the reference.

- ``exr``: ``frame_NNNN.exr``, one multi-layer OpenEXR per frame (the ``OpenEXR`` package, 3.x API): linear
  HDR colour as ``R``, ``G``, ``B`` and every pass of the frame as named layers (``EXR_LAYERS``; float32 bit
  for bit as in the ``.npy``, ids and masks as UINT), plus ``distance.Z``, the length of the camera-space
  point ``|X_cam| = depth |K^-1 (u, v, 1)|``.
- ``depth_png``: ``passes/depth_NNNN.png``, 16-bit grey PNG, value ``round(depth / s)`` with the scale
  ``s = depth_png_scale`` [m per unit] stated in ``cameras.json``; 0 where nothing is seen.
- flow (written whenever a frame has ``flow_forward`` / ``flow_backward``): ``passes/<key>_NNNN.flo``, the
  Middlebury format (Baker et al. 2011, ``flow-code/README``: float32 ``202021.25`` ("PIEH"), int32 width,
  int32 height, then float32 ``u, v`` interleaved row by row; unknown flow as ``1e10``), and
  ``passes/<key>_NNNN.png``, the KITTI 2015 16-bit RGB PNG (Geiger et al., devkit ``io_flow.h``:
  ``R = u * 64 + 2^15``, ``G = v * 64 + 2^15``, ``B = 1`` where the flow is valid, all three 0 elsewhere).
- ``mp4``: ``preview.mp4``, the colour frames as a video (PyAV: H.264 when the FFmpeg build has an encoder for
  it, MPEG-4 part 2 otherwise), written once at the end of the sequence from the PNG frames.
"""
from __future__ import annotations

import struct
from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image

from tissuerender.files import write_atomic
from tissuerender.groundtruth.output import PASSES_FOLDER, pass_path
from tissuerender.groundtruth.pass_kernels import kitti_flow_code
from tissuerender.stages import StageRecorder, recorder_or_new

FLOW_KEYS = ("flow_forward", "flow_backward")  # the passes written as .flo and KITTI PNG as well
PREVIEW = "preview.mp4"
FLO_MAGIC = 202021.25  # "PIEH" read as a little-endian float32
FLO_UNKNOWN = 1e10  # Middlebury flowIO.h UNKNOWN_FLOW; readers treat |u|, |v| > 1e9 as unknown
KITTI_SCALE = 64.0  # KITTI stores u * 64 + 2^15 in 16 bits: 1/64 px steps, |flow| < 512 px
KITTI_OFFSET = 2.0 ** 15
DEPTH_PNG_SCALE = 1e-4  # [m per unit]: 0.1 mm steps up to 6.5535 m (a laparoscope sees 0.01-0.3 m)

# EXR channel suffixes of a pass by its number of components (floats); ids and masks are one UINT channel
_AXES = {1: ("Z",), 2: ("X", "Y"), 3: ("X", "Y", "Z")}


def exr_path(out: Path, index: int) -> Path:
    return Path(out) / f"frame_{index:04d}.exr"


def depth_png_path(out: Path, index: int) -> Path:
    return Path(out) / PASSES_FOLDER / f"depth_{index:04d}.png"


def flo_path(out: Path, key: str, index: int) -> Path:
    return Path(out) / PASSES_FOLDER / f"{key}_{index:04d}.flo"


def kitti_path(out: Path, key: str, index: int) -> Path:
    return Path(out) / PASSES_FOLDER / f"{key}_{index:04d}.png"


# --- OpenEXR -----------------------------------------------------------------------------------------------

def ray_distance(depth: np.ndarray, K, lens=None) -> np.ndarray:
    """Distance [m] from the camera centre to the point seen, ``depth |K^-1 (u, v, 1)|`` (pixel centres at
    integer ``(u, v)``), float32; inf where the depth is. With a ``lens`` (``groundtruth.lens.FisheyeLens``) the
    pixel's ray is its undistorted position's, ``depth |K^-1 (undistort(u, v), 1)|``."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(float)
    uv = np.stack([u, v], axis=-1)
    if lens is not None:
        uv = lens.undistort(uv)
    rays = np.concatenate([uv, np.ones((h, w, 1))], axis=-1) @ np.linalg.inv(np.asarray(K, float)).T
    return (depth.astype(float) * np.linalg.norm(rays, axis=-1)).astype(np.float32)


def exr_channels(hdr: np.ndarray, passes: dict, K: np.ndarray | None = None, lens=None) -> dict[str, np.ndarray]:
    """The channels of a frame's EXR: ``R``, ``G``, ``B`` from ``hdr`` and, per pass ``name`` of shape (H, W)
    or (H, W, c): floats as ``name.Z`` (one component) or ``name.X``, ``name.Y`` [, ``name.Z``]; integer ids
    as ``name.id`` and boolean masks as ``name.mask``, both UINT. With ``K`` and a ``depth`` pass, also
    ``distance.Z`` (``ray_distance``). Anything not an image-sized array is left out."""
    hdr = np.asarray(hdr, np.float32)
    h, w = hdr.shape[:2]
    channels = {c: np.ascontiguousarray(hdr[..., i]) for i, c in enumerate("RGB")}
    layers = dict(passes)
    if K is not None and "depth" in layers:
        layers["distance"] = ray_distance(np.asarray(layers["depth"]), K, lens)
    for name, array in layers.items():
        if not isinstance(array, np.ndarray) or array.shape[:2] != (h, w) or array.ndim not in (2, 3):
            continue
        if array.dtype == bool:
            channels[f"{name}.mask"] = array.astype(np.uint32)
        elif np.issubdtype(array.dtype, np.integer):
            if array.ndim != 2 or (array < 0).any():
                raise ValueError(f"{name}: expected non-negative ids (H, W) for an EXR UINT layer")
            channels[f"{name}.id"] = array.astype(np.uint32)
        else:
            planes = array[..., None] if array.ndim == 2 else array
            if planes.shape[2] not in _AXES:
                raise ValueError(f"{name}: expected 1 to 3 components for an EXR layer, found {planes.shape[2]}")
            for i, axis in enumerate(_AXES[planes.shape[2]]):
                channels[f"{name}.{axis}"] = np.ascontiguousarray(planes[..., i], dtype=np.float32)
    return channels


# Stored uncompressed, like the passes' .npy masters: one 640x480 liver_probe frame with the four single-frame
# passes writes in 0.14 s and 14.8 MB so, against ZIP's 1.2 s and 9.3 MB, RLE's 0.52 s and 13.5 MB and PIZ's
# 2.8 s and 8.1 MB (all lossless; benchmarks/passes_cost.py, docs/ground-truth.md "Cost"); ZIP alone cost a fifth
# of the colour frame, and the motion passes rewrite the file once more at the end of the sequence.
EXR_COMPRESSION = "NO_COMPRESSION"


def write_exr(path: Path, hdr: np.ndarray, passes: dict, K: np.ndarray | None = None, lens=None) -> None:
    """One multi-layer scanline OpenEXR (uncompressed, ``EXR_COMPRESSION``) with ``exr_channels``."""
    import OpenEXR  # imported here: only renders that ask for exr pay for loading it

    channels = exr_channels(hdr, passes, K, lens)
    header = {"compression": getattr(OpenEXR, EXR_COMPRESSION), "type": OpenEXR.scanlineimage}

    def write(tmp):
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))

    write_atomic(path, write)


# --- 16-bit depth PNG ---------------------------------------------------------------------------------------

def depth_png_scale(far: float) -> float:
    """Metres per unit of the depth PNG: 0.1 mm, or ``far / 65535`` when the camera sees beyond 6.5535 m, so
    every depth up to ``camera.far`` fits in 16 bits."""
    return max(DEPTH_PNG_SCALE, float(far) / 65535.0)


def encode_depth_png(depth: np.ndarray, scale: float) -> np.ndarray:
    """``round(depth / scale)`` as uint16, at least 1 where a surface is seen and 0 where nothing is (inf)."""
    depth = np.asarray(depth, float)
    seen = np.isfinite(depth)
    units = np.zeros(depth.shape, np.uint16)
    units[seen] = np.clip(np.rint(depth[seen] / scale), 1, 65535)
    return units


# zlib level of the PNGs written per frame (depth, KITTI flow): level 1 writes a 640x480 frame's PNG several
# times faster than the default 6 for about 1.5 to 2 times the bytes; every reader decodes any level
# (docs/ground-truth.md, "Cost")
PNG_ZLIB_LEVEL = 1


def write_depth_png(path: Path, depth: np.ndarray, scale: float) -> None:
    units = encode_depth_png(depth, scale)
    write_atomic(path, lambda tmp: Image.fromarray(units).save(tmp, format="PNG",  # uint16: Pillow mode I;16
                                                               compress_level=PNG_ZLIB_LEVEL))


# --- optical flow: Middlebury .flo and KITTI PNG --------------------------------------------------------------

def _check_flow(flow: np.ndarray) -> np.ndarray:
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow: expected an (H, W, 2) array of (u, v) pixels, found shape {flow.shape}")
    return flow


def write_flo(path: Path, flow: np.ndarray) -> None:
    """Middlebury ``.flo``: magic 202021.25, width, height (int32), then float32 (u, v) per pixel in row
    order, little-endian; NaN (no flow) written as ``FLO_UNKNOWN``."""
    flow = _check_flow(flow).astype("<f4", copy=False)
    values = np.where(np.isfinite(flow).all(axis=2, keepdims=True), flow, np.float32(FLO_UNKNOWN))
    h, w = flow.shape[:2]

    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(struct.pack("<fii", FLO_MAGIC, w, h))
            values.tofile(f)  # C order: (u, v) per pixel, row by row

    write_atomic(path, write)


def encode_kitti_flow(flow: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint16: ``u * 64 + 2^15``, ``v * 64 + 2^15`` rounded, and 1 where the flow is valid: finite
    and representable (``-512 <= u, v < 512``); invalid pixels are (0, 0, 0)."""
    flow = np.ascontiguousarray(_check_flow(flow), float)
    out = np.empty(flow.shape[:2] + (3,), np.uint16)
    kitti_flow_code(flow, KITTI_SCALE, KITTI_OFFSET, out)
    return out


def decode_kitti_flow(coded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of ``encode_kitti_flow``: (flow (H, W, 2) float32 with NaN where invalid, valid (H, W))."""
    valid = coded[..., 2] > 0
    flow = (coded[..., :2].astype(np.float32) - np.float32(KITTI_OFFSET)) / np.float32(KITTI_SCALE)
    flow[~valid] = np.nan
    return flow, valid


def encode_png16_rgb(rgb: np.ndarray) -> bytes:
    """A 16-bit RGB PNG file's bytes (FFmpeg's PNG encoder through PyAV; Pillow writes 8-bit RGB only)."""
    import av  # the video library, imported here: only flow files and videos need it

    h, w = rgb.shape[:2]
    codec = av.CodecContext.create("png", "w")
    codec.width, codec.height, codec.pix_fmt = w, h, "rgb48be"
    # FFmpeg's png encoder options: zlib level PNG_ZLIB_LEVEL, each row filtered by its left neighbour's difference
    codec.options = {"compression_level": str(PNG_ZLIB_LEVEL), "pred": "sub"}
    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb, np.uint16), format="rgb48le")
    packets = list(codec.encode(frame.reformat(format="rgb48be"))) + list(codec.encode(None))
    return b"".join(bytes(p) for p in packets)


def write_kitti_flow(path: Path, flow: np.ndarray) -> None:
    data = encode_png16_rgb(encode_kitti_flow(flow))
    write_atomic(path, lambda tmp: Path(tmp).write_bytes(data))


# --- preview video ------------------------------------------------------------------------------------------

def video_codec() -> str:
    """``libx264`` (H.264) when this FFmpeg build can encode it, else ``mpeg4``."""
    import av

    for name in ("libx264", "mpeg4"):
        try:
            av.codec.Codec(name, "w")
            return name
        except Exception:  # PyAV raises its own UnknownCodecError (a ValueError in some versions)
            continue
    raise RuntimeError("PyAV's FFmpeg has neither an H.264 nor an MPEG-4 encoder")


def write_video(path: Path, frames, fps: float) -> int:
    """Encode uint8 RGB frames (H, W, 3), all of one size, as an mp4; odd sizes are padded to even (yuv420p
    halves the chroma resolution) by repeating the last row or column. Returns the number of frames."""
    import av

    rate = Fraction(float(fps)).limit_denominator(1001)
    count = 0

    def write(tmp):
        nonlocal count
        with av.open(str(tmp), "w", format="mp4") as container:
            stream = None
            for rgb in frames:
                rgb = np.asarray(rgb, np.uint8)
                h, w = rgb.shape[:2]
                rgb = np.pad(rgb, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
                if stream is None:
                    codec = video_codec()
                    stream = container.add_stream(codec, rate=rate,
                                                  options={"crf": "18"} if codec == "libx264" else {})
                    stream.width, stream.height, stream.pix_fmt = rgb.shape[1], rgb.shape[0], "yuv420p"
                    stream.codec_context.thread_count = 1  # one thread: the same bytes on every machine
                    if codec == "mpeg4":
                        stream.bit_rate = 8_000_000
                for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                    container.mux(packet)
                count += 1
            if stream is None:
                raise ValueError(f"{path}: no frames to write")
            for packet in stream.encode(None):
                container.mux(packet)

    write_atomic(path, write)
    return count


def write_preview(out: Path, png_paths: list[Path], fps: float) -> Path:
    """``preview.mp4`` from the sequence's PNG frames, in order."""
    path = Path(out) / PREVIEW
    write_video(path, (np.asarray(Image.open(p).convert("RGB")) for p in png_paths), fps)
    return path


# --- what the pipeline calls --------------------------------------------------------------------------------

def frame_files(out: Path, index: int, formats) -> list[Path]:
    """The files ``write_frame_formats`` writes for frame ``index`` (flow files not included: they depend on
    the passes a frame has)."""
    files = [exr_path(out, index)] if "exr" in formats else []
    return files + ([depth_png_path(out, index)] if "depth_png" in formats else [])


def write_frame_formats(out: Path, index: int, formats, hdr: np.ndarray, passes: dict, K: np.ndarray,
                        depth_scale: float, recorder: StageRecorder | None = None, lens=None) -> list[Path]:
    """Frame ``index``'s EXR and depth PNG (as ``formats`` asks) and its flow as .flo and KITTI PNG (whenever
    ``passes`` holds ``flow_forward`` / ``flow_backward``), each timed as its plan stage (``write_exr``,
    ``write_depth_png``, ``write_flow_files``). Returns the paths written."""
    rec = recorder_or_new(recorder)
    written = []
    if "exr" in formats:
        with rec.run("write_exr"):
            write_exr(exr_path(out, index), hdr, passes, K, lens)
        written.append(exr_path(out, index))
    if "depth_png" in formats:
        with rec.run("write_depth_png"):
            write_depth_png(depth_png_path(out, index), passes["depth"], depth_scale)
        written.append(depth_png_path(out, index))
    if any(key in passes for key in FLOW_KEYS):
        with rec.run("write_flow_files"):
            written += write_flow_files(out, index, passes)
    return written


def write_flow_files(out: Path, index: int, passes: dict) -> list[Path]:
    """``.flo`` and KITTI PNG of each of ``FLOW_KEYS`` that ``passes`` holds."""
    written = []
    for key in FLOW_KEYS:
        if key in passes:
            write_flo(flo_path(out, key, index), passes[key])
            write_kitti_flow(kitti_path(out, key, index), passes[key])
            written += [flo_path(out, key, index), kitti_path(out, key, index)]
    return written


MOTION_KEYS = ("flow_forward", "flow_backward", "occluded_forward", "occluded_backward", "scene_flow_forward",
               "scene_flow_backward")


def complete_from_masters(out: Path, indices, formats) -> list[Path]:
    """For motion passes written as ``passes/<key>_NNNN.npy`` after the frames (flow needs the next frame):
    each frame's ``.flo`` and KITTI PNG, and, with ``exr`` in ``formats``, the frame's EXR rewritten with the
    motion layers it lacks. Returns the new files (an EXR rewritten in place is not listed again)."""
    written = []
    for k in indices:
        motion = {key: np.load(pass_path(out, key, k)) for key in MOTION_KEYS if pass_path(out, key, k).exists()}
        # already written from the frame's own passes dict (and not older than the masters): nothing to do
        current = [p for key in FLOW_KEYS if key in motion for p in (flo_path(out, key, k), kitti_path(out, key, k))
                   if p.exists() and p.stat().st_mtime_ns >= pass_path(out, key, k).stat().st_mtime_ns]
        if not motion or len(current) == 2 * sum(key in motion for key in FLOW_KEYS):
            continue
        written += write_flow_files(out, k, motion)
        if "exr" in formats and exr_path(out, k).exists():
            _add_exr_layers(exr_path(out, k), motion)
    return written


def _add_exr_layers(path: Path, passes: dict) -> bool:
    """Rewrite ``path`` with the layers of ``passes`` it does not have yet (its own channels kept as read)."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        channels = {name: c.pixels for name, c in f.channels().items()}
    h, w = channels["R"].shape
    added = {k: v for k, v in exr_channels(np.zeros((h, w, 3), np.float32), passes).items() if k not in "RGB"}
    if set(added) <= set(channels):
        return False
    channels.update(added)
    header = {"compression": getattr(OpenEXR, EXR_COMPRESSION), "type": OpenEXR.scanlineimage}

    def write(tmp):
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))

    write_atomic(path, write)
    return True
