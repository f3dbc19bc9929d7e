"""The world folder: what a command writes, computed as a :class:`WorldFolder` and written by
:func:`write_world_folder`, the one writer (atomically: map/, each simulator's models and world,
spawn.yaml, preview, extra files, the effective config), and the :class:`Result` it reports,
built by adding notes, never by replacing them.

The world builders (``world/terrain.py``, ``walls.py``, ``voxels.py``) and the commands' grid
steps return a :class:`WorldFolder` and write nothing; each command adds what it read
(:meth:`WorldFolder.noted`) and its extra files (:meth:`WorldFolder.with_extra`), then calls the
writer once."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, cast

from scan2terrain.config import Config
from scan2terrain.exporters import mapserver as map_export
from scan2terrain.exporters import sdf
from scan2terrain.exporters.heightmap import CLASSIC, GZ
from scan2terrain.exporters.output import MARKER, OutputDir, atomic_output
from scan2terrain.exporters.robot import MODEL_FILES, ROBOT_DIR, robot_files
from scan2terrain.readers.world import Simulator, WorldGeometry, read_world
from scan2terrain.types import (
    OccupancyGrid,
    Pose2D,
    Spawn,
)
from scan2terrain.world.georef import georeference
from scan2terrain.world.preview import Preview, preview3d

WORLD_FILES = {GZ: "world_gz.sdf", CLASSIC: "world_classic.world"}


CONFIG_FILE = MARKER  # scan2terrain.yaml: what marks a folder --overwrite may replace


SPAWN_FILE = "spawn.yaml"
PREVIEW3D_FILE = "preview3d.png"


#: What the extra files a command writes beside the world are, for the report (by stem).
EXTRA_ABOUT = {
    "octree": "the octree, as OctoMap's .bt (octovis, octomap_server, octree2world)",
    "occupied_voxels": "the occupied voxels' centres",
    "trajectory": "the trajectory (TUM: t x y z qx qy qz qw, what --trajectory reads)",
    "trajectory_raw": "the trajectory as recorded, before correction (TUM)",
    "fidelity.yaml": "the recording replayed in the world(s), figures",
    "fidelity.png": "where the replayed beams end, by error",
    "fidelity_ends.ply": "each replayed beam's end point and error (PLY: x y z error)",
}


@dataclass(frozen=True)
class WrittenWorld:
    """One simulator's world as written in the output folder (a :class:`SimWorld`, computed,
    once it is on disk), for the report.

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
    #: The folder's ready robot for this simulator (robot/model_<sim>.sdf), or None.
    robot: Path | None = None


@dataclass
class Result:
    """What a command wrote, for the CLI to report."""

    out: Path = Path()  #: the folder written (set by :func:`write_world_folder`)
    worlds: list[WrittenWorld] = field(default_factory=list)
    heightmap_side: int = 0
    resolution: float = 0.0
    size_z: float = 0.0
    preview: Path | None = None
    preview3d: Path | None = None  #: the oblique picture of the first world's collisions
    config: Path | None = None
    notes: list[str] = field(default_factory=list)  #: what was read and chosen, for the report
    geometry: str = "heightmap"  #: world.geometry of the worlds written
    walls: str = ""  #: for wall geometries: what the walls are made of, for the report
    tiles: tuple[int, int] = (1, 1)  #: heightmap tiles along y and x (terrain.max_side)
    spawn: Spawn | None = None  #: where a robot can start, map frame (each world's: worlds)
    preview_label: str = ""  #: what preview.png shows, for the report
    no_world: str = ""  #: why the folder holds no world (a bag with nothing to map), or ""
    headline: str = ""  #: what the folder holds when it is no world's (the fidelity command)


