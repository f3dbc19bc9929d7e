"""Named steps composed into the commands. Only this module and cli.py know every stage.

map2world:   read map YAML -> classify -> invert/canvas -> filter -> align to world axes
             -> heights (unknown policy) -> heightmap -> model + world per simulator, map, preview
image2world: read image -> luminance -> invert/canvas -> filter -> align -> heights -> ... (same)
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.errors import InputError
from scan2terrain.exporters import mapserver as map_export
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import CLASSIC, GZ, Heightmap, make_heightmap
from scan2terrain.exporters.output import OutputDir, atomic_output
from scan2terrain.exporters.preview import preview_png
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
from scan2terrain.types import UNKNOWN, HeightGrid, OccupancyGrid, Pose2D

if TYPE_CHECKING:
    from scan2terrain.octree.tree import VoxelOctree

ScalarT = TypeVar("ScalarT", bound=np.generic)

WORLD_FILES = {GZ: "world_gz.sdf", CLASSIC: "world_classic.world"}
CONFIG_FILE = "scan2terrain.yaml"


@dataclass(frozen=True)
class WorldOutput:
    """One simulator's world inside the output folder."""

    placement: sdf.Placement
    world: Path
    models: Path
    map_yaml: Path | None


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


# --- steps -----------------------------------------------------------------------------------


def filter_occupancy(trinary: NDArray[np.int8], cfg: Config) -> NDArray[np.int8]:
    """Apply the configured filter and speckle removal to a trinary grid."""
    f = cfg.filter
    if not f.enabled or (f.kind == "none" and f.speckle_min_cells <= 1):
        return trinary
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
    f = cfg.filter
    if not f.enabled or f.kind == "none":
        return values
    return _apply_filter(values, f.kind, f.size, fallback="median")


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

    refuse_existing(out, overwrite)
    meta, grid = read_map_yaml(yaml_path, max_pixels=cfg.max_pixels)
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
) -> Result:
    """A trinary occupancy grid to a world folder: invert/canvas -> filter -> align -> heights
    (unknown policy) -> heightmap -> worlds, map_server map, preview. ``extra`` files (relative
    name -> bytes) are written into the same folder."""
    trinary = invert_occupancy(grid.data) if cfg.canvas.invert else grid.data
    trinary, origin = place_on_canvas(trinary, grid.origin, grid.resolution, cfg, fill=UNKNOWN)
    filtered = filter_occupancy(trinary, cfg)

    aligned, world_origin = axis_align(filtered, origin, grid.resolution, fill=UNKNOWN)
    t = cfg.terrain
    heights = occupancy_to_heights(
        aligned, wall_height=t.height, policy=t.unknown, unknown_height=t.unknown_height
    )
    pad = unknown_level(t.unknown, wall_height=t.height, unknown_height=t.unknown_height)
    hm = terrain_heightmap(heights, grid.resolution, world_origin, cfg, pad_height=pad)
    return _write(
        out,
        cfg,
        overwrite=overwrite,
        source=source,
        hm=hm,
        levels=(0.0, pad, t.height),
        map_out=OccupancyGrid(aligned, grid.resolution, world_origin),
        preview=preview_png(trinary, filtered, occupancy=True),
        extra=extra,
    )


