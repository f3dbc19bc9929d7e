"""Writing one file atomically (a temporary name in the same folder, then a rename), and the
locks that tell a live run's hidden temporaries from a killed run's (:func:`sweep`).

Shared by every stage that writes a single file (``.bt`` octrees, point clouds); whole output
folders use :class:`scan2terrain.exporters.output.OutputDir`.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from scan2terrain.errors import OutputError

try:
    import fcntl
except ImportError:  # not POSIX: no locks (every lock below is then a no-op)
    fcntl = None  # type: ignore[assignment]

#: Prefix of the hidden temporary names beside an output (kept short: NAME_MAX is 255 bytes).
TMP_PREFIX = ".s2t-"
_NAME_MAX = 255


def real_path(path: Path) -> Path:
    """``path`` absolute, with symbolic links and ``..`` resolved (missing parts kept as given)."""
    return Path(os.path.realpath(Path(path)))


def _cwd() -> Path | None:
    try:
        return real_path(Path.cwd())
    except OSError:  # the working folder was removed
        return None


def _home() -> Path | None:
    try:
        return real_path(Path.home())
    except (OSError, RuntimeError, KeyError):  # no HOME and no passwd entry
        return None


def is_url(name: Path | str) -> bool:
    """``scheme://...`` (http, https, s3, file, ...), as opposed to a local path."""
    return re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", str(name)) is not None


def url_path(name: Path | str) -> Path:
    """A path, or a URL as a path (its query and fragment dropped), for names and suffixes."""
    return Path(re.split(r"[?#]", str(name), maxsplit=1)[0] if is_url(name) else name)


def check_path(target: Path, inputs: Iterable[Path | str] = (), *, what: str = "output") -> Path:
    """Checks shared by output folders and output files; returns the resolved target.

    Refuses (:class:`OutputError`, one line naming ``target``) a broken symbolic link, a
    target that is ``/``, the home or current folder or one of their parents, one that is or
    contains an input, a name too long for the file system, and a target whose nearest
    existing parent is not a writable folder.
    """
    target = Path(target)
    real = real_path(target)
    if len(os.fsencode(real.name)) > _NAME_MAX:
        raise OutputError(f"{target}: name too long (more than {_NAME_MAX} bytes)")
    if target.is_symlink() and not target.exists():
        raise OutputError(
            f"{target}: is a broken symbolic link (to {target.readlink()}); "
            f"remove it or name another {what}"
        )
    if real.parent == real:
        raise OutputError(f"{target}: is the root folder; name a new {what}")
    for name, place in (("current", _cwd()), ("home", _home())):
        if place is not None and (real == place or real in place.parents):
            which = "is" if real == place else "contains"
            raise OutputError(f"{target}: {which} the {name} folder; name a new {what}")
    for source in inputs:
        if is_url(source):
            continue
        src = real_path(Path(source))
        if real == src or real in src.parents:
            which = "is" if real == src else "contains"
            raise OutputError(f"{target}: {which} the input {source}; name another {what}")
    ancestor = real.parent
    while not ancestor.exists() and not ancestor.is_symlink():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"{target}: {ancestor} is not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputError(f"{target}: cannot write in {ancestor} (permission denied)")
    return real


def check_file_target(path: Path, overwrite: bool, inputs: Iterable[Path | str] = ()) -> Path:
    """Refuse (:class:`OutputError`, one line) an output file that cannot or must not be written:
    what :func:`check_path` refuses, a folder, an existing
    file without ``overwrite``, or a missing parent folder. Returns the resolved path."""
    path = Path(path)
    real = check_path(path, inputs, what="output file")
    if real.is_dir():
        raise OutputError(f"{path}: is a folder, not a file")
    if real.exists() and not overwrite:
        raise OutputError(f"{path}: exists (use --overwrite to replace it)")
    if not real.parent.is_dir():
        raise OutputError(f"{path}: folder {real.parent} does not exist")
    return real


def atomic_write(path: Path, data: bytes | bytearray) -> None:
    """Write ``data`` to a temporary file beside ``path`` (mode 0644), then rename it into place.

    A symbolic link is written through (its target is replaced, the link stays). On any
    failure the temporary file is removed and ``path`` is untouched; an ``OSError`` comes back
    as :class:`OutputError` (still an ``OSError``) naming ``path``.
    """
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
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from exc
        raise


def _flock(fd: int) -> None:
    if fcntl is None:
        return
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


# --- locks: telling a live run's temporaries from a killed run's ------------------------------


def try_lock(folder: Path) -> int | None:
    """An open descriptor holding an exclusive flock on ``folder`` (or a file); None if another
    process holds it (or locks are not available)."""
    if fcntl is None:
        return None
    try:
        fd = os.open(folder, os.O_RDONLY | (os.O_DIRECTORY if folder.is_dir() else 0))
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


@contextlib.contextmanager
def locked(parent: Path) -> Iterator[None]:
    """A blocking exclusive flock on ``parent`` (a folder), for the sweep and the creation of
    a temporary folder: milliseconds."""
    if fcntl is None:
        yield
        return
    fd = os.open(parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def sweep(parent: Path) -> None:
    """Remove hidden temporary folders and files in ``parent`` that no live run holds. Called with
    ``parent`` locked, so a folder another run is creating is already locked by it."""
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return
    for entry in entries:
        name = entry.name
        if not (name.startswith(TMP_PREFIX) and name.endswith((".part", ".old"))):
            continue
        is_dir = entry.is_dir(follow_symlinks=False)
        if not (is_dir or entry.is_file(follow_symlinks=False)):
            continue
        path = parent / name
        held = try_lock(path)
        if held is None:
            continue
        try:
            if name.endswith(".part") and is_dir:
                shutil.rmtree(path, ignore_errors=True)
            elif name.endswith(".part"):  # a single file's (fileio.atomic_write)
                path.unlink(missing_ok=True)
            # An aside (.old) is its target's: _restore puts it back, or the target's next
            # successful run replaces it.
        finally:
            os.close(held)
