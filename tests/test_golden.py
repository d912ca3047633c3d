"""Golden-image checks: the project's own goldens pass, and the checks catch real regressions."""
from __future__ import annotations

from pathlib import Path

import pytest
import tomli_w

from tissuerender import golden
from tissuerender.cli import main

pytest_plugins = ["tissuerender.pytest_golden"]
GOLDEN = Path(__file__).resolve().parent / "golden"
NAMES = [img.name for img in golden.load_manifest(GOLDEN)[1].image]


@pytest.mark.parametrize("name", NAMES)
def test_project_golden_image(golden, name):
    result = golden(GOLDEN, name)
    if result.mode == "exact":
        assert result.metrics["flip"] <= 0.02 and result.metrics["psnr"] >= 35.0


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
