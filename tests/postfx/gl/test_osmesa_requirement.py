"""Tests marked ``osmesa`` skip where the backend cannot run, but fail under ``CI=true`` naming why
(tests/conftest.py), so a CI machine without libOSMesa cannot pass with the GL backend untested."""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parents[2]
ROOT = TESTS.parent
MISSING = "libOSMesa is not installed; install the Debian package libosmesa6"


def _conftest():
    """tests/conftest.py as a module (the suite imports with --import-mode=importlib: no sys.path entry)."""
    spec = importlib.util.spec_from_file_location("tests_conftest_under_test", TESTS / "conftest.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_decision_skips_locally_fails_under_ci_and_runs_when_osmesa_works():
    decide = _conftest().osmesa_requirement
    assert decide(None, {"CI": "true"}) is None and decide(None, {}) is None
    assert decide(MISSING, {}) == ("skip", f"the OSMesa backend cannot run: {MISSING}")
    assert decide(MISSING, {"CI": "false"})[0] == "skip"
    for ci in ("true", "TRUE", "1"):
        assert decide(MISSING, {"CI": ci}) == ("fail", f"CI=true and the OSMesa backend cannot run: {MISSING}")


def _run_marked_test_without_osmesa(ci: str | None) -> subprocess.CompletedProcess:
    """pytest in a subprocess on one osmesa test, with ``postfx.chain.osmesa_problem`` reporting the library
    missing (what the conftest asks on a machine without libosmesa6)."""
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    script = ("import sys, pytest, postfx.chain\n"
              f"postfx.chain.osmesa_problem = lambda: {MISSING!r}\n"
              "sys.exit(pytest.main(sys.argv[1:]))")
    node = "tests/postfx/gl/test_chain.py::test_full_chain_agrees_and_auto_prefers_osmesa"
    return subprocess.run([sys.executable, "-c", script, node, "-q", "-rs", "-p", "no:cacheprovider"], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=600)


def test_a_marked_test_without_osmesa_fails_under_ci_naming_the_library():
    run = _run_marked_test_without_osmesa("true")
    assert run.returncode == 1, run.stdout + run.stderr
    assert f"CI=true and the OSMesa backend cannot run: {MISSING}" in run.stdout
    assert "1 error" in run.stdout  # pytest.fail in setup: an error, exit status 1


def test_a_marked_test_without_osmesa_skips_outside_ci():
    run = _run_marked_test_without_osmesa(None)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "1 skipped" in run.stdout and MISSING in run.stdout
