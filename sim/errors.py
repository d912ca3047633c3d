"""Errors that reach users: each names the file (or source), the element and what was wrong.

The CLI turns these into a one-line message and exit status 2, never a traceback.
"""


class MeshError(ValueError):
    """A mesh file or procedural mesh request that cannot be used (missing, malformed, broken)."""


class SimulationDiverged(RuntimeError):
    """Raised when an integrator's state becomes non-finite or unbounded."""
