"""What each command runs: one row per command of the dispatch table (its run function, whether
its work is compiled by numba, the config defaults it sets before the config file and flags).

A run function takes the parsed arguments and the effective config and returns its report (the
CLI prints it unless --quiet). Each loads its command module (``load``) only when it runs: they
import numpy, numba and the readers, which --help does not need.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from scan2terrain.cli.display import ProgressBar, TaskBar, report

if TYPE_CHECKING:
    from scan2terrain.config import Config


@dataclass(frozen=True)
class Command:
    #: Does the work and returns the report.
    run: Callable[[argparse.Namespace, Config], str]
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
    """--progress / --no-progress, else when stderr is a terminal; never with --quiet."""
    show = sys.stderr.isatty() if args.progress is None else args.progress
    return bool(show) and not args.quiet


def _map2world(args: argparse.Namespace, cfg: Config) -> str:
    map2world = load("scan2terrain.commands.maps:map2world")
    return report(map2world(args.map, args.out, cfg, overwrite=args.overwrite))


def _image2world(args: argparse.Namespace, cfg: Config) -> str:
    image2world = load("scan2terrain.commands.maps:image2world")
    return report(image2world(args.image, args.out, cfg, overwrite=args.overwrite))


def _octree2world(args: argparse.Namespace, cfg: Config) -> str:
    octree2world = load("scan2terrain.commands.voxels:octree2world")
    with ProgressBar(enabled=show_progress(args)) as bar:
        result = octree2world(
            args.tree, args.out, cfg, overwrite=args.overwrite, progress=bar.update
        )
    return report(result)


def _bag2world(args: argparse.Namespace, cfg: Config) -> str:
    bag2world = load("scan2terrain.commands.scans:bag2world")
    show = show_progress(args)
    with ProgressBar(enabled=show) as bar, TaskBar(enabled=show) as tasks:
        result = bag2world(
            args.bag,
            args.out,
            cfg,
            overwrite=args.overwrite,
            progress=bar.update if bar.enabled else None,  # no bar: no counting pass
            stream_progress=tasks.update,
        )
    return report(result)


def _cloud2world(args: argparse.Namespace, cfg: Config) -> str:
    cloud2world = load("scan2terrain.commands.scans:cloud2world")
    with TaskBar(enabled=show_progress(args)) as tasks:
        result = cloud2world(
            args.clouds, args.out, cfg, overwrite=args.overwrite, stream_progress=tasks.update
        )
    return report(result)


def _convert(args: argparse.Namespace, cfg: Config) -> str:
    convert: Callable[..., str] = load("scan2terrain.commands.scans:convert")
    return convert(args.source, args.target, cfg, overwrite=args.overwrite)


def _inspect(args: argparse.Namespace, cfg: Config) -> str:
    inspect_bag: Callable[..., str] = load("scan2terrain.commands.scans:inspect_bag")
    return inspect_bag(args.bag, cfg)


def _dem2world(args: argparse.Namespace, cfg: Config) -> str:
    dem2world = load("scan2terrain.commands.dem:dem2world")
    return report(dem2world(args.dem, args.out, cfg, overwrite=args.overwrite))


def _fidelity(args: argparse.Namespace, cfg: Config) -> str:
    fidelity_command = load("scan2terrain.commands.replay:fidelity_command")
    return report(
        fidelity_command(
            args.world,
            args.recording,
            args.out,
            cfg,
            simulator=cfg.world.simulator,
            overwrite=args.overwrite,
        )
    )


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
}

#: Each command's own defaults (:attr:`Command.defaults`), for callers that build its config.
COMMAND_DEFAULTS: dict[str, dict[str, Any]] = {
    name: dict(c.defaults) for name, c in COMMANDS.items() if c.defaults
}