@dataclass(frozen=True)
class SimWorld:
    """One simulator's share of a world folder: its models' files and its world file."""

    placement: sdf.Placement  #: where the terrain or walls sit (for the report)
    files: dict[str, bytes]  #: relative path (models/<name>/...) -> bytes
    world: bytes  #: the world file (world_gz.sdf or world_classic.world)
    map_offset: tuple[float, float]  #: map frame -> this world's frame, for map/*.yaml
    comment: str  #: what the map YAMLs say about where they come from
    spawn: tuple[float, float, float, float, float, float]  #: the spawn pose in this world
    z_offset: float = 0.0  #: map z -> this world's z (Classic's heightmap zero)

    @property
    def name(self) -> str:
        """The world file's name in the folder."""
        return WORLD_FILES[self.placement.simulator]

    def collisions(self) -> WorldGeometry:
        """Its collision triangles in its frame, read back from its bytes as the simulator's
        physics gets them (:func:`~scan2terrain.readers.world.read_world`)."""
        simulator = cast("Simulator", self.placement.simulator)
        files = {**self.files, self.name: self.world}
        return read_world(Path(self.name), simulator=simulator, files=files)


class Derived(Protocol):
    """Files made from the worlds as computed, before anything is written (the replay of a
    recording in them: ``commands/replay.py``)."""

    def files(self, worlds: Sequence[SimWorld]) -> tuple[dict[str, bytes], list[str]]:
        """The files (name -> bytes) and the report's notes."""
        ...


#: Files written beside the world (octree.bt, occupied voxels), by name: their bytes, a Future
#: of them being made on another thread while the world is built (the writer waits for it), or
#: a :class:`Derived` maker of files from the worlds (its name is only a key).
ExtraFiles = Mapping[str, "bytes | Future[bytes] | Derived"]


@dataclass(frozen=True)
class WorldFolder:
    """Everything a world folder holds, computed; :func:`write_world_folder` writes it."""

    source: Path
    result: Result  #: the report so far (notes are added to, never replaced)
    worlds: list[SimWorld]
    map_out: OccupancyGrid | None  #: the navigation map in world axes, or None
    preview: Preview | None  #: None: nothing to preview (no world)
    extra: ExtraFiles  #: more files at the top (octree.bt, occupied voxels)
    #: The effective config the worlds were built with (``auto`` values resolved), written as
    #: scan2terrain.yaml.
    cfg: Config

    def noted(self, first: Sequence[str] = (), then: Sequence[str] = ()) -> WorldFolder:
        """The folder with ``first`` put before the report's notes (what was read before the
        world was built) and ``then`` after them."""
        self.result.notes[:0] = first
        self.result.notes.extend(then)
        return self

    def with_extra(self, extra: ExtraFiles, *, before: bool = False) -> WorldFolder:
        """The folder with more files at the top (``before``: listed before its own)."""
        both = {**extra, **self.extra} if before else {**self.extra, **extra}
        return dataclasses.replace(self, extra=both)


def write_world_folder(folder: WorldFolder, out: Path, *, overwrite: bool) -> Result:
    """The one writer of world folders, atomically: map/, each simulator's models and world,
    spawn.yaml, preview, extra files, the effective config. Returns the completed report."""
    result, cfg = folder.result, folder.cfg
    result.out = out
    if result.spawn is not None and not result.spawn.ground:
        result.notes.append(f"Spawn: {result.spawn.why} (spawn.yaml)")
    extra = _derived(folder, result)
    # preview3d.png is drawn on another thread while the files are written (numpy lets go of
    # the GIL): the same bytes, a third less time added to a command.
    with ThreadPoolExecutor(max_workers=1) as pool, atomic_output(out, overwrite=overwrite) as od:
        picture = None
        if cfg.output.preview and folder.worlds:
            first = folder.worlds[0]
            picture = pool.submit(lambda: preview3d(first.collisions(), first.spawn))
        _write_map_pgm(od, cfg, folder.map_out)
        # robot/: the ready robot, a model file for each simulator the folder has a world for.
        sims = [part.placement.simulator for part in folder.worlds]
        robot = {rel: od.write(rel, data) for rel, data in robot_files(sims).items()}
        for part in folder.worlds:
            sim = part.placement.simulator
            for rel, data in part.files.items():
                od.write(rel, data)
            world = od.write(WORLD_FILES[sim], part.world)
            yamls = _write_map_yaml(
                od, cfg, folder.map_out, sim=sim, offset=part.map_offset, comment=part.comment
            )
            model = robot.get(f"{ROBOT_DIR}/{MODEL_FILES[sim]}")
            result.worlds.append(
                _world_output(part.placement, world, out / "models", yamls, part.spawn, model)
            )
        if picture is not None:
            result.preview3d = od.write(PREVIEW3D_FILE, picture.result())
        _write_tail(od, result, cfg, source=folder.source, preview=folder.preview, extra=extra)
        made = od.made
    if made:
        result.notes.append(
            f"Created the missing folder{'s' if len(made) > 1 else ''} "
            f"{', '.join(map(str, made))} for the output"
        )
    return result


