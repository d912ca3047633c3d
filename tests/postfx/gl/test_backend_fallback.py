"""backend = "auto" falls back to NumPy, and backend = "osmesa" is a one-line user error naming the cause,
whatever keeps VTK's off-screen window from opening: the project's own check (libOSMesa missing), an
ImportError (a VTK wheel without ``vtkOSOpenGLRenderWindow``, before 9.4) or an OSError (a library that
does not load)."""
from __future__ import annotations

import json
import sys
import types

import numpy as np
import pytest
import vtkmodules.vtkRenderingOpenGL2 as real_opengl2

import postfx
from postfx.gl import context
from postfx.tonemap import Tonemap
from tissuerender.cli import main

H, W = 12, 16
LENS = postfx.Lens(70.0, W, H)


def _without_window_class(monkeypatch):
    """vtkRenderingOpenGL2 as in a VTK wheel built without OSMesa: everything but the off-screen window."""
    fake = types.ModuleType(real_opengl2.__name__)
    fake.__dict__.update({k: v for k, v in vars(real_opengl2).items() if k != "vtkOSOpenGLRenderWindow"})
    monkeypatch.setitem(sys.modules, real_opengl2.__name__, fake)
    monkeypatch.setattr(sys.modules["vtkmodules"], "vtkRenderingOpenGL2", fake, raising=False)
    return "cannot import name 'vtkOSOpenGLRenderWindow'"


def _window_library_fails_to_load(monkeypatch):
    """The window class exists, but creating it loads a library that is not there."""
    def window():
        raise OSError("libGL.so.1: cannot open shared object file: No such file or directory")

    fake = types.ModuleType(real_opengl2.__name__)
    fake.__dict__.update(vars(real_opengl2))
    fake.vtkOSOpenGLRenderWindow = window
    monkeypatch.setitem(sys.modules, real_opengl2.__name__, fake)
    monkeypatch.setattr(sys.modules["vtkmodules"], "vtkRenderingOpenGL2", fake, raising=False)
    return "libGL.so.1: cannot open shared object file"


# (not tested: an OSError from binding the GL calls after the window opened, also caught in Context.__init__;
# a second OSMesa window would leave the process's context no longer current for the other GL tests)
FAILURES = {"import": _without_window_class, "constructor": _window_library_fails_to_load}


@pytest.fixture
def fresh_context(monkeypatch):
    """No context yet in this process, and libOSMesa reported present (so the failure is VTK's)."""
    monkeypatch.setattr(context.Context, "_instance", None)
    monkeypatch.setattr(context, "library_available", lambda: True)


def _inputs():
    rng = np.random.default_rng(5)
    return rng.uniform(0.0, 4.0, (H, W, 3)).astype(np.float32), np.full((H, W), 0.1, np.float32)


@pytest.mark.parametrize("failure", sorted(FAILURES))
def test_auto_falls_back_to_numpy_with_the_same_pixels(failure, fresh_context, monkeypatch):
    FAILURES[failure](monkeypatch)
    hdr, depth = _inputs()
    chain = [("tonemap", Tonemap())]
    reference = postfx.apply_chain(hdr, depth, chain, LENS, backend="numpy")
    auto = postfx.apply_chain(hdr, depth, chain, LENS, backend="auto")
    assert auto.backend_used == "numpy"
    assert np.array_equal(auto.image, reference.image)
    assert context.Context._instance is None  # nothing half-built kept


@pytest.mark.parametrize("failure", sorted(FAILURES))
def test_osmesa_names_the_window_class_and_the_cause(failure, fresh_context, monkeypatch):
    cause = FAILURES[failure](monkeypatch)
    hdr, depth = _inputs()
    with pytest.raises(postfx.OSMesaUnavailable) as err:
        postfx.apply_chain(hdr, depth, [("tonemap", Tonemap())], LENS, backend="osmesa")
    message = str(err.value)
    assert "\n" not in message and "vtkOSOpenGLRenderWindow" in message and cause in message
    assert "vtk>=9.4" in message and "backend = \"numpy\"" in message


def test_render_exits_2_with_osmesa_and_records_numpy_with_auto(scene_dict, write_scene, tmp_path, fresh_context,
                                                                monkeypatch, capsys):
    cause = _without_window_class(monkeypatch)
    scene_dict["effects"]["backend"] = "osmesa"
    path = write_scene(scene_dict, "osmesa.toml")
    assert main(["render", str(path), "-o", str(tmp_path / "gl"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "effects.backend = \"osmesa\"" in err and cause in err
    assert not (tmp_path / "gl" / "frame_0001.png").exists()
    scene_dict["effects"]["backend"] = "auto"
    path = write_scene(scene_dict, "auto.toml")
    assert main(["render", str(path), "-o", str(tmp_path / "auto"), "-q"]) == 0
    manifest = json.loads((tmp_path / "auto" / "manifest.json").read_text())
    assert manifest["postfx_backend"] == "numpy" and (tmp_path / "auto" / "frame_0001.png").exists()
