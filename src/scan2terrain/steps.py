"""Named grid steps the commands share: filtering, canvas and classification, the terrain layout
(one heightmap or tiles), hole filling, and the points' column statistics and heights.

The checks every command runs before any work are in ``checks.py``; what the world builders use
(previews, the spawn search, texts) is in ``world/``; the octree's file thread in
``commands/voxels.py``."""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.checks import refuse_tiles_grid
from scan2terrain.config import Config, two_digits_up
from scan2terrain.errors import InputError
from scan2terrain.exporters.heightmap import make_heightmap
from scan2terrain.exporters.tiles import Terrain, make_tiled_heightmap
from scan2terrain.filters.registry import run_filter
from scan2terrain.filters.speckle import remove_speckles
from scan2terrain.grids import (
    canvas,
    from_rank,
    projection,
    to_rank,
    to_trinary,
    upsample,
)
from scan2terrain.grids.occupancy import RANK_FREE, RANK_OCCUPIED
from scan2terrain.grids.tiles import TileSet
from scan2terrain.octree.keys import KEY_OFFSET, in_key_range
from scan2terrain.types import (
    HeightGrid,
    OccupancyGrid,
    Pose2D,
)
from scan2terrain.world.preview import filtering

if TYPE_CHECKING:
    from scan2terrain.grids.projection import ColumnStats
    from scan2terrain.grids.tiles import Lattice, TileSet
    from scan2terrain.types import ScanCounts

#: Called after every scan: (counts so far, scans expected in total, 0 when unknown).
ScanProgress = Callable[["ScanCounts", int], None]
#: Streaming: called after every task: (tasks done, tasks in all, points counted so far).
StreamProgress = Callable[[int, int, int], None]

ScalarT = TypeVar("ScalarT", bound=np.generic)


# --- steps -----------------------------------------------------------------------------------


def filter_occupancy(trinary: NDArray[np.int8], cfg: Config) -> NDArray[np.int8]:
    """Apply the configured filter and speckle removal to a trinary grid."""
    if not filtering(cfg, occupancy=True):
        return trinary
    f = cfg.filter
    rank = run_filter(to_rank(trinary), f.kind, f.size, fallback="majority")
    if f.speckle_min_cells > 1:
        rank = remove_speckles(
            rank,
            value=RANK_OCCUPIED,
            min_cells=f.speckle_min_cells,
            replace_with=RANK_FREE,
        )
    return from_rank(rank)


def filter_grey(values: NDArray[ScalarT], cfg: Config) -> NDArray[ScalarT]:
    """Apply the configured filter to a grey image (median fallback: greys are ordered)."""
    if not filtering(cfg, occupancy=False):
        return values
    return run_filter(values, cfg.filter.kind, cfg.filter.size, fallback="median")


def terrain_layout(
    heights: NDArray[np.float32],
    resolution: float,
    origin: Pose2D,
    cfg: Config,
    *,
    pad_height: float,
) -> Terrain:
    """World-aligned heights (metres, every cell known) -> up-sampled (``terrain.upsample``)
    -> the heightmap image (``terrain.bit_depth``), padded at ``pad_height``; a grid of more
    than ``terrain.max_side`` samples a side (after up-sampling) becomes terrain tiles
    (:class:`~.exporters.tiles.TiledHeightmap`)."""
    t = cfg.terrain
    fine, fine_res = upsample(heights.astype(np.float32), resolution, t.upsample)
    grid = HeightGrid(fine, np.ones(fine.shape, dtype=bool), fine_res, origin)
    return terrain_of(grid, cfg, pad_height=pad_height)


def terrain_of(grid: HeightGrid, cfg: Config, *, pad_height: float) -> Terrain:
    """One heightmap (``terrain.bit_depth``) when ``grid`` (yaw 0) fits ``terrain.max_side``,
    else tiles of that side sharing their border samples."""
    t = cfg.terrain
    if max(grid.shape) <= t.max_side:
        return make_heightmap(grid, bit_depth=t.bit_depth, pad_height=pad_height)
    return make_tiled_heightmap(
        grid, max_side=t.max_side, bit_depth=t.bit_depth, pad_height=pad_height
    )


