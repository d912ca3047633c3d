"""Errors shared by the post-effect chain and its GL backend."""
from __future__ import annotations


class OSMesaUnavailable(RuntimeError):
    """The off-screen OpenGL backend cannot run here (message names what to install)."""
