"""The checks every command runs before any work, and the refusals of what a run cannot use:
option combinations, output paths, grid sizes against the memory budget, recordings none of
whose scans could be used."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

from scan2terrain.config import Config, two_digits_up
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters.heightmap import CLASSIC
from scan2terrain.exporters.output import OutputDir

if TYPE_CHECKING:
    from scan2terrain.grids.tiles import TileSet
    from scan2terrain.types import ScanCounts


def refuse_existing(out: Path, overwrite: bool, inputs: tuple[Path | str, ...] = ()) -> None:
    # Checked before any work so a refused run costs nothing; OutputDir checks again. The
    # target is resolved; one that is or contains an input (``inputs``), ``/``, or the current
    # or home folder or a parent of them is refused even under --overwrite.
    OutputDir.check_target(out, overwrite, inputs)


#: Peak bytes per grid cell of the octree and streamed paths, from the grid to the world files,
#: measured over the process's base: 69-90 on the autzen LAZ at 0.2 m (16.6 M cells, sparse),
#: 200 on four LAS tiles at 0.098 m (16.7 M cells, every one occupied: the walls' mesh).
GRID_BYTES_PER_CELL = 200


def refuse_large_grid(
    source: Path, what: str, rows: int, cols: int, *, resolution: float, cfg: Config
) -> None:
    """Refuse a grid of ``rows`` x ``cols`` cells over ``max_pixels``, or estimated to need more
    than ``max_memory`` MiB, before it is allocated (the octree's and the streamed path's, from
    the ``what`` it spans): one line naming the settings that fix it, instead of a MemoryError
    or the machine swapping."""
    cells = rows * cols
    if cells > cfg.max_pixels:
        raise ConfigError(
            f"{source}: the {what} span {cols} x {rows} cells of {resolution:g} m, over"
            f" max_pixels {cfg.max_pixels}: choose a coarser --resolution (files in different"
            " coordinate systems also spread this far)"
        )
    need = cells * GRID_BYTES_PER_CELL / 2**20
    if need > cfg.max_memory:
        fits = two_digits_up(resolution * math.sqrt(need / cfg.max_memory))
        raise ConfigError(
            f"{source}: the {what} span {cols} x {rows} cells of {resolution:g} m, about"
            f" {need / 1024:.1f} GiB to build, over max_memory {cfg.max_memory} MiB: choose"
            f" --resolution {fits:g} or coarser, or raise --max-memory"
        )


def refuse_tiles_grid(tiles: TileSet, cfg: Config, source: Path) -> None:
    """Refuse, before the dense grid is allocated, the grid of tiles that hold no point or
    that :func:`refuse_large_grid` refuses."""
    if tiles.points == 0:
        raise InputError(source, "no point in the z band: nothing to make a grid of")
    rows, cols = tiles.grid_shape()
    refuse_large_grid(source, "points", rows, cols, resolution=tiles.lattice.resolution, cfg=cfg)


def refuse_unused(source: Path, counts: ScanCounts, done: str) -> None:
    """A recording none of whose scan messages could be ``done`` (used, replayed): one line
    saying how many lacked a pose or a valid point, and why the first had no pose."""
    if counts.inserted:
        return
    why = f"; the first: {counts.first_unposed}" if counts.first_unposed else ""
    raise InputError(
        source,
        f"none of {counts.messages} scan message(s) could be {done} "
        f"({counts.unposed} without a pose, {counts.empty} without a valid point){why}",
    )


def skipped_notes(counts: ScanCounts) -> list[str]:
    """The report's lines on the scans left out: without a pose, without a valid point."""
    notes = []
    if counts.unposed:
        notes.append(f"scans without a pose, skipped: {counts.unposed} ({counts.first_unposed})")
    if counts.empty:
        notes.append(f"scans without a valid point, skipped: {counts.empty}")
    return notes


def no_voxels(cfg: Config, what: str) -> None:
    """Refuse ``world.geometry voxels``, before any work, for commands that hold no voxels."""
    if cfg.world.geometry == "voxels":
        raise ConfigError(
            f"world.geometry voxels meshes an octree's voxels (octree2world, bag2world,"
            f" cloud2world); {what} has no third dimension: use mesh, boxes, polylines or"
            " heightmap"
        )


def heightmap_only(cfg: Config, what: str) -> Config:
    """``cfg`` for inputs that are heights, not occupancy (``world.geometry`` auto resolved);
    refuses wall geometries and what no heightmap can be (:func:`heightmap_options`)."""
    no_voxels(cfg, what)
    cfg = cfg.for_grid("height")
    heightmap_options(cfg)
    if cfg.world.geometry != "heightmap":
        raise ConfigError(
            f"world.geometry {cfg.world.geometry} needs an occupancy grid (map2world, or"
            f" octree/bag/cloud2world with octree.grid occupancy); {what} makes heightmaps only"
        )
    return cfg


def heightmap_options(cfg: Config) -> None:
    """Refuse, before any work, heightmap options a chosen simulator cannot load: every command
    that writes a heightmap checks the same things, with the same message."""
    if cfg.terrain.bit_depth == 16 and cfg.world.simulator in (CLASSIC, "both"):
        raise ConfigError(
            "Gazebo Classic reads only the first byte of each heightmap pixel: use "
            "--bit-depth 8 with --simulator classic or both (16-bit is gz-sim only)"
        )


def grid_options(cfg: Config) -> None:
    """Before any work, for the commands whose grid comes from voxels or points (octree2world,
    bag2world, cloud2world): refuse what the world they will write cannot be."""
    grid = cfg.octree.grid
    if cfg.for_grid(grid).world.geometry == "heightmap":
        heightmap_options(cfg)
