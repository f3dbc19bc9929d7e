"""map2world and image2world, and the two grid-to-world steps every command ends with.

map2world:   read map YAML -> classify -> invert/canvas -> filter -> align to world axes
             -> heights (unknown policy) -> heightmap -> model + world per simulator, map, preview
image2world: read image -> luminance -> invert/canvas -> filter -> align -> heights -> ... (same)
walls:       with world.geometry mesh | boxes | polylines, an occupancy grid's occupied cells
             -> outlines (mesh, polylines) or merged boxes -> one static model per simulator
             (world.walls_folder)

:func:`occupancy_folder` (a trinary grid) and :func:`height_folder` (a 2.5D grid) are how every
command's grid becomes a world folder, computed; each command writes it once
(:func:`~scan2terrain.world.folder.write_world_folder`). Any size: a terrain wider or taller than
``terrain.max_side`` samples is written as heightmap tiles (gz-sim only), and a map wider or
taller than ``output.map_max_side`` cells as map tiles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scan2terrain.checks import heightmap_only, heightmap_options, no_voxels, refuse_existing
from scan2terrain.config import Config
from scan2terrain.filters.median import median_filter
from scan2terrain.filters.unknown import occupancy_to_heights, unknown_level
from scan2terrain.grids import (
    axis_align,
    invert_occupancy,
)
from scan2terrain.readers import read_grey_image, read_map_yaml
from scan2terrain.steps import (
    classify,
    filter_grey,
    filter_occupancy,
    place_on_canvas,
    terrain_layout,
)
from scan2terrain.types import (
    FREE,
    UNKNOWN,
    HeightGrid,
    OccupancyGrid,
    Pose2D,
    StartPose,
)
from scan2terrain.world.folder import Result, WorldFolder, write_world_folder
from scan2terrain.world.preview import filtering, grey8, make_preview
from scan2terrain.world.spawn import spawn_for, terrain_around
from scan2terrain.world.terrain import terrain_folder
from scan2terrain.world.walls import walls_folder


def map2world(yaml_path: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """A map_server map (YAML + image) to a Gazebo world folder. See the module docstring."""

    refuse_existing(out, overwrite, (yaml_path,))
    no_voxels(cfg, "map2world")
    meta, grid = read_map_yaml(yaml_path, max_pixels=cfg.max_pixels)
    refuse_existing(out, overwrite, (meta.image,))  # the image may live elsewhere
    trinary = classify(grid, meta.mode, meta.occupied_thresh, meta.free_thresh)
    folder = occupancy_folder(grid.with_data(trinary), Path(yaml_path), cfg)
    return write_world_folder(folder, out, overwrite=overwrite)


def occupancy_folder(
    grid: OccupancyGrid,
    source: Path,
    cfg: Config,
    *,
    start: StartPose | None = None,
    scans: bool = False,
) -> WorldFolder:
    """A trinary occupancy grid to a world folder: invert/canvas -> filter -> align -> heights
    (unknown policy) -> heightmap -> worlds, map_server map, preview. ``start`` is where the
    robot started (the spawn pose is searched from there; None: from the map origin);
    ``scans``: the grid was made from scans (walls' faces where their end points lie,
    ``world.wall_faces``)."""
    cfg = cfg.for_grid("occupancy", scans=scans)
    if cfg.world.geometry == "heightmap":
        heightmap_options(cfg)
    trinary = invert_occupancy(grid.data) if cfg.canvas.invert else grid.data
    trinary, origin = place_on_canvas(trinary, grid.origin, grid.resolution, cfg, fill=UNKNOWN)
    filtered = filter_occupancy(trinary, cfg)
    if cfg.world.geometry != "heightmap":
        return walls_folder(
            grid.with_data(filtered, origin),
            source,
            cfg,
            preview=make_preview(trinary, filtered, cfg, occupancy=True),
            start=start,
        )

    aligned, world_origin = axis_align(filtered, origin, grid.resolution, fill=UNKNOWN)
    t = cfg.terrain
    heights = occupancy_to_heights(
        aligned, wall_height=t.height, policy=t.unknown, unknown_height=t.unknown_height
    )
    pad = unknown_level(t.unknown, wall_height=t.height, unknown_height=t.unknown_height)
    hm = terrain_layout(heights, grid.resolution, world_origin, cfg, pad_height=pad)
    return terrain_folder(
        cfg,
        source=source,
        hm=hm,
        levels=(0.0, pad, t.height),
        map_out=OccupancyGrid(aligned, grid.resolution, world_origin),
        preview=make_preview(trinary, filtered, cfg, occupancy=True),
        spawn=spawn_for(
            heights,
            grid.resolution,
            world_origin,
            start,
            ground=heights <= 0,
            free=aligned == FREE,
            samples=True,
            # The padding is ground where unknown cells are (terrain.unknown free).
            around=terrain_around(hm, t.upsample, pad) if pad <= 0 else None,
        ),
    )


def height_folder(
    grid: HeightGrid, source: Path, cfg: Config, *, start: StartPose | None = None
) -> WorldFolder:
    """A 2.5D height grid (metres) to a world folder. Unknown cells sit at the lowest known
    height. Filters: the plain median (``filter.size``) when filtering is on, as heights are
    not labels. ``start`` as for :func:`occupancy_folder`."""
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
    return terrain_folder(
        cfg,
        source=source,
        hm=hm,
        levels=(floor, (floor + top) / 2, top),
        map_out=None,
        preview=make_preview(
            grey8(before, floor, top), grey8(filled, floor, top), cfg, occupancy=False
        ),
        spawn=spawn_for(
            aligned,
            grid.resolution,
            world_origin,
            start,
            samples=True,
            around=terrain_around(hm, cfg.terrain.upsample, floor),
        ),
    )


def image2world(image_path: Path, out: Path, cfg: Config, *, overwrite: bool = False) -> Result:
    """Any image to a Gazebo world folder: luminance is height, white is ``terrain.height``."""

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
    folder = terrain_folder(
        cfg,
        source=Path(image_path),
        hm=hm,
        levels=levels,
        map_out=None,
        preview=make_preview(values, filtered, cfg, occupancy=False),
        spawn=spawn_for(
            heights,
            res,
            world_origin,
            None,
            samples=True,
            around=terrain_around(hm, cfg.terrain.upsample, 0.0),
        ),
    )
    return write_world_folder(folder, out, overwrite=overwrite)


# --- walls (world.geometry mesh | boxes | polylines) -----------------------------------------
