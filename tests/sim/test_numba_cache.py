"""sim.numba_cache: a cached kernel is recompiled when a project file it imports changes, not only its own file."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from sim import numba_cache


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text))


def test_dependencies_follow_project_imports_only(tmp_path):
    _write(tmp_path / "sim" / "__init__.py", "")
    _write(tmp_path / "sim" / "a.py", "import numpy as np\n")
    _write(tmp_path / "sim" / "pkg" / "__init__.py", "")
    _write(tmp_path / "sim" / "pkg" / "d.py", "from sim.a import np\n")
    _write(tmp_path / "sim" / "b.py", """\
        import os
        from numba import njit
        from sim.pkg import (
            d,
        )
        """)
    _write(tmp_path / "sim" / "lone.py", "import numpy\n")
    deps = [Path(p).relative_to(tmp_path).as_posix() for p in numba_cache.dependencies(tmp_path / "sim" / "b.py",
                                                                                        tmp_path)]
    # itself first; the package and its submodule from the multi-line "from ... import (...)"; d's own import
    assert deps == ["sim/b.py", "sim/a.py", "sim/pkg/__init__.py", "sim/pkg/d.py"]
    before_b = numba_cache.source_stamp(tmp_path / "sim" / "b.py", tmp_path)
    before_lone = numba_cache.source_stamp(tmp_path / "sim" / "lone.py", tmp_path)
    _write(tmp_path / "sim" / "a.py", "import numpy as np  # changed\n")
    assert numba_cache.source_stamp(tmp_path / "sim" / "b.py", tmp_path) != before_b  # a dependency changed
    assert numba_cache.source_stamp(tmp_path / "sim" / "lone.py", tmp_path) == before_lone  # unrelated


_RUN = """\
import sys
sys.path.insert(0, {tmp!r})
if {ours!r}:
    from sim import numba_cache
    numba_cache.ROOT = __import__("pathlib").Path({tmp!r})
    numba_cache.PACKAGES = (*numba_cache.PACKAGES, "depdemo")
from depdemo.caller import g
print(g())
"""


def _run(tmp: Path, ours: bool, cache: Path) -> str:
    out = subprocess.run([sys.executable, "-c", _RUN.format(tmp=str(tmp), ours=ours)], capture_output=True,
                         text=True, check=True,
                         # no .pyc: one written in the same second as an edit of the same size (1 -> 2) would be
                         # taken for the edited source (its stamp is the source's mtime in whole seconds and size)
                         env={"NUMBA_CACHE_DIR": str(cache), "PATH": "/usr/bin:/bin", "PYTHONDONTWRITEBYTECODE": "1"})
    return out.stdout.strip()


def test_a_changed_callee_in_another_file_recompiles_its_cached_caller(tmp_path):
    for ours in (False, True):  # numba's own stamp (the stale result this fixes), then ours
        root = tmp_path / ("ours" if ours else "stock")
        _write(root / "depdemo" / "__init__.py", "")
        _write(root / "depdemo" / "callee.py", "from numba import njit\n\n@njit\ndef f():\n    return 1\n")
        _write(root / "depdemo" / "caller.py", """\
            from numba import njit
            from depdemo.callee import f

            @njit(cache=True)
            def g():
                return f()
            """)
        cache = root / "cache"
        assert _run(root, ours, cache) == "1"
        _write(root / "depdemo" / "callee.py", "from numba import njit\n\n@njit\ndef f():\n    return 2\n")
        assert _run(root, ours, cache) == ("2" if ours else "1")