def octree2world(source: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """An OctoMap ``.bt`` file, or an OctoMap text scan file (ray-cast into a new octree), to a
    world folder through octomap_server's 2D projection or a 2.5D height grid."""
    from scan2terrain.octree.bt import bt_bytes, read_bt
    from scan2terrain.readers.octomap_scan import is_scan_file

    refuse_existing(out, overwrite)
    source = Path(source)
    extra: dict[str, bytes] = {}
    if is_scan_file(source):
        tree = build_octree(source, cfg)
        keys, occupied = tree.occupied_and_free()
        resolution = tree.resolution
        extra["octree.bt"] = bt_bytes(resolution=resolution, keys=keys, occupied=occupied)
    else:
        bt = read_bt(source)
        keys, occupied = bt.expand()
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
) -> Result:
    """Known voxels (OctoMap keys, occupied or free) to a world folder: octomap_server's 2D
    projection (``octree.grid: occupancy``) or a 2.5D height grid, plus the occupied voxel
    centres when ``octree.points`` asks for them."""
    from scan2terrain.grids import projection

    extra = dict(extra or {})
    if len(keys) == 0:
        raise InputError(source, "the octree holds no known voxel")
    o = cfg.octree
    if o.points != "none":
        from scan2terrain.exporters.pointcloud import points_bytes
        from scan2terrain.octree.keys import key_to_coord

        centres = key_to_coord(keys[occupied], resolution)
        extra[f"occupied_voxels.{o.points}"] = points_bytes(centres, f".{o.points}")
    z_min = -math.inf if o.z_min is None else o.z_min
    z_max = math.inf if o.z_max is None else o.z_max
    if o.grid == "occupancy":
        grid = projection.project_occupancy(keys, occupied, resolution, z_min=z_min, z_max=z_max)
        return occupancy_world(grid, source, out, cfg, overwrite=overwrite, extra=extra)
    stats = projection.column_stats(keys, occupied, resolution, z_min=z_min, z_max=z_max)
    if not stats.known.any():
        raise InputError(source, "no occupied voxel in the z band: nothing to make terrain of")
    heights = stats.to_height_grid(o.height_stat)
    if o.fill == "nearest":
        heights = projection.fill_nearest(heights, max_distance_m=o.fill_max_distance)
    elif o.fill == "idw":
        heights = projection.fill_idw(heights)
    return height_world(heights, source, out, cfg, overwrite=overwrite, extra=extra)


def build_octree(source: Path, cfg: Config) -> VoxelOctree:
    """Ray-cast every scan of an OctoMap text scan file into a new octree."""
    from scan2terrain.octree.tree import SensorModel, VoxelOctree
    from scan2terrain.readers.octomap_scan import read_scans

    o = cfg.octree
    tree = VoxelOctree(
        o.resolution, SensorModel(o.hit, o.miss, o.clamp_min, o.clamp_max, o.occupancy)
    )
    for scan in read_scans(source):
        try:
            tree.insert_scan(scan.points, scan.origin, max_range=o.max_range)
        except InputError as exc:
            raise InputError(source, exc.problem) from None
    return tree


def height_world(
    grid: HeightGrid,
    source: Path,
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    extra: dict[str, bytes] | None = None,
) -> Result:
    """A 2.5D height grid (metres) to a world folder. Unknown cells sit at the lowest known
    height. Filters: the plain median (``filter.size``) when filtering is on, as heights are
    not labels."""
    heights = grid.heights
    known = grid.known
    floor = float(heights[known].min()) if known.any() else 0.0
    filled = np.where(known, heights, floor).astype(np.float32)
    f = cfg.filter
    before = filled
    if f.enabled and f.kind != "none":
        filled = median_filter(filled, size=f.size)
    aligned, world_origin = axis_align(filled, grid.origin, grid.resolution, fill=floor)
    hm = terrain_heightmap(aligned, grid.resolution, world_origin, cfg, pad_height=floor)
    top = float(aligned.max(initial=floor))
    return _write(
        out,
        cfg,
        overwrite=overwrite,
        source=source,
        hm=hm,
        levels=(floor, (floor + top) / 2, top),
        map_out=None,
        preview=preview_png(
            _grey8(before, floor, top), _grey8(filled, floor, top), occupancy=False
        ),
        extra=extra,
    )


def _grey8(heights: NDArray[np.float32], lo: float, hi: float) -> NDArray[np.uint8]:
    span = hi - lo if hi > lo else 1.0
    grey: NDArray[np.uint8] = np.clip(np.rint((heights - lo) / span * 255), 0, 255).astype(np.uint8)
    return grey


def image2world(image_path: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """Any image to a Gazebo world folder: luminance is height, white is ``terrain.height``."""
    from scan2terrain.readers import read_grey_image

    refuse_existing(out, overwrite)
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
    hm = terrain_heightmap(heights, res, world_origin, cfg, pad_height=0.0)
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
        preview=preview_png(values, filtered, occupancy=False),
    )