def place_on_canvas(
    data: NDArray[ScalarT], origin: Pose2D, resolution: float, cfg: Config, *, fill: int
) -> tuple[NDArray[ScalarT], Pose2D]:
    """The paper's crop/extend and offset options (``cfg.canvas``), keeping georeference."""
    c = cfg.canvas
    return canvas(
        data,
        origin,
        resolution,
        width=c.width,
        height=c.height,
        offset_x=c.offset_x,
        offset_y=c.offset_y,
        fill=fill,
    )


def classify(
    grid: OccupancyGrid, mode: str, occupied_thresh: float, free_thresh: float
) -> NDArray[np.int8]:
    """map_server values to trinary; raw maps are classified with their own thresholds."""
    if mode == "raw":
        return to_trinary(
            grid.data, occupied_above=100 * occupied_thresh, free_below=100 * free_thresh
        )
    return to_trinary(grid.data)


# --- commands --------------------------------------------------------------------------------


def fill_holes(heights: HeightGrid, cfg: Config) -> HeightGrid:
    """Unknown cells of a 2.5D grid filled as ``octree.fill`` says (none, nearest, idw)."""

    o = cfg.octree
    if o.fill == "nearest":
        reach = o.fill_max_distance
        if reach is None:
            reach = max(1.0, 4 * heights.resolution)
        return projection.fill_nearest(heights, max_distance_m=reach)
    if o.fill == "idw":
        return projection.fill_idw(heights)
    return heights


# --- heights from points ----------------------------------------------------------------------


class PointColumns:
    """The points' own column statistics, gathered beside an octree for a height grid: the
    :class:`~scan2terrain.grids.tiles.TileSet` the streamed path makes (on its ``lattice``,
    ``commands.stream.lattice_for``), fed the points the octree is fed (a scan's hits) but for
    those outside its key range, which it drops. They are added on a second thread, ``BATCH``
    points or more at a time, while the octree takes the same points on the others (its
    insertion leaves a core idle part of the time; its kernels and the tiles' release the GIL):
    10 M points in random order, 0.27 s into the octree and 0.47 s into the tiles one after the
    other, take 0.67 s side by side (best of 5, another process busy). One batch is added while
    the next is gathered, never more: memory stays one batch.

    ``cast``: the points are ray-cast, and later rays may clear some of their voxels; the
    octree's occupied columns then bound the heights (:meth:`TileSet.heights`). End points
    occupy every voxel they hit, so their heights are the tiles' alone, as streamed.
    """

    BATCH = 1 << 20

    def __init__(self, lattice: Lattice, *, cast: bool) -> None:

        self.tiles = TileSet(lattice)
        self.cast = cast
        self._held: list[NDArray[np.float64]] = []
        self._n = 0
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="point-columns")
        self._adding: Future[None] | None = None

    def add(self, points: NDArray[np.float64]) -> None:
        """Points (N, 3), metres, in the octree's frame, as float64 (the z sum's input); they
        must not change until :meth:`finish`."""
        self._held.append(points)
        self._n += len(points)
        if self._n >= self.BATCH:
            self._send()

    def finish(self) -> TileSet:
        """The tiles, every point added."""
        self._send()
        self._pool.shutdown()
        return self.tiles

    def _send(self) -> None:
        held, self._held, self._n = self._held, [], 0
        if self._adding is not None:
            self._adding.result()  # the batch before (its error, if any, raised here)
            self._adding = None
        if held:
            self._adding = self._pool.submit(self._add, held)

    def _add(self, held: list[NDArray[np.float64]]) -> None:

        points = held[0] if len(held) == 1 else np.concatenate(held)
        reach = KEY_OFFSET * self.tiles.lattice.resolution * (1 - 1e-6)
        if len(points) and not -reach < points.min() <= points.max() < reach:
            points = points[in_key_range(points, self.tiles.lattice.resolution)]
        self.tiles.add_points(points)


