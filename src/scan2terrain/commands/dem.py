"""dem2world: read GeoTIFF -> square pixels, DEM centre at the origin -> canvas/filter ->
heights above the lowest -> 16-bit heightmap at z = lowest elevation -> worlds, preview; and
the optional passthrough world that loads the GeoTIFF itself (gz-sim >= 7 with GDAL)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from lxml import etree

from scan2terrain.checks import heightmap_only, refuse_existing
from scan2terrain.config import Config
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import GZ, Heightmap
from scan2terrain.exporters.tiles import Terrain, TiledHeightmap
from scan2terrain.filters.median import median_filter
from scan2terrain.grids import canvas as grid_canvas
from scan2terrain.readers.dem import read_dem
from scan2terrain.steps import terrain_of
from scan2terrain.texts import minus
from scan2terrain.types import HeightGrid
from scan2terrain.world.folder import Result, write_world_folder
from scan2terrain.world.names import terrain_name
from scan2terrain.world.preview import filtering, grey8, make_preview
from scan2terrain.world.spawn import spawn_for, terrain_around
from scan2terrain.world.terrain import terrain_folder

if TYPE_CHECKING:
    from scan2terrain.readers.dem import Dem


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

    refuse_existing(out, overwrite, (dem_path,))
    cfg = heightmap_only(cfg, "dem2world")
    t = cfg.terrain
    if cfg.canvas.invert:
        raise ConfigError("canvas.invert (--invert) has no meaning for a DEM")
    source = Path(dem_path)
    dem = read_dem(
        source,
        pixel_size=cfg.dem.resolution,
        max_pixels=cfg.max_pixels,
        max_elevation=cfg.dem.max_elevation,
    )
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
    hm = terrain_of(
        HeightGrid(above.astype(np.float32), np.ones(above.shape, dtype=bool), res, origin),
        cfg,
        pad_height=0.0,
    )
    # make_heightmap puts 0 at min(0, lowest) = 0 here; the ground's 0 is the lowest elevation.
    # Tiles keep their pixels (0 two levels below the lowest) and are raised by it.
    hm = hm.raised(z0) if isinstance(hm, TiledHeightmap) else dataclasses.replace(hm, z_min=z0)
    notes = _dem_notes(source, dem, res, hm, with_classic=cfg.world.simulator != GZ)
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
    folder = terrain_folder(
        cfg,
        source=source,
        hm=hm,
        # Texture blend heights, in the heightmap's own heights (0 = its lowest point).
        levels=(0.0, hm.z_range / 2, hm.z_range),
        map_out=None,
        preview=make_preview(grey8(before, z0, top), grey8(heights, z0, top), cfg, occupancy=False),
        comment_extra="".join(f" {n}\n" for n in notes),
        spawn=spawn_for(
            above + np.float32(z0),
            res,
            origin,
            None,
            samples=True,
            around=terrain_around(hm, 1, z0),
        ),
    )
    folder = folder.noted(then=notes).with_extra(extra)
    return write_world_folder(folder, out, overwrite=overwrite)


def _dem_notes(source: Path, dem: Dem, res: float, hm: Terrain, *, with_classic: bool) -> list[str]:
    """What was read and where it went: for the report and the SDF comments (Gazebo
    Classic's frame only when a Classic world is written)."""
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
        classic = f"; in Gazebo Classic z = {minus('elevation', hm.z_min)} m" * with_classic
        lines.append(
            f"z = elevation in gz-sim (heightmap 0 at {hm.z_min!r} m, size.z {hm.z_range!r} m)"
            f"{classic}."
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
