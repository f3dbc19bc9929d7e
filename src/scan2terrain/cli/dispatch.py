"""What each command runs: one row per command of the dispatch table (its run function, whether
its work is compiled by numba, the config defaults it sets before the config file and flags).

A run function takes the parsed arguments, the effective config and a progress callback (or
None), and returns what its command returns: the :class:`~scan2terrain.world.folder.Result` of
the folder it wrote, or the text to print (convert, inspect). ``scan2terrain.api.run`` calls it,
for the CLI and for the Python API alike, and makes the API's Result of it. Each loads its
command module (``load``) only when it runs: they import numpy, numba and the readers, which
--help does not need.

A new command is a row here (its options in parser.py) and a function in ``scan2terrain/api.py``
calling ``_call`` with its positional arguments.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from scan2terrain.config import Config
    from scan2terrain.types import ScanCounts
    from scan2terrain.world.folder import Result


@dataclass(frozen=True)
class Progress:
    """How far a run is, as its progress callback is told (octree2world on scan files,
    bag2world, cloud2world).

    ``unit`` is ``"scan"`` (scans inserted into the octree; ``total`` 0 when not known, as for
    an OctoMap scan file read once) or ``"task"`` (tasks of ``--stream`` or Dask done);
    ``points`` counts the points read so far.
    """

    unit: Literal["scan", "task"]
    done: int
    total: int
    points: int


#: What a run calls as it goes (``progress=`` of the Python API; the CLI's progress bars).
ProgressCallback = Callable[[Progress], None]


@dataclass(frozen=True)
class Command:
    #: Does the work: (parsed arguments, effective config, progress callback or None) -> the
    #: folder's Result, or the text to print.
    run: Callable[[argparse.Namespace, Config, ProgressCallback | None], Result | str]
    #: Its work runs in numba kernels (compiled on a first run, see warmup.py): the CLI says
    #: when it compiles.
    numba: bool = False
    #: Config values the command sets before the config file and the flags (which override them).
    defaults: Mapping[str, Any] = field(default_factory=dict)


def load(target: str) -> Any:
    """``"module:name"``, imported now (as the filter registry loads filters)."""
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def show_progress(args: argparse.Namespace) -> bool:
    """--progress / --no-progress, else when stderr is a terminal; never with --quiet (nor for
    a command that reports no progress)."""
    if not hasattr(args, "progress"):
        return False
    show = sys.stderr.isatty() if args.progress is None else args.progress
    return bool(show) and not args.quiet


def _scans(progress: ProgressCallback | None) -> Callable[[ScanCounts, int], None] | None:
    """The commands' scan counts as :class:`Progress` (None: no callback, and for bag2world no
    counting pass)."""
    if progress is None:
        return None
    tell = progress

    def update(counts: ScanCounts, total: int) -> None:
        tell(Progress("scan", counts.messages, total, counts.points))

    return update


def _tasks(progress: ProgressCallback | None) -> Callable[[int, int, int], None] | None:
    """The streamed tasks done as :class:`Progress`."""
    if progress is None:
        return None
    tell = progress

    def update(done: int, total: int, points: int) -> None:
        tell(Progress("task", done, total, points))

    return update


def _map2world(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> Result:
    map2world = load("scan2terrain.commands.maps:map2world")
    result: Result = map2world(args.map, args.out, cfg, overwrite=args.overwrite)
    return result


def _image2world(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> Result:
    image2world = load("scan2terrain.commands.maps:image2world")
    result: Result = image2world(args.image, args.out, cfg, overwrite=args.overwrite)
    return result


def _octree2world(
    args: argparse.Namespace, cfg: Config, progress: ProgressCallback | None
) -> Result:
    octree2world = load("scan2terrain.commands.voxels:octree2world")
    result: Result = octree2world(
        args.tree, args.out, cfg, overwrite=args.overwrite, progress=_scans(progress)
    )
    return result


def _bag2world(args: argparse.Namespace, cfg: Config, progress: ProgressCallback | None) -> Result:
    bag2world = load("scan2terrain.commands.scans:bag2world")
    result: Result = bag2world(
        args.bag,
        args.out,
        cfg,
        overwrite=args.overwrite,
        progress=_scans(progress),  # None: no counting pass
        stream_progress=_tasks(progress),
    )
    return result


def _cloud2world(
    args: argparse.Namespace, cfg: Config, progress: ProgressCallback | None
) -> Result:
    cloud2world = load("scan2terrain.commands.scans:cloud2world")
    result: Result = cloud2world(
        args.clouds, args.out, cfg, overwrite=args.overwrite, stream_progress=_tasks(progress)
    )
    return result


def _convert(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> str:
    convert: Callable[..., str] = load("scan2terrain.commands.scans:convert")
    return convert(args.source, args.target, cfg, overwrite=args.overwrite)


def _inspect(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> str:
    inspect_bag: Callable[..., str] = load("scan2terrain.commands.scans:inspect_bag")
    return inspect_bag(args.bag, cfg)


def _dem2world(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> Result:
    dem2world = load("scan2terrain.commands.dem:dem2world")
    result: Result = dem2world(args.dem, args.out, cfg, overwrite=args.overwrite)
    return result


def _fidelity(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> Result:
    fidelity_command = load("scan2terrain.commands.replay:fidelity_command")
    result: Result = fidelity_command(
        args.world,
        args.recording,
        args.out,
        cfg,
        simulator=cfg.world.simulator,
        overwrite=args.overwrite,
    )
    return result


def _view(args: argparse.Namespace, cfg: Config, _: ProgressCallback | None) -> str:
    view: Callable[..., str] = load("scan2terrain.commands.view:view")
    return view(args.world, host=args.host, port=args.port, browser=not args.no_browser)


#: Every command, in the order --help lists them.
COMMANDS: dict[str, Command] = {
    "map2world": Command(_map2world),
    "image2world": Command(_image2world),
    "octree2world": Command(_octree2world, numba=True),
    "bag2world": Command(_bag2world, numba=True),
    "cloud2world": Command(
        _cloud2world,
        numba=True,
        # Clouds come at every scale, from a room to an airborne survey: see cloud_resolution.
        defaults={"octree.resolution": None},
    ),
    "convert": Command(_convert),
    "inspect": Command(_inspect),
    "dem2world": Command(
        _dem2world,
        # A DEM spans hundreds of metres of height: 8 bits would be steps of range / 255.
        defaults={"terrain.bit_depth": 16, "world.simulator": "gz", "filter.kind": "none"},
    ),
    # A world is scored for one simulator: gz-sim's, unless told.
    "fidelity": Command(_fidelity, defaults={"world.simulator": "gz"}),
    "view": Command(_view),
}

#: Each command's own defaults (:attr:`Command.defaults`), for callers that build its config.
COMMAND_DEFAULTS: dict[str, dict[str, Any]] = {
    name: dict(c.defaults) for name, c in COMMANDS.items() if c.defaults
}