def point_heights(
    tiles: TileSet, cfg: Config, source: Path, *, occupied: ColumnStats | None = None
) -> tuple[HeightGrid, list[str]]:
    """The height grid of points' column statistics, the same on every path: sized before it
    is allocated, ``octree.height_stat`` of the points' z per cell (bounded by the octree's
    ``occupied`` columns after ray casting, see :meth:`TileSet.heights`), holes filled as
    ``octree.fill`` says; and a note when its cells are coarser than the relief's detail
    (:func:`relief_note`). The tiles are emptied once the grid is made."""

    refuse_tiles_grid(tiles, cfg, source)
    heights = tiles.heights(cfg.octree.height_stat, occupied)
    if not heights.known.any():
        raise InputError(source, "no occupied voxel in the z band: nothing to make terrain of")
    note = relief_note(heights, tiles.cell_spreads(), tiles.points)
    tiles.clear()
    return fill_holes(heights, cfg), [note] if note else []


#: A height grid's cells are coarser than its relief's detail when the points of a quarter of
#: them span more than this share of the relief (1st to 99th percentile of the heights)...
RELIEF_SHARE = 0.1
#: ... and more than this (metres). Flat ground's scatter grows with the points a cell holds
#: (lidar's few centimetres span half a metre over 500 points) but is no relief a cell hides.
RELIEF_HIDDEN_MIN = 1.0


def relief_note(heights: HeightGrid, spreads: NDArray[np.float32], points: int) -> str | None:
    """A note when a height grid's cells are coarser than its relief's detail: a quarter of
    the cells holding two points or more (``spreads``: max - min of their z, metres) hide
    more than ``RELIEF_SHARE`` of the relief and more than ``RELIEF_HIDDEN_MIN``. It names the
    resolution of about four points a cell where the ``points`` are (their count over the
    known cells' area) when that is finer. Points of more than one surface (trees over the
    ground, roofs) span their height at any cell size: the note says so too.

    Why these: smooth hills 60 m across at 10 m cells hide a fifth of their relief in a
    quarter of the cells (just under a tenth at 5 m); the autzen LAZ's ground passes at 20 m
    and is noted at 40 m, its river bank then a block or two; its every class (buildings,
    trees) from 20 m. A share of the heightmap's own relief: it does not depend on units."""
    known = heights.heights[heights.known]
    if len(spreads) == 0 or len(known) == 0:
        return None
    hidden = float(np.percentile(spreads, 75))
    low, high = np.percentile(known, [1, 99])
    relief = float(high - low)
    if not (hidden > RELIEF_SHARE * relief and hidden > RELIEF_HIDDEN_MIN):
        return None
    r = heights.resolution
    cells = len(known)
    fine = two_digits_up(2 * math.sqrt(cells * r * r / points))
    if fine < r:
        advice = f"--resolution {fine:g} (about four points a cell where there are points)"
        advice += " keeps more of it"
    else:
        advice = f"its points are too sparse for finer cells ({points / cells:.1f} a cell)"
    return (
        f"cells of {r:g} m are coarse for this terrain: in a quarter of them the points span"
        f" {hidden:.3g} m of height or more, over a tenth of its {relief:.3g} m relief;"
        f" {advice}, unless they are more than one surface (trees, buildings: keep the"
        " ground, e.g. --las-classes 2)"
    )


#: An occupancy grid from points this full of occupied cells is most likely ground, not walls.
SOLID_SHARE = 0.9
#: ... once it has this many cells. Fewer cannot be 90% full without being full (one cell is
#: over a tenth of them), and a grid that small is one small object seen alone (a post, a
#: pole), which fills its own footprint: its walls are right, and terrain would not help.
SOLID_MIN_CELLS = 10


def solid_hint(grid: OccupancyGrid) -> str | None:
    """A note when a grid made from points or voxels is nearly all occupied (ground counted
    as obstacle: a survey, or a scan without a z band), which makes one solid block of walls;
    any grid of ``SOLID_MIN_CELLS`` or more (a 3 x 3 m field at 0.1 m is 900 cells)."""
    occupied = np.count_nonzero(grid.data > 50)
    if grid.data.size < SOLID_MIN_CELLS or occupied < SOLID_SHARE * grid.data.size:
        return None
    return (
        f"{occupied / grid.data.size:.0%} of the grid is occupied: the ground counts as an"
        " obstacle, so the walls are one solid block. --grid height makes terrain of it;"
        " --z-min/--z-max keep the ground out of an occupancy grid"
    )
