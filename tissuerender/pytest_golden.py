"""pytest plugin: golden-image checks from tests (``pytest_plugins = ["tissuerender.pytest_golden"]``).

The ``golden`` fixture checks one image of a golden folder and fails the test with the metrics::

    def test_my_scene(golden):
        golden("tests/golden", "default")
"""
from __future__ import annotations

import pytest

from tissuerender import golden as golden_images


@pytest.fixture
def golden():
    def check(directory, name: str):
        results = golden_images.check(directory, only=name)
        if not results:
            pytest.fail(f"{directory}: no image named {name!r} in manifest.toml")
        result = results[0]
        if not result.passed:
            pytest.fail(f"golden image {name!r} differs: {result.message} (see {directory}/failures/)")
        return result

    return check
