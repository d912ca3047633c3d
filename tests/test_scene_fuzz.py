"""Property test: random mutations of valid scenes either load or are rejected with exit status 2 and a
one-line message — never a traceback, never a hang."""
from __future__ import annotations

import copy
import math
from pathlib import Path

import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tissuerender import SceneError, load_scene
from tissuerender.cli import main
from tests.conftest import MINIMAL_SCENE

SCENES = sorted((Path(__file__).resolve().parents[1] / "scenes").glob("*.toml"))
try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib

BASES = [copy.deepcopy(MINIMAL_SCENE)] + [tomllib.loads(p.read_text()) for p in SCENES]
SCALES = [0.0, -1.0, float("nan"), 1e30, -1e30, float("inf")]
REPLACEMENTS = ["x", 0, -1, 1.5, True, [], {}, [1, 2], {"a": 1}]


def _paths(node, prefix=()):
    """Every (container, key) pair inside a nested dict/list structure."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield node, k
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield node, i
            yield from _paths(v, prefix + (i,))


def _mutate(data, draw):
    sites = list(_paths(data))
    container, key = sites[draw(st.integers(0, len(sites) - 1))]
    op = draw(st.sampled_from(["drop", "duplicate", "retype", "rename", "scale"]))
    value = container[key]
    if op == "drop":
        del container[key]
    elif op == "duplicate":
        if isinstance(container, list):
            container.append(copy.deepcopy(value))
        else:
            container[f"{key}_copy"] = copy.deepcopy(value)
    elif op == "retype":
        container[key] = copy.deepcopy(draw(st.sampled_from(REPLACEMENTS)))  # never share (or nest) the list itself
    elif op == "rename" and isinstance(container, dict):
        container[str(key)[::-1] or "k"] = container.pop(key)
    elif op == "scale":
        factor = draw(st.sampled_from(SCALES))
        if isinstance(value, bool):
            container[key] = not value
        elif isinstance(value, (int, float)):
            scaled = value * factor if not (value == 0 and math.isinf(factor)) else factor
            container[key] = int(scaled) if isinstance(value, int) and math.isfinite(scaled) and abs(scaled) < 2**62 else scaled
        elif isinstance(value, list) and value and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            container[key] = [v * factor for v in value]
    return data


@st.composite
def mutated_scenes(draw):
    data = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 3))):
        if not data:
            break
        data = _mutate(data, draw)
    return data


@settings(max_examples=400, deadline=None, database=None,  # no replay of stale examples across schema changes
          suppress_health_check=[HealthCheck.function_scoped_fixture,
                                 HealthCheck.too_slow])
@given(data=mutated_scenes())
def test_mutated_scene_loads_or_fails_with_status_2(data, tmp_path_factory, capsys):
    path = tmp_path_factory.mktemp("fuzz") / "mutant.toml"
    try:
        path.write_text(tomli_w.dumps(data))
    except (TypeError, ValueError):
        return  # not representable as TOML (e.g. an empty key path); nothing to load
    status = main(["validate", str(path)])
    err = capsys.readouterr().err
    if status == 0:
        load_scene(path)  # really loads
    else:
        assert status == 2
        assert err.startswith("error: ") and str(path) in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1
        try:
            load_scene(path)
        except SceneError:
            pass
