"""User-facing errors. The CLI prints their message on one line and exits with status 2."""
from __future__ import annotations


class UserError(Exception):
    """A mistake in what the user gave us (a scene, a path, an option): never a traceback."""


class SceneError(UserError):
    """A scene file that cannot be used; the message names the file, the key path, what was expected
    and what was found."""

    def __init__(self, path, key: str | None, message: str):
        self.path = str(path)
        self.key = key
        where = f"{self.path}: {key}: " if key else f"{self.path}: "
        super().__init__(where + message)
