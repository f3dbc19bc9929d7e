"""Atomic output folders: everything is written into a hidden sibling, then renamed into place.

A failure at any point leaves the target as it was (absent, or the old folder under
``--overwrite``) and removes the partial folder.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from scan2terrain.errors import OutputError


class OutputDir:
    """Collects files under a temporary folder; :meth:`commit` moves it to ``target``."""

    def __init__(self, target: Path, *, overwrite: bool = False) -> None:
        self.target = Path(target)
        self.check_target(self.target, overwrite)
        parent = self.target.absolute().parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
            self.tmp = Path(
                tempfile.mkdtemp(prefix=f".{self.target.name}.", suffix=".part", dir=parent)
            )
        except OSError as exc:
            raise OutputError(
                f"{parent}: cannot create the output folder ({exc.strerror})"
            ) from None
        self.files: list[Path] = []

    @staticmethod
    def check_target(target: Path, overwrite: bool) -> None:
        """Refuse an existing target without ``overwrite``, and anything that is not a folder."""
        if target.exists() and not target.is_dir():
            raise OutputError(f"{target}: exists and is not a folder")
        if target.exists() and not overwrite:
            raise OutputError(f"{target}: output folder exists (use --overwrite to replace it)")

    def write(self, relative: str, data: bytes) -> Path:
        path = self.tmp / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        self.files.append(Path(relative))
        return self.target / relative

    def commit(self) -> None:
        self.tmp.chmod(0o755)  # mkdtemp makes it 0700
        old = None
        if self.target.exists():
            old = self.target.with_name(f".{self.target.name}.old")
            if old.exists():
                shutil.rmtree(old)
            self.target.rename(old)
        try:
            self.tmp.rename(self.target)
        except OSError:
            if old is not None:
                old.rename(self.target)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def discard(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


@contextlib.contextmanager
def atomic_output(target: Path, *, overwrite: bool = False) -> Iterator[OutputDir]:
    out = OutputDir(target, overwrite=overwrite)
    try:
        yield out
    except BaseException:
        out.discard()
        raise
    out.commit()
