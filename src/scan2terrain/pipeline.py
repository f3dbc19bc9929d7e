"""Named steps composed into the commands. Only this module and cli.py know every stage.

map2world:   read map YAML -> classify -> invert/canvas -> filter -> align to world axes
             -> heights (unknown policy) -> heightmap -> model + world per simulator, map, preview
image2world: read image -> luminance -> invert/canvas -> filter -> align -> heights -> ... (same)
dem2world:   read GeoTIFF -> square pixels, DEM centre at the origin -> canvas/filter -> heights
             above the lowest -> 16-bit heightmap at z = lowest elevation -> worlds, preview
walls:       with world.geometry mesh | boxes | polylines, an occupancy grid's occupied cells
             -> outlines (mesh, polylines) or merged boxes -> one static model per simulator

Any size: a terrain wider or taller than ``terrain.max_side`` samples is written as heightmap
tiles sharing their border samples (gz-sim only, see exporters/tiles.py), and a map_server map
wider or taller than ``output.map_max_side`` cells as map tiles, each with its own YAML.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters import mapserver as map_export
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import CLASSIC, GZ, Heightmap, make_heightmap
from scan2terrain.exporters.output import OutputDir, atomic_output
from scan2terrain.exporters.preview import preview_png
from scan2terrain.exporters.tiles import TiledHeightmap, TileSpec, make_tiled_heightmap
from scan2terrain.filters import (
    majority_filter,
    median_filter,
    paper_median_filter,
    remove_speckles,
    thin_wall_median_filter,
)
from scan2terrain.filters.unknown import occupancy_to_heights, unknown_level
from scan2terrain.grids import (
    axis_align,
    canvas,
    from_rank,
    invert_occupancy,
    to_rank,
    to_trinary,
    upsample,
)
from scan2terrain.grids.occupancy import RANK_FREE, RANK_OCCUPIED
from scan2terrain.grids.spawn import FOOTPRINT, find_spawn
from scan2terrain.types import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    HeightGrid,
    OccupancyGrid,
    Pose2D,
    Spawn,
    Start,
)

if TYPE_CHECKING:
    from scan2terrain.octree.tree import VoxelOctree
    from scan2terrain.readers.dem import Dem
    from scan2terrain.readers.scans import ScanCounts

#: Called after every scan: (counts so far, scans expected in total, 0 when unknown).
ScanProgress = Callable[["ScanCounts", int], None]

ScalarT = TypeVar("ScalarT", bound=np.generic)

WORLD_FILES = {GZ: "world_gz.sdf", CLASSIC: "world_classic.world"}
CONFIG_FILE = "scan2terrain.yaml"
SPAWN_FILE = "spawn.yaml"
#: What the extra files a command writes beside the world are, for the report (by stem).
EXTRA_ABOUT = {
    "octree": "the octree, as OctoMap's .bt (octovis, octomap_server, octree2world)",
    "occupied_voxels": "the occupied voxels' centres",
}

#: The ground of a heightmap world: one heightmap, or tiles when the grid is too big for one.
Terrain = Heightmap | TiledHeightmap


@dataclass(frozen=True)
class WorldOutput:
    """One simulator's world inside the output folder.

    ``map_yaml`` is the map_server YAML lined up with this world (None when no map was written,
    or when the map was written as tiles: then ``map_tiles`` lists one YAML per tile, row by row
    from the lowest y). For tiled terrain ``placement`` describes the whole terrain (model name
    = the tiles' common prefix, size = the grid's extent).
    """

    placement: sdf.Placement
    world: Path
    models: Path
    map_yaml: Path | None
    map_tiles: tuple[Path, ...] = ()
    #: Where to spawn a robot, in this world's frame: (x, y, z, roll, pitch, yaw).
    spawn: tuple[float, float, float, float, float, float] | None = None


@dataclass
class Result:
    """What a command wrote, for the CLI to report."""

    out: Path
    worlds: list[WorldOutput] = field(default_factory=list)
    heightmap_side: int = 0
    resolution: float = 0.0
    size_z: float = 0.0
    preview: Path | None = None
    config: Path | None = None
    notes: list[str] = field(default_factory=list)  #: what was read and chosen, for the report
    geometry: str = "heightmap"  #: world.geometry of the worlds written
    walls: str = ""  #: for wall geometries: what the walls are made of, for the report
    tiles: tuple[int, int] = (1, 1)  #: heightmap tiles along y and x (terrain.max_side)
    spawn: Spawn | None = None  #: where a robot can start, map frame (each world's: worlds)
    preview_label: str = ""  #: what preview.png shows, for the report


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
    rank = _apply_filter(to_rank(trinary), f.kind, f.size, fallback="majority")
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
    return _apply_filter(values, cfg.filter.kind, cfg.filter.size, fallback="median")


def _apply_filter(
    a: NDArray[ScalarT], kind: str, size: int, *, fallback: Literal["majority", "median"]
) -> NDArray[ScalarT]:
    if kind == "median":
        return median_filter(a, size=size)
    if kind == "majority":
        return majority_filter(a, size=size)
    if kind == "paper":
        return paper_median_filter(a, fallback=fallback)
    if kind == "thin_wall":
        return thin_wall_median_filter(a, fallback=fallback)
    return a


def terrain_heightmap(
    heights: NDArray[np.float32],
    resolution: float,
    origin: Pose2D,
    cfg: Config,
    *,
    pad_height: float,
) -> Heightmap:
    """World-aligned heights (metres, every cell known) -> up-sampled (``terrain.upsample``)
    -> the heightmap image (``terrain.bit_depth``), padded at ``pad_height``."""
    t = cfg.terrain
    fine, fine_res = upsample(heights.astype(np.float32), resolution, t.upsample)
    return make_heightmap(
        HeightGrid(fine, np.ones(fine.shape, dtype=bool), fine_res, origin),
        bit_depth=t.bit_depth,
        pad_height=pad_height,
    )


def terrain_layout(
    heights: NDArray[np.float32],
    resolution: float,
    origin: Pose2D,
    cfg: Config,
    *,
    pad_height: float,
) -> Terrain:
    """As :func:`terrain_heightmap`, but a grid of more than ``terrain.max_side`` samples a side
    (after up-sampling) becomes terrain tiles (:class:`~.exporters.tiles.TiledHeightmap`)."""
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


def map2world(yaml_path: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """A map_server map (YAML + image) to a Gazebo world folder. See the module docstring."""
    from scan2terrain.readers import read_map_yaml

    refuse_existing(out, overwrite, (yaml_path,))
    meta, grid = read_map_yaml(yaml_path, max_pixels=cfg.max_pixels)
    refuse_existing(out, overwrite, (meta.image,))  # the image may live elsewhere
    trinary = classify(grid, meta.mode, meta.occupied_thresh, meta.free_thresh)
    return occupancy_world(grid.with_data(trinary), Path(yaml_path), out, cfg, overwrite=overwrite)


def occupancy_world(
    grid: OccupancyGrid,
    source: Path,
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    extra: dict[str, bytes] | None = None,
    start: Start | None = None,
) -> Result:
    """A trinary occupancy grid to a world folder: invert/canvas -> filter -> align -> heights
    (unknown policy) -> heightmap -> worlds, map_server map, preview. ``extra`` files (relative
    name -> bytes) are written into the same folder; ``start`` is where the robot started
    (the spawn pose is searched from there; None: from the map origin)."""
    cfg = cfg.for_grid("occupancy")
    if cfg.world.geometry == "heightmap":
        heightmap_options(cfg)
    trinary = invert_occupancy(grid.data) if cfg.canvas.invert else grid.data
    trinary, origin = place_on_canvas(trinary, grid.origin, grid.resolution, cfg, fill=UNKNOWN)
    filtered = filter_occupancy(trinary, cfg)
    if cfg.world.geometry != "heightmap":
        return walls_world(
            grid.with_data(filtered, origin),
            source,
            out,
            cfg,
            overwrite=overwrite,
            preview=make_preview(trinary, filtered, cfg, occupancy=True),
            extra=extra,
            start=start,
        )

    aligned, world_origin = axis_align(filtered, origin, grid.resolution, fill=UNKNOWN)
    t = cfg.terrain
    heights = occupancy_to_heights(
        aligned, wall_height=t.height, policy=t.unknown, unknown_height=t.unknown_height
    )
    pad = unknown_level(t.unknown, wall_height=t.height, unknown_height=t.unknown_height)
    hm = terrain_layout(heights, grid.resolution, world_origin, cfg, pad_height=pad)
    return _write(
        out,
        cfg,
        overwrite=overwrite,
        source=source,
        hm=hm,
        levels=(0.0, pad, t.height),
        map_out=OccupancyGrid(aligned, grid.resolution, world_origin),
        preview=make_preview(trinary, filtered, cfg, occupancy=True),
        extra=extra,
        spawn=spawn_for(
            heights,
            grid.resolution,
            world_origin,
            start,
            ground=heights <= 0,
            free=aligned == FREE,
        ),
    )


def octree2world(
    source: Path,
    out: Path,
    cfg: Config,
    *,
    overwrite: bool = False,
    progress: ScanProgress | None = None,
) -> Result:
    """An OctoMap ``.bt`` file, or an OctoMap text scan file (ray-cast into a new octree), to a
    world folder through octomap_server's 2D projection or a 2.5D height grid. ``progress``
    (scan files only) is called after each scan with the counts so far and a total of 0
    (unknown: the file is read once)."""
    from scan2terrain.octree.bt import bt_bytes, read_bt
    from scan2terrain.readers.octomap_scan import is_scan_file

    refuse_existing(out, overwrite, (source,))
    grid_options(cfg)
    source = Path(source)
    extra: dict[str, bytes] = {}
    if is_scan_file(source):
        tree = build_octree(source, cfg, progress)
        keys, occupied = tree.occupied_and_free()
        resolution = tree.resolution
        extra["octree.bt"] = bt_bytes(resolution=resolution, keys=keys, occupied=occupied)
        runs = None
    else:
        from scan2terrain.grids.projection import leaf_columns

        bt = read_bt(source)
        # Pruned leaves (a free 256^3 block is common in octomap_server maps) stay vertical runs.
        try:
            keys, occupied, runs = leaf_columns(bt.keys, bt.depth, bt.occupied)
        except ValueError as exc:
            raise InputError(source, f"{exc}: too large to project") from None
        resolution = bt.resolution
    return voxels_world(
        keys,
        occupied,
        resolution,
        source=source,
        out=out,
        cfg=cfg,
        overwrite=overwrite,
        extra=extra,
        runs=runs,
    )


def voxels_world(
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    resolution: float,
    *,
    source: Path,
    out: Path,
    cfg: Config,
    overwrite: bool,
    extra: dict[str, bytes] | None = None,
    start: Start | None = None,
    runs: NDArray[np.uint16] | None = None,
) -> Result:
    """Known voxels (OctoMap keys, occupied or free) to a world folder: octomap_server's 2D
    projection (``octree.grid: occupancy``) or a 2.5D height grid, plus the occupied voxel
    centres when ``octree.points`` asks for them; ``start`` as for :func:`occupancy_world`;
    ``runs``: each key starts a vertical run of that many voxels (pruned leaves)."""
    from scan2terrain.grids import projection

    extra = dict(extra or {})
    if len(keys) == 0:
        raise InputError(source, "the octree holds no known voxel")
    o = cfg.octree
    if o.points != "none":
        from scan2terrain.exporters.pointcloud import points_bytes
        from scan2terrain.octree.keys import key_to_coord

        extra[f"occupied_voxels.{o.points}"] = points_bytes(
            key_to_coord(_occupied_voxels(keys, occupied, runs, source), resolution),
            f".{o.points}",
        )
    z_min = -math.inf if o.z_min is None else o.z_min
    z_max = math.inf if o.z_max is None else o.z_max
    # Size the grid before allocating it (its columns span the keys' x and y range).
    span = keys[:, :2].max(axis=0).astype(np.int64) - keys[:, :2].min(axis=0) + 1
    refuse_large_grid(source, "voxels", int(span[1]), int(span[0]), resolution=resolution, cfg=cfg)
    if o.grid == "occupancy":
        grid = projection.project_occupancy(
            keys, occupied, resolution, z_min=z_min, z_max=z_max, runs=runs
        )
        return occupancy_world(
            grid, source, out, cfg, overwrite=overwrite, extra=extra, start=start
        )
    stats = projection.column_stats(keys, occupied, resolution, z_min=z_min, z_max=z_max, runs=runs)
    if not stats.known.any():
        raise InputError(source, "no occupied voxel in the z band: nothing to make terrain of")
    heights = fill_holes(stats.to_height_grid(o.height_stat), cfg)
    return height_world(heights, source, out, cfg, overwrite=overwrite, extra=extra, start=start)


#: Most occupied voxel centres written by ``--points`` (12 bytes each in memory, 24 in PLY).
MAX_POINTS = 50_000_000


def _occupied_voxels(
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    runs: NDArray[np.uint16] | None,
    source: Path,
) -> NDArray[np.uint16]:
    """Keys of every occupied voxel, runs expanded (counted first, refused past MAX_POINTS)."""
    picked = keys[occupied]
    if runs is None:
        return picked
    lengths = runs[occupied].astype(np.int64)
    if int(lengths.sum()) > MAX_POINTS:
        raise InputError(
            source,
            f"--points: the tree's occupied leaves hold {int(lengths.sum())} voxels, more than "
            f"{MAX_POINTS}; leave out --points",
        )
    out = np.repeat(picked, lengths, axis=0)
    starts = np.cumsum(lengths) - lengths
    out[:, 2] += (np.arange(len(out)) - np.repeat(starts, lengths)).astype(np.uint16)
    return out


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


def build_octree(source: Path, cfg: Config, progress: ScanProgress | None = None) -> VoxelOctree:
    """Ray-cast every scan of an OctoMap text scan file into a new octree."""
    from scan2terrain.octree.tree import SensorModel, VoxelOctree
    from scan2terrain.readers.octomap_scan import read_scans
    from scan2terrain.readers.scans import ScanCounts

    o = cfg.octree
    tree = VoxelOctree(
        o.resolution, SensorModel(o.hit, o.miss, o.clamp_min, o.clamp_max, o.occupancy)
    )
    counts = ScanCounts()
    for scan in read_scans(source):
        try:
            tree.insert_scan(scan.points, scan.origin, max_range=o.max_range)
        except InputError as exc:
            raise InputError(source, exc.problem) from None
        counts.messages += 1
        counts.inserted += 1
        counts.points += len(scan.points)
        if progress is not None:
            progress(counts, 0)
    return tree


def height_world(
    grid: HeightGrid,
    source: Path,
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    extra: dict[str, bytes] | None = None,
    start: Start | None = None,
) -> Result:
    """A 2.5D height grid (metres) to a world folder. Unknown cells sit at the lowest known
    height. Filters: the plain median (``filter.size``) when filtering is on, as heights are
    not labels. ``start`` as for :func:`occupancy_world`."""
    cfg = heightmap_only(cfg, "a height grid")
    heights = grid.heights
    known = grid.known
    floor = float(heights[known].min()) if known.any() else 0.0
    filled = np.where(known, heights, floor).astype(np.float32)
    before = filled
    if filtering(cfg, occupancy=False):
        filled = median_filter(filled, size=cfg.filter.size)
    aligned, world_origin = axis_align(filled, grid.origin, grid.resolution, fill=floor)
    hm = terrain_layout(aligned, grid.resolution, world_origin, cfg, pad_height=floor)
    top = float(aligned.max(initial=floor))
    return _write(
        out,
        cfg,
        overwrite=overwrite,
        source=source,
        hm=hm,
        levels=(floor, (floor + top) / 2, top),
        map_out=None,
        preview=make_preview(
            _grey8(before, floor, top), _grey8(filled, floor, top), cfg, occupancy=False
        ),
        extra=extra,
        spawn=spawn_for(aligned, grid.resolution, world_origin, start),
    )


def _grey8(heights: NDArray[np.float32], lo: float, hi: float) -> NDArray[np.uint8]:
    span = hi - lo if hi > lo else 1.0
    grey: NDArray[np.uint8] = np.clip(np.rint((heights - lo) / span * 255), 0, 255).astype(np.uint8)
    return grey


def image2world(image_path: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """Any image to a Gazebo world folder: luminance is height, white is ``terrain.height``."""
    from scan2terrain.readers import read_grey_image

    cfg = heightmap_only(cfg, "image2world")
    refuse_existing(out, overwrite, (image_path,))
    img = read_grey_image(image_path, max_pixels=cfg.max_pixels)
    values = np.ascontiguousarray(np.flipud(img.values))
    res = cfg.image.resolution
    rows, cols = values.shape
    if cfg.image.origin is None:
        origin = Pose2D(-cols * res / 2, -rows * res / 2, 0.0)
    else:
        o = cfg.image.origin
        origin = Pose2D(o[0], o[1], o[2] if len(o) > 2 else 0.0)
    if cfg.canvas.invert:
        values = (img.max_value - values).astype(values.dtype)
    # After inverting: cells the canvas adds are black (floor) either way.
    values, origin = place_on_canvas(values, origin, res, cfg, fill=0)
    filtered = filter_grey(values, cfg)
    aligned, world_origin = axis_align(filtered, origin, res, fill=0)
    scale = np.float32(cfg.terrain.height / img.max_value)
    heights = (aligned.astype(np.float32) * scale).astype(np.float32)
    hm = terrain_layout(heights, res, world_origin, cfg, pad_height=0.0)
    top = float(heights.max(initial=0.0))
    levels = (0.0, top / 2, top)
    return _write(
        out,
        cfg,
        overwrite=overwrite,
        source=Path(image_path),
        hm=hm,
        levels=levels,
        map_out=None,
        preview=make_preview(values, filtered, cfg, occupancy=False),
        spawn=spawn_for(heights, res, world_origin, None),
    )


# --- walls (world.geometry mesh | boxes | polylines) -----------------------------------------


@dataclass(frozen=True)
class _Walls:
    """What a walls world is made of, ready for the SDF writers."""

    model_sdf: Callable[[sdf.Placement, str], bytes]  #: (placement, comment) -> model.sdf
    files: dict[str, bytes]  #: model-folder files besides model.sdf / model.config
    summary: str  #: what the walls are, for the SDF comment and the report


def walls_world(
    grid: OccupancyGrid,
    source: Path,
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    preview: Preview,
    extra: dict[str, bytes] | None = None,
    start: Start | None = None,
) -> Result:
    """A filtered trinary grid to a world of walls (``world.geometry``: mesh, boxes, polylines).

    The walls are the occupied cells (and the unknown ones with ``terrain.unknown: obstacle``),
    ``terrain.height`` metres high, on a ground plane over the grid. Their geometry is written in
    the grid's own map-frame pose (yaw included, no resampling) and the model sits at the world
    origin in both simulators: a map point (x, y) is the world point (x, y). The map/ folder,
    preview and config are written as for heightmaps (map/ in world axes, ``grids.axis_align``).

    A grid without a wall cell gives the ground plane alone.
    """
    t, kind = cfg.terrain, cfg.world.geometry
    walls = grid.data == OCCUPIED
    if t.unknown == "obstacle":
        walls |= grid.data == UNKNOWN
    r, origin = grid.resolution, grid.origin
    rows, cols = walls.shape
    cx, cy = origin.transform(np.array(cols * r / 2), np.array(rows * r / 2))
    ground = sdf.Ground((float(cx), float(cy)), (cols * r, rows * r), origin.yaw)
    if walls.any():
        made = _walls(walls, r, origin, ground=ground, cfg=cfg, source=source)
    else:
        made = _Walls(
            lambda p, comment: sdf.boxes_model_sdf(p, ground, np.empty((0, 5)), comment=comment),
            {},
            "no wall cell: the ground plane alone",
        )
    spawn = spawn_for(
        np.where(walls, t.height, 0.0), r, origin, start, ground=~walls, free=grid.data == FREE
    )
    described = (
        f" Generated by scan2terrain from {source.name}: walls {t.height!r} m high on a ground"
        f" plane, from the {int(walls.sum())} wall cells of a {rows}x{cols} grid at {r!r} m/cell"
        f" ({_filter_text(cfg)}), as {made.summary}.\n"
        " Map frame (x, y) = world (x, y), in gz-sim and in Gazebo Classic alike: the model sits"
        " at the world origin and the geometry is written in map coordinates (unlike a"
        " heightmap, meshes, boxes and polylines can be placed anywhere).\n"
    )
    payload = repr((kind, cfg.world.simplify, t.height, r, origin, walls.shape)).encode()
    base_name = _unique_name(source, walls.tobytes() + payload, cfg)
    aligned, world_origin = axis_align(grid.data, origin, r, fill=UNKNOWN)
    map_out = OccupancyGrid(aligned, r, world_origin)
    sims = (GZ, CLASSIC) if cfg.world.simulator == "both" else (cfg.world.simulator,)
    result = Result(
        out=out, resolution=r, size_z=t.height, geometry=kind, walls=made.summary, spawn=spawn
    )
    result.notes.extend(_map_notes(cfg, map_out))
    parts = []
    for sim in sims:
        name = base_name if sim == GZ or len(sims) == 1 else f"{base_name}_classic"
        p = sdf.walls_placement(sim, name, kind, ground, t.height)
        files = {f"models/{name}/{rel}": data for rel, data in made.files.items()}
        files[f"models/{name}/model.sdf"] = made.model_sdf(p, described)
        files[f"models/{name}/model.config"] = sdf.model_config(p, f"Walls from {source.name}")
        pose = spawn_pose(spawn, (0.0, 0.0), 0.0)
        world = sdf.world_sdf(
            p, world_name="scan2terrain", comment=described + spawn_comment(spawn, pose)
        )
        parts.append(SimWorld(p, files, world, (0.0, 0.0), described, pose))
    folder = WorldFolder(source, result, parts, map_out, preview, extra or {})
    return write_world_folder(folder, out, cfg, overwrite=overwrite)


def _walls(
    walls: NDArray[np.bool_],
    resolution: float,
    origin: Pose2D,
    *,
    ground: sdf.Ground,
    cfg: Config,
    source: Path,
) -> _Walls:
    kind = cfg.world.geometry
    if kind == "boxes":
        from scan2terrain.exporters.meshfile import dae_bytes
        from scan2terrain.geometry.boxes import merge_boxes
        from scan2terrain.geometry.mesh import boxes_mesh

        cells = merge_boxes(walls)
        boxes = _box_poses(cells, resolution, origin)
        visual = boxes_mesh(boxes, cfg.terrain.height)
        return _Walls(
            lambda p, comment: sdf.boxes_model_sdf(p, ground, boxes, comment=comment),
            {f"{sdf.MESH_DIR}/{sdf.MESH_STEM}.dae": dae_bytes(visual, sdf.MESH_STEM)},
            f"{len(cells)} boxes (the fewest that cover the wall cells exactly) in one model,"
            f" one mesh visual of them ({sdf.MESH_DIR}/{sdf.MESH_STEM}.dae)",
        )
    from scan2terrain.geometry import outlines

    polygons = outlines.trace(walls, resolution, origin)
    simplified = ""
    if cfg.world.simplify > 0:
        polygons = outlines.simplify(
            polygons, cfg.world.simplify, resolution=resolution, origin=origin
        )
        simplified = (
            f", straightened within {cfg.world.simplify!r} m without moving any cell centre across"
        )
        if not polygons:
            raise InputError(
                source, f"no wall outline is left after --simplify {cfg.world.simplify!r}"
            )
    holes = sum(len(poly.holes) for poly in polygons)
    outline = f"{len(polygons)} outline polygons with {holes} holes{simplified}"
    if kind == "polylines":
        if resolution < sdf.POLYLINE_MIN_CELL:
            raise InputError(
                source,
                f"--geometry polylines needs cells of at least {sdf.POLYLINE_MIN_CELL} m"
                f" (gz-common merges polyline points closer than 0.1 mm), not {resolution!r} m:"
                " use mesh or boxes",
            )
        rings = [poly.rings() for poly in polygons]
        return _Walls(
            lambda p, comment: sdf.polylines_model_sdf(p, ground, rings, comment=comment),
            {},
            f"{outline}, one <polyline> geometry each (holes as extra <polyline> elements)",
        )
    from scan2terrain.exporters import meshfile
    from scan2terrain.geometry.mesh import extrude

    mesh = extrude(polygons, cfg.terrain.height)
    stem = f"{sdf.MESH_DIR}/{sdf.MESH_STEM}"
    files = {
        f"{stem}.stl": meshfile.stl_bytes(mesh),
        f"{stem}.dae": meshfile.dae_bytes(mesh, sdf.MESH_STEM),
        f"{stem}.obj": meshfile.obj_bytes(mesh),
    }
    return _Walls(
        lambda p, comment: sdf.mesh_model_sdf(p, ground, comment=comment),
        files,
        f"one mesh of {len(mesh.faces)} triangles extruded from {outline}"
        f" ({stem}.stl for collision, .dae for the visual, .obj)",
    )


def _box_poses(cells: NDArray[np.int64], resolution: float, origin: Pose2D) -> NDArray[np.float64]:
    """Boxes in cells ``[row0, col0, n_rows, n_cols]`` -> ``[x, y, size_x, size_y, yaw]``:
    centres in the map frame (metres), sizes along the grid's axes, the grid's yaw."""
    c = cells.astype(np.float64)
    u = (c[:, 1] + c[:, 3] / 2) * resolution
    v = (c[:, 0] + c[:, 2] / 2) * resolution
    x, y = origin.transform(u, v)
    yaw = np.full(len(c), origin.yaw)
    return np.stack([x, y, c[:, 3] * resolution, c[:, 2] * resolution, yaw], axis=1)


def _filter_text(cfg: Config) -> str:
    f = cfg.filter
    if not filtering(cfg, occupancy=True):
        return "no filter"
    text = f"filter {f.kind}"
    if f.speckle_min_cells > 1:
        text += f", specks under {f.speckle_min_cells} cells removed"
    return text


def dem2world(dem_path: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """A DEM (single-band GeoTIFF) to a world folder whose ground is at the true elevation.

    World frame: the DEM's centre is the world origin, x east, y north, metres (CRS coordinates,
    UTM or degrees, are far too large for a simulator's float32 rendering); for a geographic DEM
    x and y are the equirectangular projection at its centre latitude. The offset is in the
    report, in the SDF comments and in ``Result.notes``. World z is the elevation in gz-sim:
    the heightmap's 0 is the lowest valid height (its pose z) and ``size.z`` the height range.
    Gazebo Classic writes no heightmap pose here, so its ground sits at elevation - lowest.

    Pixels: the DEM's own when they are square in metres (projected DEMs), so every sample keeps
    its height exactly; otherwise (geographic DEMs) bilinear resampling to square pixels that
    fill the 2^n+1 image the finer pixel size needs (``Dem.default_resolution``); the corner
    samples stay exact. ``dem.resolution`` or ``terrain.upsample`` (bilinear here, not blocks)
    choose another size. The grid is then padded, never stretched, to the next square 2^n+1 at
    the lowest height (gz-common's own DEM loader also pads with the lowest height). Filters:
    the plain median (``filter.size``) when filtering is on.
    """

    from scan2terrain.errors import ConfigError
    from scan2terrain.grids import canvas as grid_canvas
    from scan2terrain.readers.dem import read_dem

    refuse_existing(out, overwrite, (dem_path,))
    cfg = heightmap_only(cfg, "dem2world")
    t = cfg.terrain
    if cfg.canvas.invert:
        raise ConfigError("canvas.invert (--invert) has no meaning for a DEM")
    source = Path(dem_path)
    dem = read_dem(source, pixel_size=cfg.dem.resolution, max_pixels=cfg.max_pixels)
    base = cfg.dem.resolution if cfg.dem.resolution is not None else dem.default_resolution()
    res = base / t.upsample
    cells = (dem.extent[0] / res + 2) * (dem.extent[1] / res + 2)
    if not cells <= cfg.max_pixels:  # NaN too
        raise InputError(
            source,
            f"{res:g} m pixels make the {dem.extent[0]:.0f} x {dem.extent[1]:.0f} m DEM "
            f"~{cells:.3g} pixels, over max_pixels {cfg.max_pixels}: choose a coarser "
            "--resolution (or raise --max-pixels)",
        )
    grid = dem.to_height_grid(res)
    c = cfg.canvas
    heights, origin = grid_canvas(
        grid.heights, grid.origin, res, width=c.width, height=c.height,
        offset_x=c.offset_x, offset_y=c.offset_y, fill=dem.z_min,
    )  # fmt: skip
    known, _ = grid_canvas(
        grid.known, grid.origin, res, width=c.width, height=c.height,
        offset_x=c.offset_x, offset_y=c.offset_y, fill=False,
    )  # fmt: skip
    if not known.any():
        raise InputError(source, "the canvas options leave no DEM cell")
    before = heights
    if filtering(cfg, occupancy=False):
        heights = median_filter(heights, size=cfg.filter.size)
    # The DEM's own lowest elevation is the heightmap's 0 (and the padding), even where the
    # grid was resampled, cropped or filtered: pose z is always that elevation.
    z0 = dem.z_min
    top = float(heights[known].max())
    above = np.clip(np.where(known, heights - np.float32(z0), 0), 0, top - z0)
    hm = heightmap_or_tiles(
        HeightGrid(above.astype(np.float32), np.ones(above.shape, dtype=bool), res, origin),
        cfg,
        pad_height=0.0,
    )
    # make_heightmap puts 0 at min(0, lowest) = 0 here; the ground's 0 is the lowest elevation.
    # Tiles keep their pixels (0 two levels below the lowest) and are raised by it.
    hm = hm.raised(z0) if isinstance(hm, TiledHeightmap) else dataclasses.replace(hm, z_min=z0)
    notes = _dem_notes(source, dem, res, hm)
    extra: dict[str, bytes] = {}
    if cfg.dem.passthrough:
        name = f"{terrain_name(source, hm, cfg)}_dem"
        # What the PNG world's notes say about the DEM and its frame, not about its pixels.
        about = (notes[0], notes[2], *dem.notes)
        extra = _dem_passthrough(source, dem, name, cfg, "".join(f" {n}\n" for n in about))
        notes.append(
            "gz-sim >= 7 with GDAL can load the GeoTIFF itself: world_gz_dem.sdf (model "
            f"{name}; not checked here: the test harness's gz-common has no DEM support)"
        )
    result = _write(
        out,
        cfg,
        overwrite=overwrite,
        source=source,
        hm=hm,
        # Texture blend heights, in the heightmap's own heights (0 = its lowest point).
        levels=(0.0, hm.z_range / 2, hm.z_range),
        map_out=None,
        preview=make_preview(
            _grey8(before, z0, top), _grey8(heights, z0, top), cfg, occupancy=False
        ),
        extra=extra,
        comment_extra="".join(f" {n}\n" for n in notes),
        spawn=spawn_for(above + np.float32(z0), res, origin, None),
    )
    result.notes.extend(notes)
    return result


def _dem_notes(source: Path, dem: Dem, res: float, hm: Terrain) -> list[str]:
    """What was read and where it went: for the report and the SDF comments."""
    rows, cols = dem.shape
    px, py = dem.pixel_size
    crs = dem.crs + (f" ({dem.citation})" if dem.citation else "")
    own = abs(px - res) <= 1e-6 * res and abs(py - res) <= 1e-6 * res
    lines = [
        f"DEM {source.name}: {crs}, {cols}x{rows} px of {px:.6g} x {py:.6g} m "
        f"({dem.extent[0]:.6g} x {dem.extent[1]:.6g} m), elevations {dem.z_min:.6g} .. "
        f"{dem.z_max:.6g} m, {int((~dem.valid).sum())} nodata px (set to the lowest).",
        f"Heightmap pixels: the DEM's own, {res:.6g} m."
        if own
        else f"Heightmap pixels: {res:.6g} m, resampled bilinearly from {px:.6g} x {py:.6g} m.",
    ]
    cx, cy = dem.centre
    if dem.crs == "geographic":
        lines.append(
            f"Map frame = DEM frame: x east, y north, metres from the DEM centre (latitude "
            f"{cy!r}, longitude {cx!r}, {dem.units}s): a point (lat, lon) is at x = "
            f"{dem.radius!r} cos(lat0) (lon - lon0), y = {dem.radius!r} (lat - lat0), radians."
        )
    elif dem.crs == "projected":
        k = dem.pixel_size[0] / dem.pixel_size_crs[0]
        unit = "" if abs(k - 1) < 1e-12 else f", times {k!r} m/{dem.units}"
        lines.append(
            f"Map frame = DEM frame: x east, y north, metres from the DEM centre, CRS "
            f"({cx!r}, {cy!r}) {dem.units}s: a point (E, N) is at"
            f" ({minus('E', cx)}, {minus('N', cy)}){unit}."
        )
    else:
        lines.append("Map frame = DEM frame: metres from the image centre, x right, y up.")
    if isinstance(hm, TiledHeightmap):
        lines.append(
            f"z = elevation in gz-sim (every tile: pixel 0 at {hm.z_min!r} m, full scale"
            f" {hm.z_range!r} m above it)."
        )
    else:
        lines.append(
            f"z = elevation in gz-sim (heightmap 0 at {hm.z_min!r} m, size.z {hm.z_range!r} m);"
            f" in Gazebo Classic z = {minus('elevation', hm.z_min)} m."
        )
    return lines + list(dem.notes)


def _dem_passthrough(
    source: Path, dem: Dem, name: str, cfg: Config, comment: str
) -> dict[str, bytes]:
    """A gz-sim model and world that hand the GeoTIFF itself to gz-common's ``Dem`` (GDAL).

    The geometry follows gz-common 5 ``Dem::Load``/``LoadData`` and gz-physics 6
    ``CustomHeightmapShape``: the raster is resampled (GDAL nearest neighbour) so its longer
    side in pixels fills N = the next 2^n+1 and the other keeps the aspect ratio in pixels
    (``int(N / (W / H))``), the data sits in the top-left (north-west) corner, padded at the
    lowest height, and heights are absolute (pose z 0) when ``size.z`` = max - min of that
    raster. Loaded pixel k is vertex k s, vertices ``size / vertSize`` apart.
    """
    from lxml import etree

    rows, cols = dem.shape
    n = max(_gz_side(cols), _gz_side(rows))
    if cols > rows:
        dest_w = n
        dest_h = int(np.float32(n) / (np.float32(cols) / np.float32(rows)))
    else:
        dest_h = n
        dest_w = int(np.float32(n) / (np.float32(rows) / np.float32(cols)))
    dest_w, dest_h = max(dest_w, 1), max(dest_h, 1)
    # GDAL RasterIO nearest neighbour: destination pixel k reads source pixel
    # floor((k + 0.5) * source / destination). Raster rows run north first.
    ci = np.minimum(((np.arange(dest_w) + 0.5) * cols / dest_w + 1e-10).astype(int), cols - 1)
    ri = np.minimum(((np.arange(dest_h) + 0.5) * rows / dest_h + 1e-10).astype(int), rows - 1)
    loaded = dem.heights[::-1][np.ix_(ri, ci)]
    valid = dem.valid[::-1][np.ix_(ri, ci)]
    z_lo, z_hi = float(loaded[valid].min()), float(loaded[valid].max())
    sx, sy = dem.extent[0] / dest_w, dem.extent[1] / dest_h
    s = sdf.DEFAULT_SAMPLING[GZ] if cfg.world.sampling is None else cfg.world.sampling
    vert = n * s - s + 1
    size = (sx * vert / s, sy * vert / s, (z_hi - z_lo) or 1.0)
    # The field's centre is loaded pixel (n - 1) / 2, counted from the north-west corner.
    centre = (-dem.extent[0] / 2 + n * sx / 2, dem.extent[1] / 2 - n * sy / 2)
    hm = Heightmap(np.zeros((n, n), np.uint8), sx, centre, 0.0, size[2], (0, 0), (rows, cols))
    p = sdf.Placement(GZ, name, s, size, (0.0, 0.0))
    tif = f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', source.stem) or 'dem'}.tif"
    text = (
        f" Generated by scan2terrain from {source.name}: gz-sim >= 7 (gz-common built with GDAL)"
        " loads the GeoTIFF itself.\n Heights are absolute: size.z = max - min of the raster"
        " gz-common loads, pose z = 0.\n" + comment
    )
    model = etree.fromstring(
        sdf.model_sdf(hm, p, levels=(z_lo, (z_lo + z_hi) / 2, z_hi), comment=text)
    )
    for uri in model.iter("uri"):
        parent = uri.getparent()
        if parent is not None and parent.tag == "heightmap":
            uri.text = f"model://{name}/{tif}"
    files = {
        f"models/{name}/{tif}": source.read_bytes(),
        f"models/{name}/model.sdf": etree.tostring(
            model, pretty_print=True, xml_declaration=True, encoding="UTF-8"
        ),
        f"models/{name}/model.config": sdf.model_config(p, f"Terrain from {source.name} (DEM)"),
        "world_gz_dem.sdf": sdf.world_sdf(p, world_name="scan2terrain", comment=text),
    }
    for fname, data in sdf.texture_pngs().items():
        files[f"models/{name}/{sdf.TEXTURE_DIR}/{fname}"] = data
    return files


def _gz_side(k: int) -> int:
    """gz-common's DEM side for k pixels (``Dem::Load``): k when k - 1 is a power of two, else
    the next power of two >= k, plus one."""
    if k > 1 and (k - 1) & (k - 2) == 0:
        return k
    return (1 << max(0, (k - 1).bit_length())) + 1


# --- writing ---------------------------------------------------------------------------------


def heightmap_only(cfg: Config, what: str) -> Config:
    """``cfg`` for inputs that are heights, not occupancy (``world.geometry`` auto resolved);
    refuses wall geometries and what no heightmap can be (:func:`heightmap_options`)."""
    cfg = cfg.for_grid("heights")
    heightmap_options(cfg)
    if cfg.world.geometry != "heightmap":
        raise ConfigError(
            f"world.geometry {cfg.world.geometry} needs an occupancy grid (map2world, or"
            f" octree/bag/cloud2world with octree.grid occupancy); {what} makes heightmaps only"
        )
    return cfg


def refuse_large_grid(
    source: Path, what: str, rows: int, cols: int, *, resolution: float, cfg: Config
) -> None:
    """Refuse a grid of ``rows`` x ``cols`` cells over ``max_pixels`` before it is allocated
    (the octree's and the streamed path's, from the ``what`` it spans)."""
    if rows * cols > cfg.max_pixels:
        raise ConfigError(
            f"{source}: the {what} span {cols} x {rows} cells of {resolution:g} m, over"
            f" max_pixels {cfg.max_pixels}: choose a coarser --resolution (files in different"
            " coordinate systems also spread this far)"
        )


def grid_options(cfg: Config) -> None:
    """Before any work, for the commands whose grid comes from voxels or points (octree2world,
    bag2world, cloud2world): refuse what the world they will write cannot be."""
    grid = "occupancy" if cfg.octree.grid == "occupancy" else "heights"
    if cfg.for_grid(grid).world.geometry == "heightmap":
        heightmap_options(cfg)


def minus(name: str, v: float) -> str:
    """``name`` minus ``v``, written for a human: 'x - 29.125', 'x + 0.125', or 'x' for 0."""
    if v == 0:
        return name
    return f"{name} - {v!r}" if v > 0 else f"{name} + {-v!r}"


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


def model_name_for(source: Path, hm: Heightmap, cfg: Config) -> str:
    """A readable, unique, deterministic name: input stem + digest of the terrain itself.

    Gazebo Classic caches terrain by model name (~/.gazebo/paging/<name>); a new terrain must never
    reuse the name of an old one. The digest covers what the cache holds, the pixels and their
    scale and placement, not unrelated options, and not the PNG bytes (they depend on zlib).
    """
    geometry = repr((hm.resolution, hm.centre, hm.z_min, hm.z_range, cfg.world.sampling))
    return _unique_name(source, hm.pixels.tobytes() + geometry.encode(), cfg)


def terrain_name(source: Path, terrain: Terrain, cfg: Config) -> str:
    """:func:`model_name_for` one heightmap; for tiles, the prefix of every tile's model name
    (``<prefix>_<row>_<col>``), from a digest of the heights and of everything that turns them
    into pixels and places them (the tiles' pixels follow from those)."""
    if isinstance(terrain, Heightmap):
        return model_name_for(source, terrain, cfg)
    t = terrain
    scale = (t.resolution, t.origin, t.z_min, t.z_range, t.max_side, t.bit_depth, t.pad_height)
    geometry = repr((*scale, t.grid_shape, cfg.world.sampling))
    heights = hashlib.sha256(np.ascontiguousarray(t.heights).data).digest()
    return _unique_name(source, heights + geometry.encode(), cfg)


def _unique_name(source: Path, content: bytes, cfg: Config) -> str:
    """``world.model_name``, else input stem + the first 8 hex digits of sha256(content)."""
    if cfg.world.model_name:
        return cfg.world.model_name
    stem = re.sub(r"[^A-Za-z0-9]+", "_", source.stem).strip("_").lower() or "terrain"
    return f"{stem}_{hashlib.sha256(content).hexdigest()[:8]}"


def _write(
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    source: Path,
    hm: Terrain,
    levels: tuple[float, float, float],
    map_out: OccupancyGrid | None,
    preview: Preview,
    spawn: Spawn,
    extra: dict[str, bytes] | None = None,
    comment_extra: str = "",
) -> Result:
    if isinstance(hm, TiledHeightmap):
        return _write_tiled(
            out,
            cfg,
            overwrite=overwrite,
            source=source,
            tiled=hm,
            levels=levels,
            map_out=map_out,
            preview=preview,
            extra=extra,
            comment_extra=comment_extra,
            spawn=spawn,
        )
    # z where Gazebo puts the ground: the image's quantised heights, not the grid's.
    spawn = dataclasses.replace(spawn, z=hm.ground_max(spawn.x, spawn.y, FOOTPRINT / 2))
    png = hm.png()
    base_name = model_name_for(source, hm, cfg)
    sims = (GZ, CLASSIC) if cfg.world.simulator == "both" else (cfg.world.simulator,)
    result = Result(
        out=out, heightmap_side=hm.side, resolution=hm.resolution, size_z=hm.z_range, spawn=spawn
    )
    result.notes.extend(_map_notes(cfg, map_out))
    parts = []
    for sim in sims:
        name = base_name if sim == GZ or len(sims) == 1 else f"{base_name}_classic"
        p = sdf.placement_for(hm, sim, name, cfg.world.sampling)
        comment = _comment(source, hm, p) + comment_extra
        textures = f"models/{name}/{sdf.TEXTURE_DIR}"
        files = {f"{textures}/{sdf.HEIGHTMAP_FILE}": png}
        if sim == GZ:
            files.update({f"{textures}/{f}": data for f, data in sdf.texture_pngs().items()})
        files[f"models/{name}/model.sdf"] = sdf.model_sdf(hm, p, levels=levels, comment=comment)
        files[f"models/{name}/model.config"] = sdf.model_config(p, f"Terrain from {source.name}")
        # Classic keeps the heightmap's 0 at world z = 0 (no pose); gz-sim at z_min.
        pose = spawn_pose(spawn, p.offset, 0.0 if sim == GZ else hm.z_min)
        world = sdf.world_sdf(
            p, world_name="scan2terrain", comment=comment + spawn_comment(spawn, pose)
        )
        parts.append(SimWorld(p, files, world, p.offset, comment, pose))
    folder = WorldFolder(source, result, parts, map_out, preview, extra or {})
    return write_world_folder(folder, out, cfg, overwrite=overwrite)


def _write_tiled(
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    source: Path,
    tiled: TiledHeightmap,
    levels: tuple[float, float, float],
    map_out: OccupancyGrid | None,
    preview: Preview,
    extra: dict[str, bytes] | None,
    comment_extra: str,
    spawn: Spawn,
) -> Result:
    """Terrain tiles: one model per tile (models/<name>_<row>_<col>/), one gz-sim world that
    includes them all. Gazebo Classic is refused (``world.simulator: classic``) or left out with
    a note (``both``): it renders one heightmap per scene, always at the world origin."""
    rows, cols = tiled.shape
    h, w = tiled.grid_shape
    r = tiled.resolution
    what = (
        f"a {h}x{w}-sample terrain is over terrain.max_side {tiled.max_side} and becomes"
        f" {rows}x{cols} heightmap tiles"
    )
    classic_why = (
        "Gazebo Classic renders only one heightmap per world (gazebo-classic rendering/Scene.cc:"
        " 'Only one Heightmap can be created per Scene') and cannot move a heightmap away from"
        " the world origin (gazebo-classic #2167)"
    )
    if cfg.world.simulator == CLASSIC:
        raise ConfigError(
            f"{what}, and {classic_why}: use --simulator gz, a coarser resolution, or a larger"
            " terrain.max_side (2^n+1, in a --config file)"
        )
    base = terrain_name(source, tiled, cfg)
    s = sdf.DEFAULT_SAMPLING[GZ] if cfg.world.sampling is None else cfg.world.sampling
    result = Result(
        out=out,
        heightmap_side=tiled.side,
        resolution=r,
        size_z=tiled.span,
        tiles=(rows, cols),
        spawn=spawn,
    )
    result.notes.append(
        f"Terrain: {h}x{w} samples at {r:g} m/px, over terrain.max_side {tiled.max_side}: "
        f"{rows}x{cols} heightmap tiles models/{base}_<row>_<col>/ (row 0 = lowest y), "
        "neighbours sharing their border samples; gz-sim only."
    )
    if cfg.world.simulator == "both":
        result.notes.append(f"Gazebo Classic world not written: {classic_why}.")
    result.notes.extend(_map_notes(cfg, map_out))
    world_comment = _tiled_comment(source, tiled, base) + comment_extra
    textures = sdf.texture_pngs()
    files: dict[str, bytes] = {}
    placements = []
    for spec, hm in tiled.tiles():
        name = f"{base}_{spec.row}_{spec.col}"
        p = sdf.placement_for(hm, GZ, name, cfg.world.sampling)
        folder = f"models/{name}"
        files[f"{folder}/{sdf.TEXTURE_DIR}/{sdf.HEIGHTMAP_FILE}"] = hm.png()
        files.update({f"{folder}/{sdf.TEXTURE_DIR}/{f}": data for f, data in textures.items()})
        comment = _tile_comment(source, tiled, spec, hm) + comment_extra
        files[f"{folder}/model.sdf"] = sdf.model_sdf(hm, p, levels=levels, comment=comment)
        description = f"Terrain tile ({spec.row}, {spec.col}) from {source.name}"
        files[f"{folder}/model.config"] = sdf.model_config(p, description)
        placements.append(p)
    pose = spawn_pose(spawn, (0.0, 0.0), 0.0)
    world = sdf.tiled_world_sdf(
        placements, world_name="scan2terrain", comment=world_comment + spawn_comment(spawn, pose)
    )
    whole = sdf.Placement(GZ, base, s, (w * r, h * r, tiled.span), (0.0, 0.0))
    part = SimWorld(whole, files, world, (0.0, 0.0), world_comment, pose)
    plan = WorldFolder(source, result, [part], map_out, preview, extra or {})
    return write_world_folder(plan, out, cfg, overwrite=overwrite)


@dataclass(frozen=True)
class SimWorld:
    """One simulator's share of a world folder: its models' files and its world file."""

    placement: sdf.Placement  #: where the terrain or walls sit (for the report)
    files: dict[str, bytes]  #: relative path (models/<name>/...) -> bytes
    world: bytes  #: the world file (world_gz.sdf or world_classic.world)
    map_offset: tuple[float, float]  #: map frame -> this world's frame, for map/*.yaml
    comment: str  #: what the map YAMLs say about where they come from
    spawn: tuple[float, float, float, float, float, float]  #: the spawn pose in this world


@dataclass(frozen=True)
class WorldFolder:
    """Everything a world folder holds, computed; :func:`write_world_folder` writes it."""

    source: Path
    result: Result  #: the report so far (notes are added to, never replaced)
    worlds: list[SimWorld]
    map_out: OccupancyGrid | None  #: the navigation map in world axes, or None
    preview: Preview
    extra: dict[str, bytes]  #: more files at the top (octree.bt, occupied voxels)


def write_world_folder(folder: WorldFolder, out: Path, cfg: Config, *, overwrite: bool) -> Result:
    """The one writer of world folders, atomically: map/, each simulator's models and world,
    spawn.yaml, preview, extra files, the effective config. Returns the completed report."""
    result = folder.result
    with atomic_output(out, overwrite=overwrite) as od:
        _write_map_pgm(od, cfg, folder.map_out)
        for part in folder.worlds:
            sim = part.placement.simulator
            for rel, data in part.files.items():
                od.write(rel, data)
            world = od.write(WORLD_FILES[sim], part.world)
            yamls = _write_map_yaml(
                od, cfg, folder.map_out, sim=sim, offset=part.map_offset, comment=part.comment
            )
            result.worlds.append(
                _world_output(part.placement, world, out / "models", yamls, part.spawn)
            )
        _write_tail(
            od, result, cfg, source=folder.source, preview=folder.preview, extra=folder.extra
        )
    return result


def _world_output(
    p: sdf.Placement,
    world: Path,
    models: Path,
    yamls: tuple[Path, ...],
    spawn: tuple[float, float, float, float, float, float],
) -> WorldOutput:
    if len(yamls) == 1:
        return WorldOutput(p, world, models, yamls[0], spawn=spawn)
    return WorldOutput(p, world, models, None, yamls, spawn=spawn)


# --- spawn pose ------------------------------------------------------------------------------


def spawn_for(
    heights: NDArray[np.floating],
    resolution: float,
    origin: Pose2D,
    start: Start | None,
    *,
    ground: NDArray[np.bool_] | None = None,
    free: NDArray[np.bool_] | None = None,
) -> Spawn:
    """The spawn spot of a world's ground (map frame; see grids/spawn.py): searched from the
    robot's recorded start when there is one, else from the map origin (or the centre)."""
    if start is None:
        return find_spawn(heights, resolution, origin, ground=ground, free=free)
    p = start.pose
    return find_spawn(
        heights, resolution, origin, preferred=(p.x, p.y), yaw=p.yaw, ground=ground,
        free=free, why=start.why,
    )  # fmt: skip


def spawn_pose(
    spawn: Spawn, offset: tuple[float, float], z_offset: float
) -> tuple[float, float, float, float, float, float]:
    """The spawn spot in one world's frame: (x, y, z, roll, pitch, yaw), map minus offsets,
    rounded to the millimetre (and milliradian) for files and commands."""
    return (
        round(spawn.x - offset[0], 3) + 0.0,
        round(spawn.y - offset[1], 3) + 0.0,
        round(spawn.z - z_offset, 3) + 0.0,
        0.0,
        0.0,
        round(spawn.yaw, 3) + 0.0,
    )


def spawn_comment(spawn: Spawn, pose: tuple[float, ...]) -> str:
    x, y, z, _, _, yaw = pose
    return (
        f" Spawn a robot at x={x:g} y={y:g} z={z:g} yaw={yaw:g} (this world's frame; z is the"
        f" ground, see spawn.yaml): {spawn.why}.\n"
    )


def _spawn_yaml(result: Result) -> bytes:
    """spawn.yaml: the spawn pose in every world of the folder, and how it was chosen."""
    import yaml

    assert result.spawn is not None
    doc: dict[str, object] = {"why": result.spawn.why}
    for w in result.worlds:
        if w.spawn is not None:
            doc[w.placement.simulator] = {"world": w.world.name, "pose": list(w.spawn)}
    header = (
        "# Where to spawn a robot in each world of this folder (scan2terrain): pose is\n"
        "# [x, y, z, roll, pitch, yaw] in that world's frame (metres, radians); z is the\n"
        "# highest ground under a 1.5 x 1.5 m footprint, so a robot whose model origin is at\n"
        "# its lowest point rests there.\n"
    )
    return (header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)).encode()


def _map_parts(cfg: Config, map_out: OccupancyGrid) -> list[tuple[str, OccupancyGrid]]:
    """(file stem, grid) of the map/ image(s): ``map`` when the map fits
    ``output.map_max_side``, else ``map_<row>_<col>`` tiles (row 0 = lowest y)."""
    parts = map_export.map_tiles(map_out, cfg.output.map_max_side)
    if len(parts) == 1:
        return [("map", map_out)]
    return [(f"map_{i}_{j}", tile) for i, j, tile in parts]


def _map_notes(cfg: Config, map_out: OccupancyGrid | None) -> list[str]:
    if map_out is None or not cfg.output.map_yaml:
        return []
    rows, cols = map_out.shape
    m = cfg.output.map_max_side
    if rows <= m and cols <= m:
        return []
    return [
        f"Map: {rows}x{cols} cells, over output.map_max_side {m}: written as "
        f"{-(-rows // m)}x{-(-cols // m)} tiles map/map_<row>_<col>.pgm (row 0 = lowest y), "
        "each with map_<row>_<col>_<simulator>.yaml placing it in that world."
    ]


def _write_map_pgm(od: OutputDir, cfg: Config, map_out: OccupancyGrid | None) -> None:
    if map_out is not None and cfg.output.map_yaml:
        for stem, part in _map_parts(cfg, map_out):
            od.write(f"map/{stem}.pgm", map_export.map_pgm(part))


def _write_map_yaml(
    od: OutputDir,
    cfg: Config,
    map_out: OccupancyGrid | None,
    *,
    sim: str,
    offset: tuple[float, float],
    comment: str,
) -> tuple[Path, ...]:
    """map/map_<sim>.yaml: the filtered map with its origin in that simulator's world frame; for
    a tiled map, map/map_<row>_<col>_<sim>.yaml per tile, each with its own tile's origin."""
    if map_out is None or not cfg.output.map_yaml:
        return ()
    parts = _map_parts(cfg, map_out)
    written = []
    for stem, part in parts:
        # map_out is in world axes (grids.axis_align): its yaw, and each tile's, is 0.
        shifted = part.with_data(
            part.data, Pose2D(part.origin.x - offset[0], part.origin.y - offset[1], 0.0)
        )
        about = f"Filtered map in the {sim} world frame.\n"
        if len(parts) > 1:
            about = (
                f"Tile {stem} of the filtered map (rows, columns from the lowest y, x; up to"
                f" {cfg.output.map_max_side} cells a side) in the {sim} world frame.\n"
            )
        name = f"map/{stem}_{sim}.yaml"
        text = map_export.map_yaml(shifted, f"{stem}.pgm", comment=about + comment)
        written.append(od.write(name, text))
    return tuple(written)


def _write_tail(
    od: OutputDir,
    result: Result,
    cfg: Config,
    *,
    source: Path,
    preview: Preview,
    extra: dict[str, bytes] | None,
) -> None:
    """Preview, extra files and the effective config, as every command writes them."""
    import yaml

    if cfg.output.preview:
        result.preview = od.write("preview.png", preview.png)
        result.preview_label = preview.label
    if result.spawn is not None and result.worlds:
        od.write(SPAWN_FILE, _spawn_yaml(result))
    for name, data in (extra or {}).items():
        path = od.write(name, data)
        about = EXTRA_ABOUT.get(Path(name).stem)
        if about is not None:
            result.notes.append(f"{about}: {path}")
    header = f"# Effective scan2terrain config for {source.name}; reuse with --config.\n"
    body = yaml.safe_dump(cfg.to_dict(), sort_keys=False)
    result.config = od.write(CONFIG_FILE, (header + body).encode())


def _tiled_comment(source: Path, tiled: TiledHeightmap, base: str) -> str:
    rows, cols = tiled.shape
    h, w = tiled.grid_shape
    return (
        f" Generated by scan2terrain from {source.name}.\n"
        f" Terrain of {h}x{w} samples at {tiled.resolution!r} m/px as {rows}x{cols} heightmap"
        f" tiles of up to {tiled.max_side}x{tiled.max_side} px (terrain.max_side): models"
        f" {base}_<row>_<col>, row 0 = lowest y, column 0 = lowest x; tile (i, j) holds the"
        f" samples from row i*{tiled.max_side - 1}, column j*{tiled.max_side - 1}, so neighbours"
        " share their border samples. One scale for every tile: pixel 0 at"
        f" {tiled.z_min!r} m, full scale at {tiled.z_min + tiled.z_range!r} m (levels 0 and 1"
        " unused: gz-common reads a pixel of value 1 as white).\n"
        " gz-sim: map frame (x, y) = world (x, y). Each tile's collision <pose> and visual <pos>"
        " carry its offset (gz-sim #1295, #1803). Gazebo Classic cannot show tiled terrain"
        " (one heightmap per scene, at the world origin).\n"
    )


def _tile_comment(source: Path, tiled: TiledHeightmap, spec: TileSpec, hm: Heightmap) -> str:
    rows, cols = tiled.shape
    h, w = tiled.grid_shape
    return (
        f" Generated by scan2terrain from {source.name}.\n"
        f" Terrain tile ({spec.row}, {spec.col}) of {rows}x{cols} (row 0 = lowest y): grid"
        f" samples rows {spec.r0}..{spec.r0 + spec.rows - 1}, columns"
        f" {spec.c0}..{spec.c0 + spec.cols - 1} of {h}x{w}, shared at the borders with the"
        f" neighbouring tiles. Heightmap {hm.side}x{hm.side} px, {hm.resolution!r} m/px, pixel"
        f" 0 at {hm.z_min!r} m, brightest pixel at {hm.z_min + hm.z_range!r} m (size.z = its"
        " height; every tile shares one scale, full scale at"
        f" {tiled.z_min + tiled.z_range!r} m).\n"
        " gz-sim: map frame (x, y) = world (x, y). Collision <pose> and visual <pos> carry the"
        " offset (gz-sim #1295, #1803).\n"
    )


def _comment(source: Path, hm: Heightmap, p: sdf.Placement) -> str:
    lines = [
        f" Generated by scan2terrain from {source.name}.",
        f" Heightmap {hm.side}x{hm.side} px, {hm.resolution!r} m/px, heights {hm.z_min!r}"
        f" .. {hm.z_min + hm.z_range!r} m (size.z = height of the brightest pixel).",
    ]
    if p.simulator == GZ:
        lines.append(
            " gz-sim: map frame (x, y) = world (x, y). Collision <pose> and visual <pos>"
            " carry the offset (gz-sim #1295, #1803)."
        )
    else:
        lines.append(
            " Gazebo Classic keeps heightmaps at the world origin (#2167): map point (x, y) is"
            f" world ({minus('x', p.offset[0])}, {minus('y', p.offset[1])}). Spawn the robot"
            " there, or use"
            " map/map_classic.yaml, which is already shifted."
        )
    return "\n".join(lines) + "\n"
