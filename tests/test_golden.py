"""Golden-image checks: the project's own goldens pass, and the checks catch real regressions."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w

from tissuerender import golden
from tissuerender.cli import main

pytest_plugins = ["tissuerender.pytest_golden"]
GOLDEN = Path(__file__).resolve().parent / "golden"
NAMES = [img.name for img in golden.load_manifest(GOLDEN)[1].image]


ENTRIES = {img.name: img for img in golden.load_manifest(GOLDEN)[1].image}
EXACT = [name for name in NAMES if ENTRIES[name].mode == "exact"]


@pytest.mark.parametrize("name", NAMES)
def test_project_golden_image(golden, name):
    result = golden(GOLDEN, name)
    bias, bias_max = np.array(result.metrics["bias"]), np.array(result.metrics["bias_max"])
    assert bias_max.shape == (3,) and np.all(np.abs(bias) <= bias_max)  # the real render has no global bias
    if result.mode == "exact":
        assert result.metrics["flip"] <= ENTRIES[name].flip_max and result.metrics["psnr"] >= ENTRIES[name].psnr_min


def _scaled(image_u8, factor):
    """A global brightness change, quantised to 8 bits as a render would be."""
    return golden._to_float(np.clip(np.rint(image_u8 * factor), 0, 255).astype(np.uint8))


@pytest.mark.parametrize("factor", [1.02, 0.975, 1.03])
@pytest.mark.parametrize("name", EXACT)
def test_a_few_percent_global_brightness_change_fails_the_bias_bound(name, factor):
    """FLIP and PSNR let a global bias of a few percent through on the darker goldens (kidney_static at +2 %: FLIP
    0.007 <= 0.02, PSNR 51 dB); the per-channel bias bound catches it on every golden, while the stored image
    compared with itself passes."""
    entry = ENTRIES[name]
    stored_u8 = golden._read_png(GOLDEN / f"{name}.png")
    stored = golden._to_float(stored_u8)
    assert golden.compare_exact(entry, stored, stored, entry.bias_max)[0]
    ok, metrics, message, _ = golden.compare_exact(entry, stored, _scaled(stored_u8, factor), entry.bias_max)
    assert not ok and np.all(np.abs(metrics["bias"]) > np.array(entry.bias_max)), message
    assert np.all(np.sign(metrics["bias"]) == np.sign(factor - 1.0))
    if name == "kidney_static" and factor == 1.02:  # what the per-pixel metrics alone would have passed
        assert metrics["flip"] <= entry.flip_max and metrics["psnr"] >= entry.psnr_min


@pytest.mark.parametrize("factor", [1.02, 0.975])
def test_statistical_bias_bound_catches_a_few_percent_and_passes_the_stored_noise(factor):
    """The stored mean against a draw of the same noise (per-pixel normal with the stored variance over n seeds)
    passes; the stored mean scaled by 2-2.5 % fails on its bias."""
    entry = ENTRIES["kidney_static_noise"]
    ref = np.load(GOLDEN / f"{entry.name}.stats.npz")
    mean, var, n = ref["mean"].astype(np.float64), ref["var"].astype(np.float64), int(ref["n"])
    draw = mean + np.random.default_rng(1).normal(size=mean.shape) * np.sqrt(np.maximum(var, 1e-8) / n)
    mean_variance = (var.reshape(-1, 3).sum(axis=0)) / (mean.shape[0] * mean.shape[1]) ** 2  # independent pixels
    ok, metrics, message, _ = golden.compare_statistical(entry, mean, var, n, draw, var, mean_variance)
    assert ok, message
    ok, metrics, message, _ = golden.compare_statistical(entry, mean, var, n, mean * factor, var, mean_variance)
    assert not ok and np.all(np.abs(metrics["bias"]) > np.array(metrics["bias_max"])), message


def test_bias_standard_error_is_the_noise_of_the_image_mean():
    """Independent pixel noise of standard deviation s: the batch-means standard error of the mean is
    s / sqrt(N) (within its own sampling error, 1/sqrt(2 (blocks - 1)) = 4 % for 300 blocks); spatially
    correlated noise (4 x 4 pixel patches) gets the larger error of fewer independent values."""
    rng = np.random.default_rng(4)
    s = 0.01
    white = rng.normal(scale=s, size=(120, 160, 3))
    assert golden.bias_standard_error(white) == pytest.approx(np.full(3, s / np.sqrt(120 * 160)), rel=0.2)
    patches = np.repeat(np.repeat(rng.normal(scale=s, size=(30, 40, 3)), 4, axis=0), 4, axis=1)
    assert golden.bias_standard_error(patches) == pytest.approx(np.full(3, s / np.sqrt(30 * 40)), rel=0.2)
    floor = golden.bias_standard_error(np.zeros((120, 160, 3)))
    assert np.allclose(floor, (1 / 255) * np.sqrt(1 / 6 / (120 * 160)), rtol=1e-15)  # n=4 flops, <= 0.5 ulp each


def _setup(tmp_path, scene_dict, write_scene, mode):
    path = write_scene(scene_dict, "g.toml")
    d = tmp_path / "g"
    d.mkdir()
    (d / "manifest.toml").write_text(tomli_w.dumps({"image": [
        {"name": "img", "scene": "../g.toml", "resolution": [48, 36], "mode": mode, "n_seeds": 6,
         "flip_max": 0.01, "psnr_min": 40.0}]}))
    assert main(["golden", "update", str(d)]) == 0
    return path, d


def test_exact_check_fails_on_a_changed_render_and_writes_diffs(tmp_path, scene_dict, write_scene, capsys):
    path, d = _setup(tmp_path, scene_dict, write_scene, "exact")
    assert main(["golden", "check", str(d)]) == 0
    scene_dict["light"]["radiance"] = [4500.0, 3000.0, 3000.0]
    write_scene(scene_dict, "g.toml")
    assert main(["golden", "check", str(d)]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "0 passed, 1 failed" in out
    assert (d / "failures" / "img.diff.png").exists() and (d / "failures" / "img.new.png").exists()


def test_statistical_check_passes_noise_and_catches_a_small_bias(tmp_path, scene_dict, write_scene):
    scene_dict["light"]["samples"] = 1  # very noisy: only the statistics can tell right from wrong
    path, d = _setup(tmp_path, scene_dict, write_scene, "statistical")
    result = golden.check(d)[0]
    assert result.passed, result.message  # other seeds, same expectation
    scene_dict["light"]["radiance"] = [3300.0, 3300.0, 3300.0]  # +10 % light: a biased renderer
    write_scene(scene_dict, "g.toml")
    biased = golden.check(d)[0]
    assert not biased.passed and biased.metrics["min_p"] < biased.metrics["threshold"]


def test_bad_manifest_is_a_user_error(tmp_path, capsys):
    d = tmp_path / "bad"
    d.mkdir()
    (d / "manifest.toml").write_text('[[image]]\nname = "x"\nscene = "s.toml"\nflip_maxx = 1\n')
    assert main(["golden", "check", str(d)]) == 2
    err = capsys.readouterr().err
    assert "image[0].flip_maxx" in err and "unknown key" in err


def test_only_an_unknown_name_is_a_user_error_not_an_empty_pass(tmp_path, capsys):
    """`golden check --only nosuch` used to print "0 passed, 0 failed" and exit 0."""
    d = tmp_path / "g"
    d.mkdir()
    (d / "manifest.toml").write_text('[[image]]\nname = "liver"\nscene = "s.toml"\n\n'
                                     '[[image]]\nname = "kidney"\nscene = "s.toml"\n')
    for command in ("check", "update"):
        assert main(["golden", command, str(d), "--only", "nosuch"]) == 2
        err = capsys.readouterr().err
        assert "'nosuch'" in err and "expected one of liver, kidney" in err and "Traceback" not in err