def _derived(folder: WorldFolder, result: Result) -> dict[str, bytes | Future[bytes]]:
    """The extra files, each :class:`Derived` maker's made from the folder's worlds (its
    notes added to the report)."""
    out: dict[str, bytes | Future[bytes]] = {}
    for name, data in (folder.extra or {}).items():
        if isinstance(data, (bytes, Future)):
            out[name] = data
            continue
        files, notes = data.files(folder.worlds)
        out.update(files)
        result.notes.extend(notes)
    return out


def _world_output(
    p: sdf.Placement,
    world: Path,
    models: Path,
    yamls: tuple[Path, ...],
    spawn: tuple[float, float, float, float, float, float],
    robot: Path | None,
) -> WrittenWorld:
    if len(yamls) == 1:
        return WrittenWorld(p, world, models, yamls[0], spawn=spawn, robot=robot)
    return WrittenWorld(p, world, models, None, yamls, spawn=spawn, robot=robot)


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


def sim_world(
    placement: sdf.Placement,
    files: dict[str, bytes],
    *,
    cfg: Config,
    comment: str,
    spawn: Spawn,
    offset: tuple[float, float] = (0.0, 0.0),
    z_offset: float = 0.0,
    placements: Sequence[sdf.Placement] = (),
) -> SimWorld:
    """One simulator's share of a world folder, whose frame is the map frame less ``offset``
    (x, y) and ``z_offset``: its models' ``files``, and the world file that includes
    ``placements`` (default: ``placement``'s model) with ``comment``, the georeference
    (:func:`~scan2terrain.world.georef.georeference`) and the spawn pose in that frame; the map
    YAMLs repeat the comment and the georeference."""
    where, anchor = georeference(cfg, offset, z_offset)
    pose = spawn_pose(spawn, offset, z_offset)
    world = sdf.tiled_world_sdf(
        list(placements) or [placement],
        world_name="scan2terrain",
        comment=comment + where + spawn_comment(spawn, pose),
        anchor=anchor,
    )
    return SimWorld(placement, files, world, offset, comment + where, pose, z_offset)


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
    preview: Preview | None,
    extra: Mapping[str, bytes | Future[bytes]],
) -> None:
    """Preview, extra files and the effective config, as every command writes them."""
    import yaml

    if cfg.output.preview and preview is not None:
        result.preview = od.write("preview.png", preview.png)
        result.preview_label = preview.label
    if result.spawn is not None and result.worlds:
        od.write(SPAWN_FILE, _spawn_yaml(result))
    for name, data in extra.items():
        path = od.write(name, data if isinstance(data, bytes) else data.result())
        about = EXTRA_ABOUT.get(name, EXTRA_ABOUT.get(Path(name).stem))
        if about is not None:
            result.notes.append(f"{about}: {path}")
    header = f"# Effective scan2terrain config for {source.name}; reuse with --config.\n"
    body = yaml.safe_dump(cfg.to_dict(), sort_keys=False)
    result.config = od.write(CONFIG_FILE, (header + body).encode())
