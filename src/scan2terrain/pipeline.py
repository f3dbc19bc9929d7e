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
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import GZ, Heightmap
from scan2terrain.exporters.tiles import TiledHeightmap
from scan2terrain.filters import (
    median_filter,
)
from scan2terrain.filters.unknown import occupancy_to_heights, unknown_level
from scan2terrain.grids import (
    axis_align,
    invert_occupancy,
)
from scan2terrain.steps import (
    Terrain,
    classify,
    fill_holes,
    filter_grey,
    filter_occupancy,
    filtering,
    grid_options,
    heightmap_only,
    heightmap_options,
    heightmap_or_tiles,
    make_preview,
    minus,
    new_tree,
    place_on_canvas,
    refuse_existing,
    refuse_large_grid,
    spawn_for,
    terrain_layout,
)
from scan2terrain.types import (
    FREE,
    UNKNOWN,
    HeightGrid,
    OccupancyGrid,
    Pose2D,
    Start,
)
from scan2terrain.world import (
    Result,
    terrain_name,
    walls_world,
    write_terrain,
)

if TYPE_CHECKING:
    from scan2terrain.octree.tree import VoxelOctree
    from scan2terrain.readers.dem import Dem
    from scan2terrain.readers.scans import ScanCounts


#: Called after every scan: (counts so far, scans expected in total, 0 when unknown).
#: Called after every scan: (counts so far, scans expected in total, 0 when unknown).
ScanProgress = Callable[["ScanCounts", int], None]


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
    return write_terrain(
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


def build_octree(source: Path, cfg: Config, progress: ScanProgress | None = None) -> VoxelOctree:
    """Ray-cast every scan of an OctoMap text scan file into a new octree."""
    from scan2terrain.readers.octomap_scan import read_scans
    from scan2terrain.readers.scans import ScanCounts

    o = cfg.octree
    tree = new_tree(cfg)
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
    return write_terrain(
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
    return write_terrain(
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
    result = write_terrain(
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
