"""Atomic output folders: everything is written into a hidden sibling, then renamed into place.

A failure at any point leaves the target as it was (absent, or the old folder under
``--overwrite``), removes the partial folder and any parent folder made for it.

The target is resolved (symbolic links, ``..``) before anything is written, and a target whose
replacement would destroy data is refused whatever ``--overwrite`` says: ``/``, the home folder
or one of its parents, the current folder or one of its parents, and a folder that is or
contains an input. The temporary names are short (``.s2t-XXXXXXXX.part``) so any legal output
name can be used.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from scan2terrain.errors import OutputError

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


def _is_url(path: Path | str) -> bool:
    return "://" in str(path)


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
        if _is_url(source):
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
            self.tmp = Path(tempfile.mkdtemp(prefix=TMP_PREFIX, suffix=".part", dir=parent))
        except OSError as exc:
            self._remove_made()
            raise OutputError(
                f"{self.target}: cannot create the output folder ({exc.strerror or exc})"
            ) from None
        self.files: list[Path] = []

    @staticmethod
    def check_target(target: Path, overwrite: bool, inputs: Iterable[Path | str] = ()) -> Path:
        """Refuse an existing target without ``overwrite``, anything that is not a folder, and
        every target :func:`check_path` refuses; return the resolved target."""
        real = check_path(target, inputs, what="output folder")
        if real.exists() and not real.is_dir():
            raise OutputError(f"{target}: exists and is not a folder")
        if real.exists() and not overwrite:
            raise OutputError(f"{target}: output folder exists (use --overwrite to replace it)")
        return real

    def write(self, relative: str, data: bytes) -> Path:
        path = self.tmp / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        self.files.append(Path(relative))
        return self.target / relative

    def commit(self) -> None:
        """Rename the temporary folder to the target (the old one, under ``overwrite``, is
        renamed aside first and removed last). Raises :class:`OutputError`; the caller
        (:func:`atomic_output`) then discards the temporary folder."""
        old = None
        try:
            self.tmp.chmod(0o755)  # mkdtemp makes it 0700
            if self.real.exists():
                if not self.overwrite:  # appeared while we worked
                    raise OutputError(
                        f"{self.target}: output folder exists (use --overwrite to replace it)"
                    )
                old = self.real.with_name(f"{TMP_PREFIX}{secrets.token_hex(4)}.old")
                self.real.rename(old)
            try:
                self.tmp.rename(self.real)
            except OSError:
                if old is not None:
                    old.rename(self.real)
                    old = None
                raise
        except OutputError:
            raise
        except OSError as exc:
            raise OutputError(
                f"{self.target}: cannot write the output folder ({exc.strerror or exc})"
            ) from None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
        self._remove_made()

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
