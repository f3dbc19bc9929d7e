"""Writing one file atomically: a temporary name in the same folder, then a rename.

Shared by every stage that writes a single file (``.bt`` octrees, point clouds); whole output
folders use :class:`scan2terrain.exporters.output.OutputDir`.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from scan2terrain.errors import OutputError


def check_file_target(path: Path, overwrite: bool, inputs: Iterable[Path | str] = ()) -> Path:
    """Refuse (:class:`OutputError`, one line) an output file that cannot or must not be written:
    what :func:`~scan2terrain.exporters.output.check_path` refuses, a folder, an existing
    file without ``overwrite``, or a missing parent folder. Returns the resolved path."""
    from scan2terrain.exporters.output import check_path

    path = Path(path)
    real = check_path(path, inputs, what="output file")
    if real.is_dir():
        raise OutputError(f"{path}: is a folder, not a file")
    if real.exists() and not overwrite:
        raise OutputError(f"{path}: exists (use --overwrite to replace it)")
    if not real.parent.is_dir():
        raise OutputError(f"{path}: folder {real.parent} does not exist")
    return real


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path`` (mode 0644), then rename it into place.

    A symbolic link is written through (its target is replaced, the link stays). On any
    failure the temporary file is removed and ``path`` is untouched; an ``OSError`` comes back
    as :class:`OutputError` (still an ``OSError``) naming ``path``.
    """
    from scan2terrain.exporters.output import TMP_PREFIX, locked, sweep

    path = Path(path)
    real = Path(os.path.realpath(path))
    tmp: str | None = None
    try:
        # A short temporary name: any legal name of ``path`` must stay writable. Locked while
        # this run lives, so the next run can tell a killed run's leftover (and removes it).
        with locked(real.parent):
            sweep(real.parent)
            fd, tmp = tempfile.mkstemp(prefix=TMP_PREFIX, suffix=".part", dir=real.parent)
            _flock(fd)
        with os.fdopen(fd, "wb") as out:
            out.write(data)
            out.flush()
            Path(tmp).chmod(0o644)  # mkstemp makes it 0600
            Path(tmp).replace(real)
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                Path(tmp).unlink()
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None
        raise


def _flock(fd: int) -> None:
    try:
        import fcntl
    except ImportError:  # not POSIX
        return
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
