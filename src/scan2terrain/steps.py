"""Named steps the commands share: filtering and previews, canvas and classification, the
terrain layout (one heightmap or tiles), the spawn search, and the checks every command runs
before any work (option combinations, grid sizes, output paths)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config, octree_resolution, two_digits_up
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters._numbers import decimal_text
from scan2terrain.exporters.heightmap import CLASSIC, Heightmap, make_heightmap
from scan2terrain.exporters.output import OutputDir
from scan2terrain.exporters.preview import preview_png
from scan2terrain.exporters.tiles import TiledHeightmap, make_tiled_heightmap
from scan2terrain.filters.registry import run_filter
from scan2terrain.filters.speckle import remove_speckles
from scan2terrain.grids import (
    canvas,
    from_rank,
    to_rank,
    to_trinary,
    upsample,
)
from scan2terrain.grids.occupancy import RANK_FREE, RANK_OCCUPIED
from scan2terrain.grids.spawn import Around, find_spawn
from scan2terrain.types import (
    HeightGrid,
    OccupancyGrid,
    Pose2D,
    Spawn,
    Start,
)

if TYPE_CHECKING:
    from scan2terrain.grids.projection import ColumnStats
    from scan2terrain.grids.tiles import Lattice, TileSet
    from scan2terrain.octree.tree import VoxelOctree
    from scan2terrain.types import ScanCounts

#: Called after every scan: (counts so far, scans expected in total, 0 when unknown).
ScanProgress = Callable[["ScanCounts", int], None]

ScalarT = TypeVar("ScalarT", bound=np.generic)

#: The ground of a heightmap world: one heightmap, or tiles when the grid is too big for one.
Terrain = Heightmap | TiledHeightmap


@dataclass(frozen=True)
class Preview:
    """preview.png and what it shows."""

    png: bytes
    label: str


def filtering(cfg: Config, *, occupancy: bool) -> bool:
    """Whether the configured filter changes anything: a filter kind, or for occupancy grids
    also speckle removal (heights and greys have no speckles)."""
    f = cfg.filter
    return f.enabled and (f.kind != "none" or (occupancy and f.speckle_min_cells > 1))


def make_preview(
    before: NDArray[np.generic], after: NDArray[np.generic], cfg: Config, *, occupancy: bool
) -> Preview:
    """Original | filtered | difference when a filter ran; else the input alone (labelled so)."""
    if filtering(cfg, occupancy=occupancy):
        return Preview(
            preview_png(before, after, occupancy=occupancy), "original | filtered | difference"
        )
    return Preview(preview_png(before, None, occupancy=occupancy), "the input; filtering off")


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
    return heightmap_or_tiles(grid, cfg, pad_height=pad_height)


def heightmap_or_tiles(grid: HeightGrid, cfg: Config, *, pad_height: float) -> Terrain:
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
    from scan2terrain.grids import projection

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
        from scan2terrain.grids.tiles import TileSet

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
        from scan2terrain.octree.keys import KEY_OFFSET, in_key_range

        points = held[0] if len(held) == 1 else np.concatenate(held)
        reach = KEY_OFFSET * self.tiles.lattice.resolution * (1 - 1e-6)
        if len(points) and not -reach < points.min() <= points.max() < reach:
            points = points[in_key_range(points, self.tiles.lattice.resolution)]
        self.tiles.add_points(points)


def refuse_tiles_grid(tiles: TileSet, cfg: Config, source: Path) -> None:
    """Refuse, before the dense grid is allocated, the grid of tiles that hold no point or
    that :func:`refuse_large_grid` refuses."""
    from scan2terrain.errors import InputError

    if tiles.points == 0:
        raise InputError(source, "no point in the z band: nothing to make a grid of")
    rows, cols = tiles.grid_shape()
    refuse_large_grid(source, "points", rows, cols, resolution=tiles.lattice.resolution, cfg=cfg)


def point_heights(
    tiles: TileSet, cfg: Config, source: Path, *, occupied: ColumnStats | None = None
) -> tuple[HeightGrid, list[str]]:
    """The height grid of points' column statistics, the same on every path: sized before it
    is allocated, ``octree.height_stat`` of the points' z per cell (bounded by the octree's
    ``occupied`` columns after ray casting, see :meth:`TileSet.heights`), holes filled as
    ``octree.fill`` says; and a note when its cells are coarser than the relief's detail
    (:func:`relief_note`). The tiles are emptied once the grid is made."""
    from scan2terrain.errors import InputError

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


def filter_text(cfg: Config) -> str:
    f = cfg.filter
    if not filtering(cfg, occupancy=True):
        return "no filter"
    text = f"filter {f.kind}"
    if f.speckle_min_cells > 1:
        text += f", specks under {f.speckle_min_cells} cells removed"
    return text


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
    cfg = cfg.for_grid("heights")
    heightmap_options(cfg)
    if cfg.world.geometry != "heightmap":
        raise ConfigError(
            f"world.geometry {cfg.world.geometry} needs an occupancy grid (map2world, or"
            f" octree/bag/cloud2world with octree.grid occupancy); {what} makes heightmaps only"
        )
    return cfg


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


def grid_options(cfg: Config) -> None:
    """Before any work, for the commands whose grid comes from voxels or points (octree2world,
    bag2world, cloud2world): refuse what the world they will write cannot be."""
    grid = "occupancy" if cfg.octree.grid == "occupancy" else "heights"
    if cfg.for_grid(grid).world.geometry == "heightmap":
        heightmap_options(cfg)


def minus(name: str, v: float) -> str:
    """``name`` minus ``v``, written for a human: 'x - 29.125', 'x + 0.125', or 'x' for 0;
    ``v`` rounded to the nanometre (28.95, not 28.950000000000003)."""
    text = decimal_text(abs(v), 9)
    if text == "0":
        return name
    return f"{name} - {text}" if v > 0 else f"{name} + {text}"


def heightmap_options(cfg: Config) -> None:
    """Refuse, before any work, heightmap options a chosen simulator cannot load: every command
    that writes a heightmap checks the same things, with the same message."""
    if cfg.terrain.bit_depth == 16 and cfg.world.simulator in (CLASSIC, "both"):
        raise ConfigError(
            "Gazebo Classic reads only the first byte of each heightmap pixel: use "
            "--bit-depth 8 with --simulator classic or both (16-bit is gz-sim only)"
        )


def refuse_existing(out: Path, overwrite: bool, inputs: tuple[Path | str, ...] = ()) -> None:
    # Checked before any work so a refused run costs nothing; OutputDir checks again. The
    # target is resolved; one that is or contains an input (``inputs``), ``/``, or the current
    # or home folder or a parent of them is refused even under --overwrite.
    OutputDir.check_target(out, overwrite, inputs)


def spawn_for(
    heights: NDArray[np.floating],
    resolution: float,
    origin: Pose2D,
    start: Start | None,
    *,
    ground: NDArray[np.bool_] | None = None,
    free: NDArray[np.bool_] | None = None,
    samples: bool = False,
    around: Around | None = None,
) -> Spawn:
    """The spawn spot of a world's ground (map frame; see grids/spawn.py): searched from the
    robot's recorded start when there is one, else from the map origin (or the centre).
    ``samples``: a heightmap's (Gazebo interpolates between them); ``around``: the ground the
    world has beyond the grid (a walls world's slab, a heightmap's padding)."""
    if start is None:
        return find_spawn(
            heights, resolution, origin, ground=ground, free=free, samples=samples, around=around
        )
    p = start.pose
    return find_spawn(
        heights, resolution, origin, preferred=(p.x, p.y), yaw=p.yaw, ground=ground,
        free=free, why=start.why, samples=samples, around=around,
    )  # fmt: skip


def terrain_around(hm: Terrain, upsample: int, height: float) -> Around | None:
    """The padding of one heightmap around its grid, in whole grid cells (``upsample``
    pixels a cell), at ``height`` metres: ground Gazebo builds beyond the map. Tiles: None
    (their padding is on the far sides of the last tiles only)."""
    if not isinstance(hm, Heightmap):
        return None
    rows, cols = hm.grid_shape
    left, bottom = hm.pad
    right, top = hm.side - cols - left, hm.side - rows - bottom
    return Around(
        (left // upsample, bottom // upsample, right // upsample, top // upsample), height
    )


def new_tree(cfg: Config) -> VoxelOctree:
    """An empty voxel octree with the config's resolution and OctoMap sensor model, refusing
    to grow past ``max_memory``."""
    from scan2terrain.octree.tree import SensorModel, VoxelOctree

    o = cfg.octree
    return VoxelOctree(
        octree_resolution(cfg),
        SensorModel(o.hit, o.miss, o.clamp_min, o.clamp_max, o.occupancy),
        max_bytes=cfg.max_memory << 20,
    )


@contextmanager
def octree_file(
    resolution: float, keys: NDArray[np.uint16], occupied: NDArray[np.bool_]
) -> Iterator[dict[str, Future[bytes]]]:
    """``{"octree.bt": the .bt bytes}``, made on a second thread while the caller builds the
    world from the same (unchanged) voxels: the .bt kernels release the GIL, so on two cores
    the file costs no time; the bytes are the same. The writer waits for them."""
    from scan2terrain.octree.bt import bt_bytes

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="octree.bt") as pool:
        yield {
            "octree.bt": pool.submit(bt_bytes, resolution=resolution, keys=keys, occupied=occupied)
        }


def grey8(heights: NDArray[np.float32], lo: float, hi: float) -> NDArray[np.uint8]:
    """Heights as 8-bit grey between ``lo`` (black) and ``hi`` (white), for previews."""
    span = hi - lo if hi > lo else 1.0
    grey: NDArray[np.uint8] = np.clip(np.rint((heights - lo) / span * 255), 0, 255).astype(np.uint8)
    return grey


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
