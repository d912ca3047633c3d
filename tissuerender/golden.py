"""Golden-image testing as a user feature: ``tissuerender golden check|update DIR``.

``DIR/manifest.toml`` lists images::

    [[image]]
    name = "default"                  # file stem of the stored image(s)
    scene = "../../scenes/default.toml"   # relative to DIR
    resolution = [160, 120]
    frame = 1                         # the frame rendered (the scene simulated up to it; default 1)
    mode = "exact"                    # or "statistical"
    flip_max = 0.02                   # exact: mean FLIP (NVIDIA FLIP, LDR) must not exceed this
    psnr_min = 35.0                   # exact: PSNR [dB] must reach this
    bias_max = [6e-5, 6e-5, 6e-5]     # exact: largest |mean difference| per channel (LDR units), see below
    n_seeds = 8                       # statistical: renders per check, each with its own seed
    alpha = 0.01                      # statistical: family-wise false-failure rate (Bonferroni)

*Exact* mode renders the scene with its own seed and compares the PNG with the stored one: a
perceptual metric (FLIP through flip-evaluator) and PSNR, with per-image thresholds. *Statistical*
mode is for renders meant to vary with the seed (the way Mitsuba 3's render tests work): ``update``
stores the per-pixel mean and variance over ``n_seeds`` seeds; ``check`` renders ``n_seeds`` other
seeds and runs a per-pixel Welch t-test of the new mean against the stored one, failing when the
smallest p-value falls below ``alpha / pixels`` — so a noisy but unbiased image passes and a biased
one fails.

Both modes also bound the *bias*: the mean difference over the image, per channel. Per-pixel metrics
miss a global brightness change of a few percent (FLIP 0.0196 and PSNR 45 dB for the default scene
made 2.5 % brighter), yet averaged over N pixels such a shift stands out of the noise by a factor √N.
The bound is ``BIAS_Z`` standard errors of the mean difference between two unbiased renders
(:func:`bias_standard_error`): in exact mode from a render with another seed (``bias_max`` stores it;
:func:`bias_bound` derives it, and a check derives it when the manifest omits it, at the cost of one
more render); in statistical mode from the difference of the two seed-averaged means. Failures write ``DIR/failures/NAME.new.png`` and ``NAME.diff.png`` (the FLIP error map,
or |t| / 10 for statistical mode).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import flip_evaluator
import numpy as np
from PIL import Image
from pydantic import BaseModel, ConfigDict, Field, ValidationError

import postfx
from tissuerender.errors import SceneError, UserError
from tissuerender.files import write_png
from tissuerender.pipeline import render_image
from tissuerender.scene import load_scene
from tissuerender.scene.load import read_toml, validation_error


class GoldenImage(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)

    name: Annotated[str, Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")]
    scene: str
    resolution: Annotated[list[Annotated[int, Field(ge=8, le=4096)]], Field(min_length=2, max_length=2)] = [160, 120]
    frame: Annotated[int, Field(ge=1, le=100000)] = 1  # the validation cases show their fields at a later frame
    mode: Literal["exact", "statistical"] = "exact"
    flip_max: Annotated[float, Field(ge=0.0, le=1.0)] = 0.02
    psnr_min: Annotated[float, Field(ge=0.0, le=200.0)] = 35.0
    bias_max: Annotated[list[Annotated[float, Field(ge=0.0, le=1.0)]], Field(min_length=3, max_length=3)] | None = None
    n_seeds: Annotated[int, Field(ge=2, le=256)] = 8
    alpha: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.01


class GoldenManifest(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    image: Annotated[list[GoldenImage], Field(min_length=1)]


@dataclass
class Result:
    name: str
    mode: str
    passed: bool
    metrics: dict
    message: str = ""


def load_manifest(directory) -> tuple[Path, GoldenManifest]:
    directory = Path(directory)
    path = directory / "manifest.toml"
    if not directory.is_dir():
        raise UserError(f"{directory}: not a folder (expected a golden-image folder with manifest.toml)")
    data = read_toml(path)
    try:
        manifest = GoldenManifest.model_validate(data)
    except ValidationError as e:
        raise validation_error(path, e) from None
    names = [img.name for img in manifest.image]
    if len(set(names)) != len(names):
        raise SceneError(path, "image", f"expected unique names, found {names}")
    for i, img in enumerate(manifest.image):
        if img.mode == "statistical" and img.bias_max is not None:
            raise SceneError(path, f"image[{i}].bias_max", "expected no bias_max in statistical mode (the bound "
                             "follows from the seeds' statistics), found one")
    return path, manifest


def _render(entry: GoldenImage, directory: Path, seed: int | None = None) -> np.ndarray:
    scene = load_scene((directory / entry.scene).resolve())
    return render_image(scene, seed=seed, frame=entry.frame, resolution=tuple(entry.resolution))


def _to_float(img_u8: np.ndarray) -> np.ndarray:
    return img_u8.astype(np.float32) / 255.0


def psnr(reference: np.ndarray, test: np.ndarray) -> float:
    mse = float(np.mean((reference.astype(np.float64) - test.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def flip(reference: np.ndarray, test: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean FLIP error and the (H, W, 3) magma error map of two LDR sRGB images in [0, 1]."""
    error_map, mean, _ = flip_evaluator.evaluate(np.ascontiguousarray(reference), np.ascontiguousarray(test),
                                                 "LDR", applyMagma=True)
    return float(mean), np.asarray(error_map)