# --- writing ---------------------------------------------------------------------------------


def refuse_existing(out: Path, overwrite: bool) -> None:
    # Checked before any work so a refused run costs nothing; OutputDir checks again.
    OutputDir.check_target(out, overwrite)


def model_name_for(source: Path, hm: Heightmap, cfg: Config) -> str:
    """A readable, unique, deterministic name: input stem + digest of the terrain itself.

    Gazebo Classic caches terrain by model name (~/.gazebo/paging/<name>); a new terrain must never
    reuse the name of an old one. The digest covers what the cache holds, the pixels and their
    scale and placement, not unrelated options, and not the PNG bytes (they depend on zlib).
    """
    if cfg.world.model_name:
        return cfg.world.model_name
    stem = re.sub(r"[^A-Za-z0-9]+", "_", source.stem).strip("_").lower() or "terrain"
    geometry = repr((hm.resolution, hm.centre, hm.z_min, hm.z_range, cfg.world.sampling))
    digest = hashlib.sha256(hm.pixels.tobytes() + geometry.encode()).hexdigest()[:8]
    return f"{stem}_{digest}"


def _write(
    out: Path,
    cfg: Config,
    *,
    overwrite: bool,
    source: Path,
    hm: Heightmap,
    levels: tuple[float, float, float],
    map_out: OccupancyGrid | None,
    preview: bytes,
    extra: dict[str, bytes] | None = None,
) -> Result:
    import yaml

    png = hm.png()
    base_name = model_name_for(source, hm, cfg)
    sims = (GZ, CLASSIC) if cfg.world.simulator == "both" else (cfg.world.simulator,)
    result = Result(out=out, heightmap_side=hm.side, resolution=hm.resolution, size_z=hm.z_range)
    with atomic_output(out, overwrite=overwrite) as od:
        pgm_name = "map.pgm"
        if map_out is not None and cfg.output.map_yaml:
            od.write(f"map/{pgm_name}", map_export.map_pgm(map_out))
        for sim in sims:
            name = base_name if sim == GZ or len(sims) == 1 else f"{base_name}_classic"
            p = sdf.placement_for(hm, sim, name, cfg.world.sampling)
            comment = _comment(source, hm, p)
            mdir = f"models/{name}"
            od.write(f"{mdir}/{sdf.TEXTURE_DIR}/{sdf.HEIGHTMAP_FILE}", png)
            if sim == GZ:
                for fname, data in sdf.texture_pngs().items():
                    od.write(f"{mdir}/{sdf.TEXTURE_DIR}/{fname}", data)
            od.write(f"{mdir}/model.sdf", sdf.model_sdf(hm, p, levels=levels, comment=comment))
            od.write(f"{mdir}/model.config", sdf.model_config(p, f"Terrain from {source.name}"))
            world = od.write(
                WORLD_FILES[sim], sdf.world_sdf(p, world_name="scan2terrain", comment=comment)
            )
            map_yaml = None
            if map_out is not None and cfg.output.map_yaml:
                shifted = map_out.with_data(
                    map_out.data,
                    Pose2D(map_out.origin.x - p.offset[0], map_out.origin.y - p.offset[1], 0.0),
                )
                map_yaml = od.write(
                    f"map/map_{sim}.yaml",
                    map_export.map_yaml(
                        shifted,
                        pgm_name,
                        comment=f"Filtered map in the {sim} world frame.\n{comment}",
                    ),
                )
            result.worlds.append(WorldOutput(p, world, out / "models", map_yaml))
        if cfg.output.preview:
            result.preview = od.write("preview.png", preview)
        for name, data in (extra or {}).items():
            od.write(name, data)
        header = f"# Effective scan2terrain config for {source.name}; reuse with --config.\n"
        body = yaml.safe_dump(cfg.to_dict(), sort_keys=False)
        result.config = od.write(CONFIG_FILE, (header + body).encode())
    return result


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
            f" world (x - {p.offset[0]!r}, y - {p.offset[1]!r}). Spawn the robot there, or use"
            " map/map_classic.yaml, which is already shifted."
        )
    return "\n".join(lines) + "\n"
