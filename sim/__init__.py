"""Tetrahedral soft-tissue simulation (docs/design.md). Importing the package installs the faster IR copy of numba's
inliner (``sim.numba_inline``: compile time only, the compiled code is the same)."""
from sim import numba_inline  # noqa: F401
