"""Terrain worlds: one heightmap model (:func:`terrain_folder`) or tiles placed edge to edge
(:func:`tiles_folder`), each simulator's model folder and world, as a
:class:`~scan2terrain.world.folder.WorldFolder` for the one writer."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from scan2terrain.config import Config
from scan2terrain.errors import ConfigError
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import CLASSIC, GZ, Heightmap
from scan2terrain.exporters.tiles import Terrain, TiledHeightmap, TileSpec
from scan2terrain.grids.spawn import FOOTPRINT
from scan2terrain.texts import minus
from scan2terrain.types import (
    OccupancyGrid,
    Spawn,
)
from scan2terrain.world.folder import Result, WorldFolder, map_notes, sim_world
from scan2terrain.world.names import model_name_for, terrain_name
from scan2terrain.world.preview import Preview


def terrain_folder(
    cfg: Config,
    *,
    source: Path,
    hm: Terrain,
    levels: tuple[float, float, float],
    map_out: OccupancyGrid | None,
    preview: Preview,
    spawn: Spawn,
    comment_extra: str = "",
) -> WorldFolder:
    """A heightmap (or its tiles) as each simulator's model and world."""
    if isinstance(hm, TiledHeightmap):
        return tiles_folder(
            cfg,
            source=source,
            tiled=hm,
            levels=levels,
            map_out=map_out,
            preview=preview,
            comment_extra=comment_extra,
            spawn=spawn,
        )
    # z where Gazebo puts the ground: the image's quantised heights, not the grid's.
    spawn = dataclasses.replace(spawn, z=hm.ground_max(spawn.x, spawn.y, FOOTPRINT / 2))
    png = hm.png()
    base_name = model_name_for(source, hm, cfg)
    sims = (GZ, CLASSIC) if cfg.world.simulator == "both" else (cfg.world.simulator,)
    result = Result(
        heightmap_side=hm.side, resolution=hm.resolution, size_z=hm.z_range, spawn=spawn
    )
    result.notes.extend(map_notes(cfg, map_out))
    parts = []
    for sim in sims:
        name = base_name if sim == GZ or len(sims) == 1 else f"{base_name}_classic"
        p = sdf.placement_for(hm, sim, name, cfg.world.sampling)
        comment = _comment(source, hm, p) + comment_extra
        # Classic ships its own terrain textures; gz-sim's come with the model.
        textures = sdf.texture_pngs() if sim == GZ else {}
        about = f"Terrain from {source.name}"
        files = _terrain_model(
            hm, png, p, levels=levels, comment=comment, about=about, textures=textures
        )
        # Classic keeps the heightmap's 0 at world z = 0 (no pose); gz-sim at z_min.
        z_offset = 0.0 if sim == GZ else hm.z_min
        parts.append(
            sim_world(
                p, files, cfg=cfg, comment=comment, spawn=spawn, offset=p.offset,
                z_offset=z_offset,
            )
        )  # fmt: skip
    return WorldFolder(source, result, parts, map_out, preview, {}, cfg)


def tiles_folder(
    cfg: Config,
    *,
    source: Path,
    tiled: TiledHeightmap,
    levels: tuple[float, float, float],
    map_out: OccupancyGrid | None,
    preview: Preview,
    comment_extra: str,
    spawn: Spawn,
) -> WorldFolder:
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
    result.notes.extend(map_notes(cfg, map_out))
    world_comment = _tiled_comment(source, tiled, base) + comment_extra
    textures = sdf.texture_pngs()
    files: dict[str, bytes] = {}
    placements = []
    for spec, hm in tiled.tiles():
        name = f"{base}_{spec.row}_{spec.col}"
        p = sdf.placement_for(hm, GZ, name, cfg.world.sampling)
        comment = _tile_comment(source, tiled, spec, hm) + comment_extra
        about = f"Terrain tile ({spec.row}, {spec.col}) from {source.name}"
        files.update(
            _terrain_model(
                hm, hm.png(), p, levels=levels, comment=comment, about=about, textures=textures
            )
        )
        placements.append(p)
    whole = sdf.Placement(GZ, base, s, (w * r, h * r, tiled.span), (0.0, 0.0))
    part = sim_world(
        whole, files, cfg=cfg, comment=world_comment, spawn=spawn, placements=placements
    )
    return WorldFolder(source, result, [part], map_out, preview, {}, cfg)


def _terrain_model(
    hm: Heightmap,
    png: bytes,
    p: sdf.Placement,
    *,
    levels: tuple[float, float, float],
    comment: str,
    about: str,
    textures: dict[str, bytes],
) -> dict[str, bytes]:
    """The files of one terrain model folder (models/<p.model_name>/): the heightmap PNG, the
    ``textures``, model.sdf and model.config (``about`` its description)."""
    folder = f"models/{p.model_name}"
    files = {f"{folder}/{sdf.TEXTURE_DIR}/{sdf.HEIGHTMAP_FILE}": png}
    files.update({f"{folder}/{sdf.TEXTURE_DIR}/{f}": data for f, data in textures.items()})
    files[f"{folder}/model.sdf"] = sdf.model_sdf(hm, p, levels=levels, comment=comment)
    files[f"{folder}/model.config"] = sdf.model_config(p, about)
    return files


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