# Standard errors an unbiased mean difference may reach: two-sided normal tail 5.7e-7 per channel. The channel
# mean is a sum over thousands of pixels (central limit), so an unbiased render essentially never fails by chance.
BIAS_Z = 5.0
BIAS_BLOCK = 8  # [pixels] side of the batch-means blocks (longer than the noise's correlation: blur, bloom)
QUANTUM = 1.0 / 255.0  # one 8-bit level


def channel_bias(reference: np.ndarray, test: np.ndarray) -> np.ndarray:
    """Mean of ``test - reference`` over the image, per channel (LDR units)."""
    return (test.astype(np.float64) - reference.astype(np.float64)).reshape(-1, 3).mean(axis=0)


def block_means(images: np.ndarray) -> np.ndarray:
    """Means of the ``BIAS_BLOCK``² blocks of (..., H, W, 3) images: (..., blocks, 3). Block means are close to
    independent even where the noise is spatially correlated (postfx blur, bloom), unlike single pixels."""
    h, w = images.shape[-3:-1]
    b = BIAS_BLOCK
    if h < 2 * b or w < b:
        raise ValueError(f"bias estimate needs at least {2 * b} x {b} pixels, got {h} x {w}")
    cut = np.asarray(images, dtype=np.float64)[..., : h // b * b, : w // b * b, :]
    lead = cut.shape[:-3]
    blocks = cut.reshape(*lead, h // b, b, w // b, b, 3).mean(axis=(-4, -2))
    return blocks.reshape(*lead, -1, 3)


def _rounding_floor(pixels: int) -> float:
    """Standard error of an image mean over ``pixels`` pixels from two independent 8-bit roundings per pixel,
    each uniform over one level (variance q²/12): a render that differs only by rounding re-rounds its pixels."""
    return QUANTUM * math.sqrt(1.0 / 6.0 / pixels)


def bias_standard_error(difference: np.ndarray) -> np.ndarray:
    """Standard error, per channel, of the image mean of ``difference`` (H, W, 3): the difference of two
    unbiased renders with independent noise. Batch means, ``std(block means) / sqrt(blocks)``, which needs no
    assumption of independent pixels; at least the rounding floor."""
    blocks = block_means(difference)
    batch = blocks.std(axis=0, ddof=1) / math.sqrt(blocks.shape[0])
    h, w = difference.shape[:2]
    return np.maximum(batch, _rounding_floor(h * w))


def bias_bound(entry: GoldenImage, directory) -> np.ndarray:
    """The exact mode's ``bias_max``: ``BIAS_Z`` standard errors of the mean difference between the render
    with the scene's seed and one with the next seed (LDR units, per channel)."""
    directory = Path(directory)
    seed = load_scene((directory / entry.scene).resolve()).seed
    own = _to_float(_render(entry, directory))
    other = _to_float(_render(entry, directory, seed + 1))
    return BIAS_Z * bias_standard_error(other - own)


def compare_exact(entry: GoldenImage, stored: np.ndarray, new: np.ndarray,
                  bias_max) -> tuple[bool, dict, str, np.ndarray]:
    """Exact mode's verdict on two LDR images in [0, 1]: FLIP, PSNR and the per-channel bias bound."""
    mean_flip, error_map = flip(stored, new)
    value = psnr(stored, new)
    bias = channel_bias(stored, new)
    bias_max = np.asarray(bias_max, dtype=np.float64)
    ok = mean_flip <= entry.flip_max and value >= entry.psnr_min and bool(np.all(np.abs(bias) <= bias_max))
    metrics = {"flip": mean_flip, "psnr": value, "bias": bias.tolist(), "bias_max": bias_max.tolist()}
    message = (f"FLIP {mean_flip:.4f} (max {entry.flip_max}), PSNR {value:.1f} dB (min {entry.psnr_min}), "
               f"bias {_triple(bias)} (max {_triple(bias_max)})")
    return ok, metrics, message, error_map


def compare_statistical(entry: GoldenImage, ref_mean, ref_var, n_ref: int, mean, var,
                        mean_variance) -> tuple[bool, dict, str, np.ndarray]:
    """Statistical mode's verdict: the per-pixel Welch test (Bonferroni over pixels) and the per-channel bias.

    ``mean_variance`` is the variance, per channel, of one render's image mean (:func:`_stats`); both sides
    average independent seeds, so the mean difference has standard error sqrt(mean_variance (1/n_ref + 1/n)),
    at least the rounding floor, and may reach ``BIAS_Z`` of them."""
    t, p = welch_t_test(ref_mean, ref_var, n_ref, mean, var, entry.n_seeds)
    threshold = entry.alpha / p.size
    bias = channel_bias(ref_mean, mean)
    se = np.sqrt(np.asarray(mean_variance, np.float64) * (1.0 / n_ref + 1.0 / entry.n_seeds))
    bias_max = BIAS_Z * np.maximum(se, _rounding_floor(p.shape[0] * p.shape[1]))
    ok = float(p.min()) >= threshold and bool(np.all(np.abs(bias) <= bias_max))
    metrics = {"min_p": float(p.min()), "threshold": threshold, "max_abs_t": float(np.abs(t).max()),
               "bias": bias.tolist(), "bias_max": bias_max.tolist()}
    message = (f"min p {p.min():.3g} (Bonferroni threshold {threshold:.3g}), max |t| {np.abs(t).max():.2f}, "
               f"bias {_triple(bias)} (max {_triple(bias_max)})")
    return ok, metrics, message, np.clip(np.abs(t) / 10.0, 0.0, 1.0)


def _triple(values) -> str:
    return "[" + ", ".join(f"{v:.2g}" for v in values) + "]"


def _seeds(n: int, offset: int) -> list[int]:
    return [offset + k for k in range(n)]


def _stats(entry: GoldenImage, directory: Path, offset: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel mean and variance over ``n_seeds`` renders, and the variance of one render's image mean per
    channel: the block means' variances over the seeds summed, over blocks², as blocks are close to independent."""
    renders = np.stack([_to_float(_render(entry, directory, seed)) for seed in _seeds(entry.n_seeds, offset)])
    blocks = block_means(renders)  # (seeds, blocks, 3)
    mean_variance = blocks.var(axis=0, ddof=1).sum(axis=0) / blocks.shape[1] ** 2
    return renders.mean(axis=0), renders.var(axis=0, ddof=1), mean_variance


def welch_t_test(mean_ref, var_ref, n_ref, mean_new, var_new, n_new, var_floor=1e-8):
    """Per-pixel Welch two-sample t statistics and two-sided p-values (Welch–Satterthwaite degrees of
    freedom). With a handful of seeds per side the variances are themselves noisy; a normal z-test would
    understate the tails (P(|z| > 5) = 6e-7, but P(|t| > 5) = 5e-4 at 10 degrees of freedom) and fail
    unbiased images once thousands of pixels are tested."""
    from scipy.stats import t as student_t  # heavy and needed only by statistical checks: kept lazy

    a = np.maximum(var_ref, var_floor) / n_ref
    b = np.maximum(var_new, var_floor) / n_new
    t = (mean_new - mean_ref) / np.sqrt(a + b)
    dof = (a + b) ** 2 / (a * a / (n_ref - 1) + b * b / (n_new - 1))
    p = 2.0 * student_t.sf(np.abs(t), dof)
    return t, p


def _read_png(path: Path) -> np.ndarray:
    if not path.is_file():
        raise UserError(f"{path}: stored golden image missing; run `tissuerender golden update {path.parent}`")
    return np.asarray(Image.open(path).convert("RGB"))


def selected(directory, only: str | None = None) -> list[GoldenImage]:
    """The manifest's images, or just the one named ``only`` (a name the manifest lacks is a user error)."""
    path, manifest = load_manifest(directory)
    if only is None:
        return list(manifest.image)
    chosen = [entry for entry in manifest.image if entry.name == only]
    if not chosen:
        names = ", ".join(entry.name for entry in manifest.image)
        raise UserError(f"{path}: --only {only!r}: no image of that name; expected one of {names}")
    return chosen


def update(directory, only: str | None = None) -> list[Path]:
    """Render every listed image and store it (PNG; plus mean/variance for statistical mode)."""
    directory = Path(directory)
    written = []
    for entry in selected(directory, only):
        if entry.mode == "exact":
            write_png(directory / f"{entry.name}.png", _render(entry, directory))
        else:
            mean, var, _ = _stats(entry, directory, offset=0)
            write_png(directory / f"{entry.name}.png", postfx.to_uint8(mean))
            np.savez_compressed(directory / f"{entry.name}.stats.npz", mean=mean.astype(np.float32),
                                var=var.astype(np.float32), n=np.int64(entry.n_seeds))
        written.append(directory / f"{entry.name}.png")
    return written


def check(directory, only: str | None = None, write_failures: bool = True) -> list[Result]:
    """Compare fresh renders with the stored images; returns one :class:`Result` per image."""
    directory = Path(directory)
    results = []
    for entry in selected(directory, only):
        if entry.mode == "exact":
            stored = _to_float(_read_png(directory / f"{entry.name}.png"))
            new = _to_float(_render(entry, directory))
            if stored.shape != new.shape:
                results.append(Result(entry.name, "exact", False, {}, f"size {stored.shape} != {new.shape}"))
                continue
            bias_max = entry.bias_max if entry.bias_max is not None else bias_bound(entry, directory)
            ok, metrics, message, diff = compare_exact(entry, stored, new, bias_max)
        else:
            stats_path = directory / f"{entry.name}.stats.npz"
            if not stats_path.is_file():
                raise UserError(f"{stats_path}: stored statistics missing; run `tissuerender golden update {directory}`")
            ref = np.load(stats_path)
            mean, var, mean_variance = _stats(entry, directory, offset=100_000)
            ok, metrics, message, diff = compare_statistical(entry, ref["mean"], ref["var"], int(ref["n"]), mean, var,
                                                             mean_variance)
            new = mean
        if not ok and write_failures:
            failures = directory / "failures"
            write_png(failures / f"{entry.name}.new.png", postfx.to_uint8(new))
            write_png(failures / f"{entry.name}.diff.png", postfx.to_uint8(diff))
        results.append(Result(entry.name, entry.mode, bool(ok), metrics, message))
    return results


def _cmd_check(args) -> int:
    results = check(args.dir, only=args.only)
    for r in results:
        print(f"{'pass' if r.passed else 'FAIL'}  {r.name:20s} [{r.mode}] {r.message}")
    failed = [r for r in results if not r.passed]
    print(f"{len(results) - len(failed)} passed, {len(failed)} failed")
    return 1 if failed else 0


def _cmd_update(args) -> int:
    for path in update(args.dir, only=args.only):
        print(f"wrote {path}")
    return 0


def add_cli(subparsers) -> None:
    golden = subparsers.add_parser("golden", help="golden-image regression checks")
    sub = golden.add_subparsers(dest="golden_command", required=True)
    for name, func, text in (("check", _cmd_check, "render and compare with the stored images"),
                             ("update", _cmd_update, "render and store the images")):
        p = sub.add_parser(name, help=text)
        p.add_argument("dir", help="folder holding manifest.toml")
        p.add_argument("--only", default=None, help="just the image with this name")
        p.set_defaults(func=func)
