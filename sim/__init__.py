"""Tetrahedral soft-tissue simulation (docs/design.md). Importing the package sets up numba for the kernels of every
package of the project: a cached kernel is recompiled when a file it imports changes (``sim.numba_cache``), and the
inliner copies IR faster (``sim.numba_inline``: compile time only, the compiled code is the same)."""
from sim import numba_cache, numba_inline  # noqa: F401
