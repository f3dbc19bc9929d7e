"""Atomic output folders: everything is written into a hidden sibling, then renamed into place.

At every instant the target is either the old folder or the new one, whatever kills the process:
on Linux the new folder is swapped in with one ``renameat2(RENAME_EXCHANGE)`` (the old one is
then in the hidden sibling, removed last), and a new target appears with
``renameat2(RENAME_NOREPLACE)``, so two runs on one target without ``--overwrite`` cannot both
succeed. Where the file system has no such rename, the old folder is first renamed aside under a
name derived from the target's (``.s2t-<digest>.old``), and the next run for that target puts it
back if the target is missing.

Every run holds an exclusive ``flock`` on its hidden folder while it lives; the next run in that
parent folder removes hidden folders nobody holds (left by killed runs), under a short lock on
the parent so a folder being created is never taken for a leftover. A failure at any point
leaves the target as it was (absent, or the old folder under ``--overwrite``), removes the
partial folder and any parent folder made for it; an ``OSError`` (full disk, permissions) is one
line, exit 2.

The target is resolved (symbolic links, ``..``) before anything is written, and a target whose
replacement would destroy data is refused whatever ``--overwrite`` says: ``/``, the home folder
or one of its parents, the current folder or one of its parents, and a folder that is or
contains an input. The temporary names are short (``.s2t-XXXXXXXX.part``) so any legal output
name can be used.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from scan2terrain.errors import OutputError
from scan2terrain.fileio import TMP_PREFIX, check_path, locked, sweep, try_lock

#: The file every output folder holds (the effective config): what marks a folder as ours.
MARKER = "scan2terrain.yaml"


class OutputDir:
    """Collects files under a temporary folder; :meth:`commit` moves it to ``target``.

    Paths returned by :meth:`write` are under ``target`` as given; the files themselves go
    to the resolved target (through symbolic links).
    """

    def __init__(
        self, target: Path, *, overwrite: bool = False, inputs: Iterable[Path | str] = ()
    ) -> None:
        self.target = Path(target)
        self.overwrite = overwrite
        self.real = self.check_target(self.target, overwrite, inputs)
        self.made: list[Path] = []  # parent folders made for the output, outermost first
        self._lock: int | None = None
        parent = self.real.parent
        try:
            missing = []
            p = parent
            while not p.exists():
                missing.append(p)
                p = p.parent
            for d in reversed(missing):
                d.mkdir()
                self.made.append(d)
            with locked(parent):
                sweep(parent)
                self.tmp = Path(tempfile.mkdtemp(prefix=TMP_PREFIX, suffix=".part", dir=parent))
                self._lock = try_lock(self.tmp)
        except OSError as exc:
            self._remove_made()
            raise OutputError(
                f"{self.target}: cannot create the output folder ({exc.strerror or exc})"
            ) from exc
        self.files: list[Path] = []

    @staticmethod
    def check_target(target: Path, overwrite: bool, inputs: Iterable[Path | str] = ()) -> Path:
        """Refuse an existing target without ``overwrite``, anything that is not a folder, and
        every target :func:`check_path` refuses; return the resolved target. A target that a
        killed ``--overwrite`` run left renamed aside is put back first."""
        real = check_path(target, inputs, what="output folder")
        _restore(real)
        if real.exists() and not real.is_dir():
            raise OutputError(f"{target}: exists and is not a folder")
        if real.exists() and not overwrite:
            raise OutputError(f"{target}: output folder exists (use --overwrite to replace it)")
        if real.exists():
            refuse_foreign(target, real)
        return real

    def write(self, relative: str, data: bytes) -> Path:
        path = self.tmp / relative
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        except OSError as exc:
            raise OutputError(
                f"{self.target}: cannot write {relative} ({exc.strerror or exc})"
            ) from exc
        self.files.append(Path(relative))
        return self.target / relative

    def commit(self) -> None:
        """Put the temporary folder at the target: a new target appears at once, an old one
        (under ``overwrite``) is exchanged with the new one in one step and removed last.
        Raises :class:`OutputError`; the caller (:func:`atomic_output`) then discards the
        temporary folder (which holds the old folder after an exchange, or the new one)."""
        try:
            self.tmp.chmod(0o755)  # mkdtemp makes it 0700
            if not _rename(self.tmp, self.real, _RENAME_NOREPLACE):
                if not self.overwrite:  # appeared while we worked
                    raise OutputError(
                        f"{self.target}: output folder exists (use --overwrite to replace it)"
                    )
                if not self.real.is_dir() or self.real.is_symlink():
                    raise OutputError(f"{self.target}: exists and is not a folder")
                refuse_foreign(self.target, self.real)  # it may have changed while we worked
                if not _rename(self.tmp, self.real, _RENAME_EXCHANGE):
                    self._replace_aside()
        except OutputError:
            raise
        except OSError as exc:
            raise OutputError(
                f"{self.target}: cannot write the output folder ({exc.strerror or exc})"
            ) from exc
        # After an exchange the old folder is at self.tmp; discard() removes it.

    def _replace_aside(self) -> None:
        """Without an atomic exchange: the old folder goes aside (locked, under the name
        :func:`_restore` looks for), the new one in, then the old one is removed."""
        aside = _aside(self.real)
        held = try_lock(self.real)
        try:
            self.real.rename(aside)
            try:
                self.tmp.rename(self.real)
            except OSError:
                aside.rename(self.real)
                raise
            shutil.rmtree(aside, ignore_errors=True)
        finally:
            if held is not None:
                os.close(held)

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
        self._remove_made()
        self.release()

    def release(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None

    def _remove_made(self) -> None:
        for d in reversed(self.made):
            with contextlib.suppress(OSError):
                d.rmdir()  # only if still empty
        self.made = []


@contextlib.contextmanager
def atomic_output(
    target: Path, *, overwrite: bool = False, inputs: Iterable[Path | str] = ()
) -> Iterator[OutputDir]:
    out = OutputDir(target, overwrite=overwrite, inputs=inputs)
    try:
        yield out
        out.commit()
    except BaseException:
        out.discard()
        raise
    if out.tmp.exists():  # the old folder, after an exchange
        shutil.rmtree(out.tmp, ignore_errors=True)
    out.release()


def refuse_foreign(target: Path, real: Path) -> None:
    """Refuse to replace ``real`` unless it is empty or holds :data:`MARKER` (a folder this
    tool wrote), naming a few of the entries that would be lost."""
    try:
        names = sorted(p.name for p in real.iterdir())
    except OSError as exc:
        raise OutputError(f"{target}: cannot read the folder ({exc.strerror or exc})") from exc
    if not names or (real / MARKER).is_file():
        return
    shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    raise OutputError(
        f"{target}: exists and was not written by scan2terrain (no {MARKER}; it holds {shown}):"
        " --overwrite replaces only scan2terrain's own output folders; name a new folder, or"
        " move this one away first"
    )


# --- renames and locks ------------------------------------------------------------------------

_RENAME_NOREPLACE = 1
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _renameat2() -> Any:
    """glibc's ``renameat2`` (2.28+), or None."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


