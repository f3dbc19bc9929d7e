"""Run many ``scan2terrain`` commands cheaply and watch how each one ends.

``run_cases`` (called by the tests) starts ONE fresh Python process running this file, which
imports scan2terrain and its heavy libraries once and then forks a child per case (a few at a
time). The child sets an address-space limit (``RLIMIT_AS``) and a wall-clock alarm (SIGALRM:
a hang), sends its stdout to /dev/null and its stderr (file descriptor 2, so what C libraries
print is caught too) to a file, calls ``scan2terrain.cli.main(argv)`` and leaves with its exit
code (``os._exit``: no atexit handlers, no flushing of buffers inherited from the parent); an
exception escaping ``main`` (a BaseException such as pyo3's PanicException) is printed and
ends it with 1, as it would a real ``scan2terrain``. The parent ``wait4``s and reports, per
case, the exit code or the signal, the child's peak RSS and CPU time, its stderr and the files
it left next to its output.

A fresh process, not the pytest process, is forked from: pytest may have run numba's parallel
kernels or Open3D before (threads that do not survive a fork), and OpenBLAS is held to one
thread (``OPENBLAS_NUM_THREADS=1``) so that nothing but the main thread exists at a fork.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

#: Modules imported once by the runner before any fork (none of them starts a thread).
PRELOAD = (
    "numpy",
    "scipy.ndimage",
    "PIL.Image",
    "PIL.PngImagePlugin",
    "yaml",
    "lxml.etree",
    "laspy",
    "lazrs",
    "tifffile",
    "rosbags.highlevel",
    "open3d",
    "scan2terrain.cli",
    "scan2terrain.commands.maps",
    "scan2terrain.commands.voxels",
    "scan2terrain.commands.dem",
    "scan2terrain.commands.scans",
    "scan2terrain.commands.stream",
    "scan2terrain.readers.cloudfile",
    "scan2terrain.readers.bag",
    "scan2terrain.readers.dem",
    "scan2terrain.readers._las_kernels",
    "scan2terrain.octree.bt",
)


@dataclass(frozen=True)
class Case:
    """One command: ``argv`` for ``scan2terrain.cli.main``; ``watch`` is the folder that must
    hold nothing new afterwards when the command refuses its input (exit 2)."""

    name: str
    argv: list[str]
    watch: str


@dataclass
class Outcome:
    """How a case ended: ``exit`` code or ``signal`` number (one of them is None)."""

    name: str
    argv: list[str]
    exit: int | None
    signal: int | None
    stderr: str
    maxrss_mb: float
    seconds: float
    new_files: list[str] = field(default_factory=list)
    #: CPU time of the child (user + system): what a case costs whatever else runs.
    cpu_seconds: float = 0.0

    def describe(self) -> str:
        how = f"signal {self.signal}" if self.signal is not None else f"exit {self.exit}"
        tail = self.stderr.strip().splitlines()[-3:]
        return f"{self.name}: {how}, {self.maxrss_mb:.0f} MB, {self.seconds:.2f} s: {tail}"


def one_line(o: Outcome, src: Path | str) -> str:
    """The command's only stderr line: an error naming ``src`` (exit 2, nothing written)."""
    lines = o.stderr.strip().splitlines()
    assert o.exit == 2 and o.signal is None, o.describe()
    assert len(lines) == 1, o.describe()
    assert lines[0].startswith(f"scan2terrain: error: {src}: "), o.describe()
    assert not o.new_files, o.describe()
    return lines[0]


def run_cases(
    cases: Sequence[Case],
    *,
    limit_bytes: int,
    jobs: int = 2,
    timeout_s: int = 60,
    workdir: Path,
) -> list[Outcome]:
    """Run ``cases`` in a fresh runner process, ``jobs`` children at a time."""
    spec = {
        "cases": [asdict(c) for c in cases],
        "limit": limit_bytes,
        "jobs": jobs,
        "timeout": timeout_s,
        "workdir": str(workdir),
    }
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    env.pop("RUST_BACKTRACE", None)
    done = subprocess.run(
        [sys.executable, str(Path(__file__).resolve())],
        input=json.dumps(spec),
        capture_output=True,
        text=True,
        env=env,
        check=False,
        timeout=timeout_s * (len(cases) + 1),
    )
    if done.returncode != 0:
        raise RuntimeError(f"mutation runner failed ({done.returncode}): {done.stderr[-3000:]}")
    return [Outcome(**o) for o in json.loads(done.stdout)]


# --- the runner process ---------------------------------------------------------------------


def _listing(folder: Path) -> set[str]:
    if not folder.exists():
        return set()
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _child(case: dict[str, Any], err_path: Path, limit: int, timeout: int) -> None:
    """In the forked child: limits, redirections, the command, ``os._exit`` with its code."""
    code = 1
    try:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        signal.alarm(timeout)
        err = os.open(err_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(err, 2)
        os.dup2(null, 1)
        sys.stderr = open(2, "w", closefd=False, buffering=1)  # noqa: SIM115
        sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
        from scan2terrain import cli

        code = cli.main(list(case["argv"]))
    except SystemExit as exc:  # argparse
        code = exc.code if isinstance(exc.code, int) else 2
    except BaseException:  # escaped main(): what a plain `scan2terrain` would die of (exit 1)
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def _main() -> None:
    import importlib

    spec = json.loads(sys.stdin.read())
    for name in PRELOAD:
        importlib.import_module(name)
    tasks = Path("/proc/self/task")
    if tasks.is_dir() and len(list(tasks.iterdir())) > 1:  # a fork copies only this thread
        raise RuntimeError("the preloaded modules started threads: forking is not safe")
    limit, jobs, timeout = int(spec["limit"]), int(spec["jobs"]), int(spec["timeout"])
    workdir = Path(spec["workdir"])
    workdir.mkdir(parents=True, exist_ok=True)
    cases: list[dict[str, Any]] = spec["cases"]
    results: dict[int, dict[str, Any]] = {}
    running: dict[int, tuple[int, float, set[str]]] = {}  # pid -> (case index, start, listing)
    todo = list(range(len(cases)))[::-1]
    while todo or running:
        while todo and len(running) < jobs:
            i = todo.pop()
            before = _listing(Path(cases[i]["watch"]))
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _child(cases[i], workdir / f"stderr_{i}.txt", limit, timeout)
            running[pid] = (i, time.monotonic(), before)
        pid, status, usage = os.wait4(-1, 0)
        if pid not in running:
            continue
        i, start, before = running.pop(pid)
        case = cases[i]
        err = (workdir / f"stderr_{i}.txt").read_text(errors="replace")
        after = _listing(Path(case["watch"]))
        results[i] = {
            "name": case["name"],
            "argv": case["argv"],
            "exit": os.WEXITSTATUS(status) if os.WIFEXITED(status) else None,
            "signal": os.WTERMSIG(status) if os.WIFSIGNALED(status) else None,
            "stderr": err,
            "maxrss_mb": usage.ru_maxrss / 1024,
            "seconds": time.monotonic() - start,
            "new_files": sorted(after - before),
            "cpu_seconds": usage.ru_utime + usage.ru_stime,
        }
    print(json.dumps([results[i] for i in range(len(cases))]))


if __name__ == "__main__":
    _main()
