"""What every reader checks before it opens a file, and how it tells a library's failure from
its own.

:func:`regular_file` refuses anything that is not a regular file *before* it is opened: opening a
named pipe (FIFO) for reading waits for a writer forever, ``/dev/zero`` reads until memory runs
out, a folder or a socket cannot be read at all. Links are followed (a link to a regular file is
fine, one to a device is not); a missing file, a link loop, a name too long or holding a NUL byte
are one :class:`~scan2terrain.errors.InputError` each, like the rest. The size it returns is what
the readers check their budgets against.

:func:`raised_in` says whether an exception came out of a library's code (tifffile, Pillow,
...) rather than ours: a decoder fed a corrupt file raises whatever its code happens to hit
(``TypeError``, ``IndexError``, ``zlib.error``, ``NotImplementedError``), and a reader turns
exactly those into an InputError at its boundary, while a bug of ours still ends the run as one.
"""

from __future__ import annotations

import stat
from collections.abc import Iterable
from pathlib import Path

from scan2terrain.errors import InputError

#: How ``stat`` names what is not a regular file.
_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(mode: int) -> str | None:
    """What a ``st_mode`` is when it is not a regular file ("a folder", "a named pipe (FIFO)",
    ...), or None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def regular_file(path: Path | str, what: str, *, missing: str | None = None) -> int:
    """Refuse ``path`` unless it is (a link to) a regular file; return its size in bytes.

    Parameters
    ----------
    path : Path or str
        The input, as the user named it (the error names it so).
    what : str
        What the reader expects, for messages: ``"DEM file"`` gives "DEM file not found" and
        "is a named pipe (FIFO): cannot read it as a DEM file" (``"image file"``: "as an
        image file").
    missing : str, optional
        The message for a file that does not exist (default ``f"{what} not found"``).

    Raises
    ------
    InputError
        Missing; not a regular file (a folder, FIFO, device or socket); or a path the system
        cannot look up (a link loop, a name too long, a NUL byte, no permission).
    """
    try:
        st = Path(path).stat()
    except FileNotFoundError:
        raise InputError(path, missing or f"{what} not found") from None
    except OSError as exc:  # ELOOP, ENAMETOOLONG, ENOTDIR, EACCES
        raise InputError(path, f"cannot open the {what} ({exc.strerror or exc})") from exc
    except ValueError:  # os.stat refuses a NUL byte in a path
        raise InputError(path, f"the {what}'s name holds a NUL byte") from None
    kind = file_kind(st.st_mode)
    if kind is not None:
        article = "an" if what[:1].lower() in "aeio" else "a"
        raise InputError(path, f"is {kind}: cannot read it as {article} {what}")
    return st.st_size


def raised_in(exc: BaseException, packages: Iterable[str]) -> bool:
    """Whether ``exc`` was raised while code of one of the top-level ``packages`` (e.g.
    ``("tifffile", "imagecodecs")``) was running: some frame of its traceback is theirs."""
    wanted = set(packages)
    tb = exc.__traceback__
    while tb is not None:
        module = tb.tb_frame.f_globals.get("__name__", "")
        if isinstance(module, str) and module.partition(".")[0] in wanted:
            return True
        tb = tb.tb_next
    return False
