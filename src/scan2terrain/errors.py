"""One root error for the project, one subclass per kind of fault: the input, the config, the
output.

The CLI catches :class:`Scan2TerrainError` only, prints its message as one line and exits 2.
Errors about files also inherit the matching builtin, as rasterio does, so callers that catch
``OSError`` or ``ValueError`` keep working.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


class Scan2TerrainError(Exception):
    """Root of every error scan2terrain raises on purpose."""


class InputError(Scan2TerrainError, ValueError):
    """An input file or value is unusable. The message names the file and the problem."""

    def __init__(self, path: Path | str | None, problem: str) -> None:
        # A URL stays a string: Path would fold its '//'.
        self.path: Path | str | None = (
            path if path is None or (isinstance(path, str) and "://" in path) else Path(path)
        )
        self.problem = problem
        super().__init__(f"{path}: {problem}" if path is not None else problem)

    def __reduce__(self) -> tuple[type[InputError], tuple[Path | str | None, str]]:
        # Pickled with its two arguments, so it crosses to and from Dask workers intact.
        return (type(self), (self.path, self.problem))


@contextmanager
def about(path: Path | str, context: str = "") -> Iterator[None]:
    """An :class:`InputError` raised inside, by a stage that does not know the file (the octree,
    a batch of points), re-raised naming ``path`` (and ``context``: where in the file)."""
    try:
        yield
    except InputError as exc:
        raise InputError(path, f"{context}{exc.problem}") from exc


def shown(text: str) -> str:
    """``text`` read from a file (a topic, a frame, a type name) as a message shows it: each
    character that is not printable escaped as Python writes it (``\\n``, ``\\x1d``), so the
    message stays one line and says exactly what the file holds."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class ConfigError(Scan2TerrainError, ValueError):
    """A configuration value is out of range or unknown."""


class OutputError(Scan2TerrainError, OSError):
    """An output cannot be written (exists without --overwrite, not writable)."""


class FidelityWarning(UserWarning):
    """A world replays its recording badly: fewer than half the beams land within 10 cm."""
