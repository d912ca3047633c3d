"""No compiled kernel uses ``fastmath``, not even "contract" (docs/xpbd.md, "Determinism"): with fused
multiply-adds allowed, a process that compiled the XPBD kernels stepped the contact benchmark's model to other
positions than a process that loaded the same kernels from numba's cache, so the same scene and seed gave
different results on a fresh machine and on a warm one. The check is on the source: any ``fastmath`` option
given to ``njit``/``jit``/``overload`` in the packages fails it, with the file and line."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("sim", "tissuerender", "materials", "postfx", "scenes")
OPTION = re.compile(r"""fastmath\s*=|["']fastmath["']\s*:""")


def fastmath_options() -> list[str]:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                if OPTION.search(code):
                    found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    return found


def test_the_scan_finds_a_fastmath_option(tmp_path):
    assert OPTION.search('@njit(cache=True, fastmath={"contract"})')
    assert OPTION.search('jit_options={"error_model": "numpy", "fastmath": {"contract"}}')
    assert not OPTION.search('"""No fastmath (docs/xpbd.md)."""')


def test_no_kernel_uses_fastmath():
    assert fastmath_options() == []
