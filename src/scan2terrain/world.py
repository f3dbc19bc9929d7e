"""The world folder: what a command writes, computed as a :class:`WorldFolder` and written by
:func:`write_world_folder`, the one writer (atomically: map/, each simulator's models and world,
spawn.yaml, preview, extra files, the effective config), and the :class:`Result` it reports.

Terrain (:func:`write_terrain`: one heightmap, or tiles with :func:`write_tiles`) and walls
(:func:`walls_world`: mesh, boxes, polylines) each make their models and worlds; the names are
unique per content (:func:`model_name_for`)."""

from __future__ import annotations

import dataclasses
import hashlib
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters import mapserver as map_export
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import CLASSIC, GZ, Heightmap
from scan2terrain.exporters.output import OutputDir, atomic_output
from scan2terrain.exporters.tiles import TiledHeightmap, TileSpec
from scan2terrain.grids import (
    axis_align,
)
from scan2terrain.grids.spawn import FOOTPRINT
from scan2terrain.steps import Preview, Terrain, filter_text, minus, spawn_for
from scan2terrain.types import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    OccupancyGrid,
    Pose2D,
    Spawn,
    Start,
)

WORLD_FILES = {GZ: "world_gz.sdf", CLASSIC: "world_classic.world"}
CONFIG_FILE = "scan2terrain.yaml"
SPAWN_FILE = "spawn.yaml"
#: What the extra files a command writes beside the world are, for the report (by stem).
EXTRA_ABOUT = {
    "octree": "the octree, as OctoMap's .bt (octovis, octomap_server, octree2world)",
    "occupied_voxels": "the occupied voxels' centres",
}


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
        f" ({filter_text(cfg)}), as {made.summary}.\n"
        " Map frame (x, y) = world (x, y), in gz-sim and in Gazebo Classic alike: the model sits"
        " at the world origin and the geometry is written in map coordinates (unlike a"
        " heightmap, meshes, boxes and polylines can be placed anywhere).\n"
    )
    payload = repr((kind, cfg.world.simplify, t.height, r, origin, walls.shape)).encode()
    base_name = unique_name(source, walls.tobytes() + payload, cfg)
    aligned, world_origin = axis_align(grid.data, origin, r, fill=UNKNOWN)
    map_out = OccupancyGrid(aligned, r, world_origin)
    sims = (GZ, CLASSIC) if cfg.world.simulator == "both" else (cfg.world.simulator,)
    result = Result(
        out=out, resolution=r, size_z=t.height, geometry=kind, walls=made.summary, spawn=spawn
    )
    result.notes.extend(map_notes(cfg, map_out))
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


def model_name_for(source: Path, hm: Heightmap, cfg: Config) -> str:
    """A readable, unique, deterministic name: input stem + digest of the terrain itself.

    Gazebo Classic caches terrain by model name (~/.gazebo/paging/<name>); a new terrain must never
    reuse the name of an old one. The digest covers what the cache holds, the pixels and their
    scale and placement, not unrelated options, and not the PNG bytes (they depend on zlib).
    """
    geometry = repr((hm.resolution, hm.centre, hm.z_min, hm.z_range, cfg.world.sampling))
    return unique_name(source, hm.pixels.tobytes() + geometry.encode(), cfg)


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
    return unique_name(source, heights + geometry.encode(), cfg)


def unique_name(source: Path, content: bytes, cfg: Config) -> str:
    """``world.model_name``, else input stem + the first 8 hex digits of sha256(content)."""
    if cfg.world.model_name:
        return cfg.world.model_name
    stem = re.sub(r"[^A-Za-z0-9]+", "_", source.stem).strip("_").lower() or "terrain"
    return f"{stem}_{hashlib.sha256(content).hexdigest()[:8]}"


def write_terrain(
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
        return write_tiles(
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
        pose = spawn_pose(spawn, p.offset, 0.0 if sim == GZ else hm.z_min)
        world = sdf.world_sdf(
            p, world_name="scan2terrain", comment=comment + spawn_comment(spawn, pose)
        )
        parts.append(SimWorld(p, files, world, p.offset, comment, pose))
    folder = WorldFolder(source, result, parts, map_out, preview, extra or {})
    return write_world_folder(folder, out, cfg, overwrite=overwrite)


def write_tiles(
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
    pose = spawn_pose(spawn, (0.0, 0.0), 0.0)
    world = sdf.tiled_world_sdf(
        placements, world_name="scan2terrain", comment=world_comment + spawn_comment(spawn, pose)
    )
    whole = sdf.Placement(GZ, base, s, (w * r, h * r, tiled.span), (0.0, 0.0))
    part = SimWorld(whole, files, world, (0.0, 0.0), world_comment, pose)
    plan = WorldFolder(source, result, [part], map_out, preview, extra or {})
    return write_world_folder(plan, out, cfg, overwrite=overwrite)


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


def map_notes(cfg: Config, map_out: OccupancyGrid | None) -> list[str]:
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
