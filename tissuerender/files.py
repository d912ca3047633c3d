"""Output files written atomically: a temporary file in the target's folder, then ``os.replace`` onto the
target, so a reader (or a render interrupted mid-write) never sees a partial file.

A temporary is named ``.<stem>.<8 random characters>.tmp<suffix>`` (hidden, never an output's name). An
exception (Ctrl-C, SIGTERM) removes it; a process killed outright (SIGKILL, power loss) can leave one
behind, which the next render into the folder removes (``remove_temporaries``).
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import re
import secrets
import string
from pathlib import Path

import numpy as np
from PIL import Image

from tissuerender.errors import UserError


def output_folder(path) -> Path:
    """``path`` as an existing, writable folder (created with its parents if missing); a user error naming
    the path when it is a file, cannot be created, or cannot be written to."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserError(f"{path}: the output folder names an existing file; expected a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{path}: cannot create the output folder: {e.strerror or e}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"{path}: the output folder is not writable")
    return path


@contextlib.contextmanager
def one_writer(folder: Path):
    """While the block runs, this process is the only tissuerender writing into ``folder`` (an exclusive
    ``flock`` on the folder itself: nothing is added to it, and the system drops the lock however the process
    ends, SIGKILL included). Another render into the same folder would delete this one's temporaries
    (``remove_temporaries``) and interleave manifests: it gets a :class:`UserError` instead."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:  # a folder one may write to but not read (mode -wx): written unguarded, as before
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"{folder}: another tissuerender process is writing into this folder; wait for it to "
                            "finish or choose another output folder") from None
        except OSError:  # a file system without locks (ENOLCK, EOPNOTSUPP: some network mounts): unguarded
            pass
        yield
    finally:
        os.close(fd)  # releases the lock


# ``write_atomic``'s temporary names: 8 random characters of [a-z0-9_]
TEMPORARY_NAME = re.compile(r"^\..+\.[a-z0-9_]{8}\.tmp(\.[^.]+)?$")


def remove_temporaries(folder: Path) -> list[Path]:
    """Delete the temporaries a killed writer left in ``folder`` and its subfolders (``passes/``); returns
    them. Only one render writes into a folder at a time (``one_writer``): what it finds is a killed writer's
    or its own."""
    stale = sorted(p for p in Path(folder).rglob(".*.tmp*") if TEMPORARY_NAME.match(p.name) and p.is_file())
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


_TEMPORARY_CHARACTERS = string.ascii_lowercase + string.digits + "_"


def _create_temporary(path: Path) -> str:
    """A new, empty temporary beside ``path`` (``TEMPORARY_NAME``), created exclusively with the mode a plain
    ``open()`` gives (0o666 less the umask): ``tempfile.mkstemp`` makes it 0o600, which the rename would carry
    onto every output, unreadable to anyone else sharing a results folder."""
    for _ in range(100):
        name = "".join(secrets.choice(_TEMPORARY_CHARACTERS) for _ in range(8))
        tmp = path.parent / f".{path.stem}.{name}.tmp{path.suffix}"
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        return str(tmp)
    raise FileExistsError(f"{path.parent}: no free temporary name for {path.name}")


# what the machine, not the program, refuses: a full disk or quota, a read-only or vanished folder, no permission
_OUTPUT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG,
                  errno.ENOENT}


class OutputError(UserError):
    """An output file the machine would not let us write (``_OUTPUT_ERRNOS``): its path and the system's reason.
    Nothing partial is left: the temporary is removed, the files finished before stay."""


def write_atomic(path: Path, write) -> None:
    """Call ``write(tmp_path)`` then rename onto ``path``. The temporary name keeps ``path``'s suffix, so
    writers that choose the format by suffix (meshio) write the right one. A new file gets the mode a plain
    ``open()`` would give it; a replaced one keeps its own. A full disk, a read-only folder and the like raise
    :class:`OutputError` naming ``path``."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _create_temporary(path)
        write(tmp)
        try:
            os.chmod(tmp, os.stat(path).st_mode & 0o7777)
        except FileNotFoundError:
            pass
        os.replace(tmp, path)
    except BaseException as e:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.errno in _OUTPUT_ERRNOS:
            raise OutputError(f"{path}: cannot write: {e.strerror or e}") from None
        raise


def refuse_non_finite(path: Path, array: np.ndarray) -> None:
    """The writers' last line of defence (``tissuerender.finite`` catches NaN where it arises): no file
    holding a NaN or inf is ever written."""
    array = np.asarray(array)
    if np.issubdtype(array.dtype, np.floating) and not np.isfinite(array).all():
        raise ValueError(f"{path}: refusing to write {int((~np.isfinite(array)).sum())} non-finite values")


def write_png(path: Path, rgb: np.ndarray) -> None:
    """An 8-bit RGB image (H, W, 3) as PNG."""
    refuse_non_finite(path, rgb)
    write_atomic(path, lambda tmp: Image.fromarray(rgb).save(tmp, format="PNG"))


def write_json(path: Path, data: dict) -> None:
    write_atomic(path, lambda tmp: Path(tmp).write_text(json.dumps(data, indent=2, sort_keys=False) + "\n"))


def write_npy(path: Path, array: np.ndarray) -> None:
    refuse_non_finite(path, array)
    def write(tmp):
        with open(tmp, "wb") as f:
            np.save(f, array)

    write_atomic(path, write)
