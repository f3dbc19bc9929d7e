"""Command line: parse arguments, run the command through the Python API's one path
(``scan2terrain.api.run``: the config, the command, its Result), print its report, map errors to
exit codes.

Exit codes: 0 success, 1 unexpected failure, 2 bad input or usage (one line on stderr).
Heavy modules (numpy, Pillow, lxml) are imported only once a command runs, so ``--help`` is fast.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
import traceback
import warnings
from typing import Any

# The module, not its names: scan2terrain.api imports this package's modules, and either may
# be imported first.
from scan2terrain import api
from scan2terrain._malloc import give_back_freed_memory
from scan2terrain.cli.dispatch import COMMAND_DEFAULTS, COMMANDS, Progress, load, show_progress
from scan2terrain.cli.display import ProgressBar, TaskBar, report
from scan2terrain.cli.parser import build_parser
from scan2terrain.errors import InputError, Scan2TerrainError, shown

__all__ = ["COMMAND_DEFAULTS", "build_parser", "main", "report"]


def main(argv: list[str] | None = None) -> int:
    give_back_freed_memory()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2

    def show(message: Any, category: Any, *_: Any, **__: Any) -> None:
        print(f"scan2terrain: warning: {message}", file=sys.stderr)

    # Restored on return: main() is also called in-process (tests, scripts), and the hook
    # must not outlive the command.
    saved, warnings.showwarning = warnings.showwarning, show
    handlers = _stop_on_signals()
    try:
        code = _run(args)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except BrokenPipeError:
        # The reader of our stdout left (``scan2terrain inspect bag | head``): what it read is
        # what it asked for, and every output file is already in place.
        _drop_stdout()
        return 0
    except KeyboardInterrupt as exc:
        # Raised for Ctrl-C, and for SIGTERM / SIGHUP by _stop_on_signals: the output folder's
        # writer has removed its hidden .part folder on the way out (only a SIGKILL leaves
        # one, which the next run in that folder removes).
        name = exc.args[0] if exc.args and isinstance(exc.args[0], str) else "SIGINT"
        out = getattr(args, "out", None) or getattr(args, "target", None)
        what = f"{out} was not written or changed; " if out is not None else ""
        print(
            f"scan2terrain: interrupted ({name}): {what}nothing half-written is left",
            file=sys.stderr,
        )
        return 128 + int(getattr(signal, name, signal.SIGINT))
    except Exception as exc:
        if args.verbose:
            traceback.print_exc()
        if isinstance(exc, Scan2TerrainError):  # its config keys named as flags by api.run
            print(f"scan2terrain: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        print(
            f"scan2terrain: internal error: {type(exc).__name__}: {_one_line(exc)} "
            "(run with -v for the traceback, and please report it)",
            file=sys.stderr,
        )
        return 1
    finally:
        warnings.showwarning = saved
        _restore_signals(handlers)


def _stop_on_signals() -> dict[int, Any]:
    """Make SIGTERM (``kill``) and SIGHUP (a closed terminal) stop a run as Ctrl-C does, by a
    KeyboardInterrupt naming the signal, so outputs are cleaned up on the way out. Only from
    the main thread (signal handlers can be set nowhere else); returns the handlers replaced."""

    if threading.current_thread() is not threading.main_thread():
        return {}

    def stop(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)

    saved: dict[int, Any] = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) == signal.SIG_IGN:  # nohup: the user asked to run on
            continue
        saved[sig] = signal.signal(sig, stop)
    return saved


def _restore_signals(saved: dict[int, Any]) -> None:
    for sig, handler in saved.items():
        signal.signal(sig, handler)


def _one_line(exc: BaseException, limit: int = 400) -> str:
    """An error's text on one line (libraries quote whole files or message definitions),
    its problem cut at ``limit`` characters; the file's name is never cut, so how deep the
    input lies does not change what is said of it."""
    if isinstance(exc, InputError) and exc.path is not None:
        return f"{exc.path}: {_cut(exc.problem, limit)}"
    return _cut(str(exc), limit)


def _cut(text: str, limit: int) -> str:
    """One line: a library's line breaks (and their indentation) as one space; any other
    character that is not printable (a name from a damaged file) escaped, not obeyed."""
    text = shown(re.sub(r"[ \t]*[\r\n][ \t\r\n]*", " ", text).replace("\t", " ").strip())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _drop_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's flush at exit does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout without a file descriptor (tests' capture)
        pass


def _run(args: argparse.Namespace) -> int:
    if COMMANDS[args.command].numba and not args.quiet:
        # Said when numba really compiles (a cache miss), and how long it took, once done.
        with load("scan2terrain.warmup:CompileWatch")(on_start=_say_compiling) as watch:
            result = _with_bars(args)
        if watch.compiled:
            took = f"{watch.seconds:.0f}" if watch.seconds >= 1 else f"{watch.seconds:.1f}"
            print(
                f"scan2terrain: compiled numba kernels in {took} s; later runs load them from "
                "the cache",
                file=sys.stderr,
            )
    else:
        result = _with_bars(args)
    if not args.quiet:
        print(result.text)
    return 0


def _with_bars(args: argparse.Namespace) -> api.Result:
    """The command run, its progress shown in bars on stderr (--progress)."""
    if not show_progress(args):
        return api.run(args)  # no bar: bag2world makes no counting pass
    counts = load("scan2terrain.types:ScanCounts")  # numpy, which the command loads anyway
    with ProgressBar(enabled=True) as bar, TaskBar(enabled=True) as tasks:

        def progress(p: Progress) -> None:
            if p.unit == "scan":
                bar.update(counts(messages=p.done, points=p.points), p.total)
            else:
                tasks.update(p.done, p.total, p.points)

        return api.run(args, progress=progress)


def _say_compiling() -> None:
    """The compile note, on a line of its own even under a progress bar."""
    line = f"scan2terrain: {load('scan2terrain.warmup:COMPILING')}"
    if "tqdm" in sys.modules:  # a bar may be drawn: tqdm clears it, writes, redraws it
        from tqdm import tqdm

        tqdm.write(line, file=sys.stderr)
    else:
        print(line, file=sys.stderr, flush=True)
