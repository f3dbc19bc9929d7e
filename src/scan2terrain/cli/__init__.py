"""Command line: parse arguments, build the config, call the pipeline, map errors to exit codes.

Exit codes: 0 success, 1 unexpected failure, 2 bad input or usage (one line on stderr).
Heavy modules (numpy, Pillow, lxml) are imported only once a command runs, so ``--help`` is fast.
"""

from __future__ import annotations

import argparse
import re
import sys
from typing import TYPE_CHECKING, Any

from scan2terrain.cli.display import ProgressBar, TaskBar, report
from scan2terrain.cli.parser import COMMAND_DEFAULTS, build_parser, flags_of, name_flags
from scan2terrain.config import TOP_LEVEL_KEYS, load_config

if TYPE_CHECKING:
    from scan2terrain.config import Config

#: Commands whose work runs in numba kernels (compiled on a first run, see warmup.py).
NUMBA_COMMANDS = ("octree2world", "bag2world", "cloud2world")

__all__ = ["COMMAND_DEFAULTS", "build_parser", "main", "report"]


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    import warnings

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
        import signal

        name = exc.args[0] if exc.args and isinstance(exc.args[0], str) else "SIGINT"
        out = getattr(args, "out", None) or getattr(args, "target", None)
        what = f"{out} was not written or changed; " if out is not None else ""
        print(
            f"scan2terrain: interrupted ({name}): {what}nothing half-written is left",
            file=sys.stderr,
        )
        return 128 + int(getattr(signal, name, signal.SIGINT))
    except Exception as exc:
        from scan2terrain.errors import Scan2TerrainError

        if args.verbose:
            import traceback

            traceback.print_exc()
        if isinstance(exc, Scan2TerrainError):
            text = name_flags(_one_line(exc), flags_of(parser, args.command))
            print(f"scan2terrain: error: {text}", file=sys.stderr)
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
    import signal
    import threading

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
    import signal

    for sig, handler in saved.items():
        signal.signal(sig, handler)


def _one_line(exc: BaseException, limit: int = 400) -> str:
    """An error's text on one line (libraries quote whole files or message definitions),
    its problem cut at ``limit`` characters; the file's name is never cut, so how deep the
    input lies does not change what is said of it."""
    from scan2terrain.errors import InputError

    if isinstance(exc, InputError) and exc.path is not None:
        return f"{exc.path}: {_cut(exc.problem, limit)}"
    return _cut(str(exc), limit)


def _cut(text: str, limit: int) -> str:
    """One line: a library's line breaks (and their indentation) as one space; any other
    character that is not printable (a name from a damaged file) escaped, not obeyed."""
    from scan2terrain.errors import shown

    text = shown(re.sub(r"[ \t]*[\r\n][ \t\r\n]*", " ", text).replace("\t", " ").strip())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _drop_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's flush at exit does not fail again."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout without a file descriptor (tests' capture)
        pass


def _run(args: argparse.Namespace) -> int:
    from scan2terrain.checks import refuse_existing

    overrides: dict[str, Any] = {
        k: v for k, v in vars(args).items() if "." in k or k in TOP_LEVEL_KEYS
    }
    cfg = load_config(args.config, overrides, defaults=COMMAND_DEFAULTS.get(args.command))
    out = getattr(args, "out", None)
    side_inputs = [p for p in (args.config, cfg.scans.trajectory) if p is not None]
    if out is not None and side_inputs:  # files besides the command's input never go either
        refuse_existing(out, args.overwrite, tuple(side_inputs))
    if args.command in NUMBA_COMMANDS and not args.quiet:
        # Said when numba really compiles (a cache miss), and how long it took, once done.
        from scan2terrain.warmup import CompileWatch

        with CompileWatch(on_start=_say_compiling) as watch:
            code = _command(args, cfg)
        if watch.compiled:
            took = f"{watch.seconds:.0f}" if watch.seconds >= 1 else f"{watch.seconds:.1f}"
            print(
                f"scan2terrain: compiled numba kernels in {took} s; later runs load them from "
                "the cache",
                file=sys.stderr,
            )
        return code
    return _command(args, cfg)


def _say_compiling() -> None:
    """The compile note, on a line of its own even under a progress bar."""
    from scan2terrain.warmup import COMPILING

    line = f"scan2terrain: {COMPILING}"
    if "tqdm" in sys.modules:  # a bar may be drawn: tqdm clears it, writes, redraws it
        from tqdm import tqdm

        tqdm.write(line, file=sys.stderr)
    else:
        print(line, file=sys.stderr, flush=True)


def _command(args: argparse.Namespace, cfg: Config) -> int:
    if args.command in ("bag2world", "cloud2world", "convert", "inspect"):
        return _run_scans(args, cfg)
    if args.command == "map2world":
        from scan2terrain.commands.maps import map2world

        result = map2world(args.map, args.out, cfg, overwrite=args.overwrite)
    elif args.command == "octree2world":
        from scan2terrain.commands.voxels import octree2world

        with ProgressBar(enabled=show_progress(args)) as bar:
            result = octree2world(
                args.tree, args.out, cfg, overwrite=args.overwrite, progress=bar.update
            )
    elif args.command == "fidelity":
        from scan2terrain.commands.replay import fidelity_command

        result = fidelity_command(
            args.world,
            args.recording,
            args.out,
            cfg,
            simulator=cfg.world.simulator,
            overwrite=args.overwrite,
        )
    elif args.command == "dem2world":
        from scan2terrain.commands.dem import dem2world

        result = dem2world(args.dem, args.out, cfg, overwrite=args.overwrite)
    else:
        from scan2terrain.commands.maps import image2world

        result = image2world(args.image, args.out, cfg, overwrite=args.overwrite)
    if not args.quiet:
        print(report(result))
    return 0


def _run_scans(args: argparse.Namespace, cfg: Config) -> int:
    from scan2terrain.commands import scans

    if args.command == "inspect":
        print(scans.inspect_bag(args.bag, cfg))
        return 0
    if args.command == "convert":
        text = scans.convert(args.source, args.target, cfg, overwrite=args.overwrite)
        if not args.quiet:
            print(text)
        return 0
    show = show_progress(args)
    if args.command == "cloud2world":
        with TaskBar(enabled=show) as tasks:
            result = scans.cloud2world(
                args.clouds, args.out, cfg, overwrite=args.overwrite, stream_progress=tasks.update
            )
    else:
        with (
            ProgressBar(enabled=show) as bar,
            TaskBar(enabled=show) as tasks,
        ):
            progress = bar.update if bar.enabled else None  # no bar: no counting pass
            result = scans.bag2world(
                args.bag,
                args.out,
                cfg,
                overwrite=args.overwrite,
                progress=progress,
                stream_progress=tasks.update,
            )
    if not args.quiet:
        print(report(result))
    return 0


def show_progress(args: argparse.Namespace) -> bool:
    """--progress / --no-progress, else when stderr is a terminal; never with --quiet."""
    show = sys.stderr.isatty() if args.progress is None else args.progress
    return bool(show) and not args.quiet