_RENAMEAT2 = _renameat2()


def _rename(src: Path, dst: Path, flags: int) -> bool:
    """``renameat2(src, dst, flags)``. False when ``dst`` exists (RENAME_NOREPLACE) or the
    system or file system cannot do it (then: RENAME_NOREPLACE falls back to a rename that
    fails on an existing folder with files; RENAME_EXCHANGE returns False). Raises OSError
    for other failures."""
    if _RENAMEAT2 is not None:
        if _RENAMEAT2(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) == 0:
            return True
        err = ctypes.get_errno()
        if flags == _RENAME_NOREPLACE and err == errno.EEXIST:
            return False
        if err not in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
            raise OSError(err, os.strerror(err), str(dst))
    if flags == _RENAME_EXCHANGE:
        return False
    if dst.exists() or dst.is_symlink():
        return False
    try:
        src.rename(dst)
    except OSError as exc:
        if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
            return False
        raise
    return True


def _aside(real: Path) -> Path:
    """Where an old target waits while it is replaced without an atomic exchange."""
    digest = hashlib.sha256(os.fsencode(real.name)).hexdigest()[:16]
    return real.with_name(f"{TMP_PREFIX}{digest}.old")


def _restore(real: Path) -> None:
    """Finish what a killed run left of a replacement without exchange, if nobody holds the
    aside folder: the target missing, put the old folder back; the new one in place, remove
    the old one."""
    aside = _aside(real)
    if not aside.is_dir() or aside.is_symlink():
        return
    held = try_lock(aside)
    if held is None:
        return
    try:
        if real.exists() or real.is_symlink():
            shutil.rmtree(aside, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                aside.rename(real)
    finally:
        os.close(held)
