"""scan2terrain: turn what a robot saw into a Gazebo world that lines up with its map frame.

Each command is a function too, with the command line's options as keyword arguments
(``scan2terrain.map2world("map.yaml", "world", height=2.5)``: :mod:`scan2terrain.api`),
imported on first use, so that ``import scan2terrain`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from scan2terrain.api import (
        Progress,
        ProgressCallback,
        Result,
        World,
        bag2world,
        cloud2world,
        convert,
        dem2world,
        fidelity,
        image2world,
        inspect,
        keywords,
        map2world,
        octree2world,
        view,
    )

    __version__: str

#: The Python API, re-exported from scan2terrain.api (its ``__all__``).
__all__ = [
    "Progress",
    "ProgressCallback",
    "Result",
    "World",
    "bag2world",
    "cloud2world",
    "convert",
    "dem2world",
    "fidelity",
    "image2world",
    "inspect",
    "keywords",
    "map2world",
    "octree2world",
    "view",
]


def __getattr__(name: str) -> object:
    # The version has one source, the package's metadata (pyproject.toml), read on demand.
    if name == "__version__":
        from importlib.metadata import version

        return version("scan2terrain")
    if name in __all__:  # the API loads the CLI's parser: only when it is used
        return getattr(importlib.import_module("scan2terrain.api"), name)
    raise AttributeError(f"module 'scan2terrain' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__, "__version__"})
