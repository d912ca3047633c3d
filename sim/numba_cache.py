"""numba's on-disk cache, invalidated when any of our source files a kernel's module imports changes.

numba keys a cached kernel on its own source file only (``numba.core.caching``: the sha256 of that file). A kernel
that calls or inlines a jitted function of another file (``sim.integrators.ebm.blocked_step.step`` inlines
``sim.integrators.ebm.blocked``'s lane loops) then keeps running the old callee after that file has changed: stale
machine code, silently. :func:`install` puts a locator first in numba's list whose source stamp is the sha256 of the
kernel's file *and* of every file of this project it imports, directly or through other project modules (a callee of
another file has to be imported to be called). Same cache folders as numba's own (``__pycache__`` next to the
source, or ``NUMBA_CACHE_DIR``); only the stamp is wider. A kernel is then recompiled when its file or a file it
depends on changes, and not when an unrelated one does.

The imports are read from the source text (``import a.b``, ``from a.b import c``, ``from a import b`` with b a
module), and followed only into this project's packages (``PACKAGES``). Installed by ``sim/__init__.py`` before any
kernel is defined (numba picks a function's locator when ``@njit(cache=True)`` decorates it); ``tissuerender``
imports ``sim`` first, so its kernels and those of ``postfx`` and ``materials`` (which may not import ``sim``:
docs/design.md, "Architecture") get it in every run of the tool; ``postfx`` or ``materials`` imported without ``sim``
keep numba's own stamp (``postfx.pointwise`` calls jitted functions of other ``postfx`` files: import ``sim`` or
``tissuerender`` first; the test suite's conftest does).
"""
from __future__ import annotations

import functools
import hashlib
import os
import re
from pathlib import Path

from numba.core import caching

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim", "tissuerender", "materials", "postfx")
_IMPORT = re.compile(r"^[ \t]*(?:from[ \t]+([\w.]+)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)|import[ \t]+([\w.]+))", re.M)


def _module_file(name: str, root: Path) -> Path | None:
    parts = name.split(".")
    if parts[0] not in PACKAGES:
        return None
    base = root.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


@functools.lru_cache(maxsize=None)
def _direct_imports(path: str, mtime: float, size: int, root: str) -> tuple[str, ...]:
    """The project files ``path`` imports (mtime and size in the key: a changed file is read again)."""
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    found = []
    for module, names, plain in _IMPORT.findall(text):
        name = module or plain
        target = _module_file(name, Path(root))
        if target is not None:
            found.append(str(target))
        if module and names:  # "from package import submodule"
            for item in re.split(r"[\s,()]+", names):
                item = item.split(" as ")[0].strip()
                if item.isidentifier():
                    sub = _module_file(f"{module}.{item}", Path(root))
                    if sub is not None:
                        found.append(str(sub))
    return tuple(sorted(set(found)))


def dependencies(py_file: str | os.PathLike, root: Path | None = None) -> list[str]:
    """``py_file`` and every project file it imports, transitively (sorted, ``py_file`` first); ``root``: the
    project's folder (default ``ROOT``)."""
    root = ROOT if root is None else root
    start = str(Path(py_file).resolve())
    seen, todo = {start}, [start]
    while todo:
        path = todo.pop()
        st = os.stat(path)
        for dep in _direct_imports(path, st.st_mtime, st.st_size, str(root)):
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return [start] + sorted(seen - {start})


def source_stamp(py_file: str | os.PathLike, root: Path | None = None) -> bytes:
    """sha256 over the contents of :func:`dependencies` (each file's path and bytes)."""
    digest = hashlib.sha256()
    for path in dependencies(py_file, root):
        st = os.stat(path)
        digest.update(path.encode())
        digest.update(caching._hash_source_file(path, st.st_mtime, st.st_size))
    return digest.digest()


class _DependencyStampMixin:
    def get_source_stamp(self):
        return source_stamp(self._py_file)

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            inside = Path(py_file).resolve().is_relative_to(ROOT)
        except OSError:
            return None
        return super().from_function(py_func, py_file) if inside else None


# numba 0.59's names had a leading underscore
_USER = getattr(caching, "UserProvidedCacheLocator", None) or getattr(caching, "_UserProvidedCacheLocator")
_IN_TREE = getattr(caching, "InTreeCacheLocator", None) or getattr(caching, "_InTreeCacheLocator")


class UserDirLocator(_DependencyStampMixin, _USER):
    """``NUMBA_CACHE_DIR``'s folder, with the dependency stamp."""


class InTreeLocator(_DependencyStampMixin, _IN_TREE):
    """``__pycache__`` next to the source, with the dependency stamp."""


def install() -> bool:
    """Put the two locators first (once); returns whether they are in numba's list."""
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    classes = getattr(impl, "_locator_classes", None)
    if not hasattr(caching, "_hash_source_file") or not isinstance(classes, list):
        return False  # another numba: its own invalidation stays
    if InTreeLocator not in classes:
        classes[:0] = [UserDirLocator, InTreeLocator]
    return True


installed = install()
