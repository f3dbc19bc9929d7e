"""The options, declared once per group and attached to every command that takes it (each sets a
config value, ``dest="section.key"``; choices come from the config's vocabulary). Each is
declared through :class:`Options`, which ends its help with that command's real default."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from scan2terrain.config import (
    BIT_DEPTHS,
    CORRECT_MODES,
    FILLS,
    FILTERS,
    GEOMETRIES,
    GRID_KINDS,
    HEIGHT_STATS,
    INSERT_MODES,
    POSE_SOURCES,
    SIMULATORS,
    TOP_LEVEL_KEYS,
    UNKNOWN_POLICIES,
    VOXEL_POINTS,
    WALL_FACES,
    Config,
)
from scan2terrain.fileio import is_url
from scan2terrain.filters.registry import FILTERS as FILTER_REGISTRY


class Options:
    """Where one command's options are declared: its parser (or one of its groups) and its
    effective defaults (the config's, after the command's own). An option that sets a config
    value gets ``(default: X)`` appended to its help, X being what the command really uses
    (one source: help cannot drift from behaviour; options whose default is None say in their
    own words what happens without them), and its flag recorded in :attr:`flags`."""

    def __init__(
        self,
        target: argparse.ArgumentParser | argparse._ArgumentGroup,
        defaults: Config,
        flags: dict[str, str] | None = None,
    ) -> None:
        self._target = target
        self.defaults = defaults
        #: Config key -> the flag that sets it (its longest), for error messages.
        self.flags: dict[str, str] = {} if flags is None else flags

    def group(self, title: str) -> Options:
        """A titled group of this command's options, in its --help."""
        return Options(self._target.add_argument_group(title), self.defaults, self.flags)

    def add(self, *names: str, **kw: Any) -> None:
        """``add_argument``, with the default stated for a config option."""
        dest = kw.get("dest", "")
        if names[0].startswith("-") and ("." in dest or dest in TOP_LEVEL_KEYS):
            self.flags.setdefault(dest, max(names, key=len))
            value: Any = self.defaults
            for part in dest.split("."):
                value = getattr(value, part)
            if value is not None and kw.get("help") and kw.get("action") != "store_const":
                kw["help"] = f"{kw['help']} (default: {_shown(value)})"
        self._target.add_argument(*names, **kw)


def _shown(value: object) -> str:
    power = isinstance(value, int) and value >= 1 << 20 and value & (value - 1) == 0
    return f"2^{value.bit_length() - 1}" if power and isinstance(value, int) else str(value)


def run_options(o: Options) -> None:
    """-v and -q: every command takes them."""
    o.add("-v", "--verbose", action="store_true", help="show tracebacks on failure")
    o.add("-q", "--quiet", action="store_true", help="print nothing on success")


def view_options(o: Options) -> None:
    """Where ``view`` serves, and whether it opens a browser."""
    o.add(
        "--host",
        default="127.0.0.1",
        help="address to serve on (default: 127.0.0.1, this "
        "machine only; 0.0.0.0 serves every network the machine is on)",
    )
    o.add("--port", type=int, default=8080, help="port to serve on (default: 8080)")
    o.add("--no-browser", action="store_true", help="only print the URL; do not open a browser")


def config_option(o: Options) -> None:
    o.add("--config", type=Path, help="YAML config file (see configs/); flags override it")


def out_options(o: Options) -> None:
    """The output folder of a command that writes one."""
    o.add("-o", "--out", type=Path, required=True, help="output folder (must not exist)")
    overwrite_option(o)


def overwrite_option(o: Options) -> None:
    o.add("--overwrite", action="store_true", help="replace an existing output (folder or file)")


def simulator_option(o: Options, *, both: bool = True) -> None:
    """Whose SDF a world is written for, or (``both`` False: fidelity) built by."""
    o.add(
        "--simulator",
        choices=SIMULATORS if both else tuple(s for s in SIMULATORS if s != "both"),
        dest="world.simulator",
        help="whose SDF the world is written in, or read as (gz: gz-sim's SDF 1.9; classic: "
        "Gazebo Classic's SDF 1.6); where a heightmap lies and how it is sampled follow it",
    )


def max_range_option(o: Options) -> None:
    """The sensor's range (every command that reads scans)."""
    o.add(
        "--max-range",
        type=float,
        dest="octree.max_range",
        help="metres: longer beams are cut there and only clear free space; bag hits beyond "
        "are dropped (< 0: unlimited)",
    )


def common(o: Options, *, heights: bool = True) -> None:
    """Options every world command takes; ``heights``: the grid's heights are set by the user
    (--height, --invert), which a DEM's elevations are not."""
    out_options(o)
    config_option(o)
    g = o.group("world")
    simulator_option(g)
    g.add(
        "--model-name",
        dest="world.model_name",
        help="terrain model name (default: input name + content digest, unique)",
    )
    g.add(
        "--sampling",
        type=int,
        dest="world.sampling",
        help="heightmap vertex sampling (default: 1 for gz, 2 for classic)",
    )
    t = o.group("terrain")
    if heights:
        t.add(
            "--height",
            type=float,
            dest="terrain.height",
            help="metres: wall height (maps) or height of white (images)",
        )
    t.add(
        "--upsample",
        type=int,
        dest="terrain.upsample",
        help="integer factor: each cell becomes k x k pixels",
    )
    t.add(
        "--bit-depth",
        type=int,
        choices=BIT_DEPTHS,
        dest="terrain.bit_depth",
        help="heightmap PNG depth; 16 needs gz-sim Garden or newer",
    )
    c = o.group("canvas (the paper's options, in cells)")
    c.add(
        "--width",
        type=int,
        dest="canvas.width",
        help="crop or extend to this width (default: the input's)",
    )
    c.add(
        "--canvas-height",
        type=int,
        dest="canvas.height",
        help="crop or extend to this height (default: the input's)",
    )
    c.add(
        "--offset-x",
        type=int,
        dest="canvas.offset_x",
        help="shift the input right by this many cells (negative crops)",
    )
    c.add(
        "--offset-y",
        type=int,
        dest="canvas.offset_y",
        help="shift the input up by this many cells (negative crops)",
    )
    if heights:
        c.add(
            "--invert",
            action="store_const",
            const=True,
            dest="canvas.invert",
            help="swap free and occupied (maps) or black and white (images)",
        )
    f = o.group("filter")
    f.add(
        "--filter",
        choices=FILTERS,
        dest="filter.kind",
        help="none: off; " + "; ".join(f"{k}: {f.help}" for k, f in FILTER_REGISTRY.items()),
    )
    f.add(
        "--no-filter",
        action="store_const",
        const=False,
        dest="filter.enabled",
        help="turn filtering off",
    )
    f.add(
        "--filter-size",
        type=int,
        dest="filter.size",
        help="window side for median/majority (odd)",
    )
    f.add(
        "--speckle-min-cells",
        type=int,
        dest="filter.speckle_min_cells",
        help="remove occupied specks smaller than this many cells (0: off)",
    )
    out = o.group("output")
    out.add(
        "--no-preview",
        action="store_const",
        const=False,
        dest="output.preview",
        help="do not write preview.png",
    )
    out.add("--max-pixels", type=int, dest="max_pixels", help="refuse larger images and grids")
    run_options(o)


def fidelity_option(o: Options) -> None:
    """The replay of the recording in the world (commands that build a world from scans)."""
    g = o.group("fidelity (a world made from scans)")
    g.add(
        "--no-fidelity",
        action="store_const",
        const=False,
        dest="output.fidelity",
        help="do not replay the recorded beams in the written world (fidelity.yaml, "
        "fidelity.png, fidelity_ends.ply and the report's fidelity line)",
    )


def geometry_options(o: Options, *, voxels: bool = True) -> None:
    """Options of the commands whose grid is occupancy (walls), not heights; ``voxels``: the
    command holds voxels (an octree), so --geometry voxels is offered."""
    g = o.group("walls (occupancy grids)")
    g.add(
        "--geometry",
        choices=GEOMETRIES if voxels else tuple(k for k in GEOMETRIES if k != "voxels"),
        dest="world.geometry",
        help="how occupied cells become walls: one extruded mesh (STL/DAE/OBJ; exact, and the "
        "fastest in physics), the fewest boxes that cover them, SDF polylines, or a heightmap "
        "(slowest; 1-cell walls are knife edges); auto: mesh for occupancy grids, "
        "heightmap for height grids; "
        + ("voxels: the occupied voxels themselves in 3D, overhangs and doorways kept; " * voxels)
        + "map frame = world frame in both simulators for all but heightmap (README: which "
        "geometry to pick)",
    )
    g.add(
        "--simplify",
        type=float,
        dest="world.simplify",
        help="metres: straighten mesh/polyline outlines within this tolerance, keeping every "
        "cell on its side (0: cell edges)",
    )
    g.add(
        "--wall-faces",
        choices=WALL_FACES,
        dest="world.wall_faces",
        help="where mesh/boxes/polylines walls put their faces: on the cell boundaries, or "
        "half a cell into the wall toward observed free space, where a scan's end points lie "
        "on average (a wall seen from one side keeps half a cell, one seen from both its cells)",
    )


def cloud_filter_options(o: Options) -> None:
    """Clean-up of cloud files before they are used (cloud2world, convert)."""
    g = o.group("cloud files")
    g.add(
        "--las-classes",
        type=int,
        nargs="+",
        metavar="CLASS",
        dest="scans.las_classes",
        help="LAS/LAZ classes to keep, e.g. 2 for ground (default: all)",
    )
    g.add(
        "--outliers",
        type=float,
        metavar="SD",
        dest="scans.outliers",
        help="drop statistical outliers: points whose mean distance to their nearest neighbours "
        "is over the mean + SD standard deviations (e.g. 2; default: off)",
    )
    g.add(
        "--outlier-neighbours",
        type=int,
        dest="scans.outlier_neighbours",
        help="neighbours each point's mean distance is taken over, for --outliers",
    )


class _LocalOrigin(argparse.Action):
    """--local-origin auto | none | X Y Z."""

    def __call__(self, parser: Any, namespace: Any, values: Any, option: Any = None) -> None:
        if values in (["auto"], ["none"]):
            setattr(namespace, self.dest, values[0])
            return
        try:
            xyz = [float(v) for v in values]
        except ValueError:
            xyz = []
        if len(xyz) != 3:
            parser.error(f"argument --local-origin: expected auto, none or X Y Z, not {values}")
        setattr(namespace, self.dest, xyz)


def georef_options(o: Options) -> None:
    """Where georeferenced clouds (UTM, state plane) are on the earth (cloud2world)."""
    g = o.group("georeference")
    g.add(
        "--local-origin",
        nargs="+",
        action=_LocalOrigin,
        metavar="ORIGIN",
        dest="scans.local_origin",
        help="subtracted from the clouds' coordinates: auto (their rounded centre, when they "
        "lie beyond 1 km of 0), none, or this point (the effective config records the one used)",
    )
    g.add(
        "--crs",
        dest="scans.crs",
        metavar="CRS",
        help="the clouds' projected CRS (EPSG:32610, WKT, ...), for <spherical_coordinates> in "
        "the worlds (default: a LAS/LAZ file's own)",
    )


def voxel_options(o: Options) -> None:
    """Options of --geometry voxels (the commands that hold voxels)."""
    g = o.group("voxels (--geometry voxels)")
    g.add(
        "--chunk",
        type=float,
        dest="world.chunk",
        help="metres: the voxel mesh is cut into cubes this size, one collision and visual each",
    )
    g.add(
        "--voxel-size",
        type=float,
        dest="world.voxel_size",
        help="metres: mesh coarser voxels, the octree's resolution times a power of two "
        "(a coarse voxel is occupied if any of its voxels is; default: the octree's)",
    )
    g.add(
        "--max-triangles",
        type=int,
        dest="world.max_triangles",
        help="refuse a voxel world of more triangles than this",
    )
    g.add(
        "--min-voxels",
        type=int,
        dest="world.min_voxels",
        help="leave out occupied voxels in 3D components (26-connected) of fewer voxels "
        "(0: keep all)",
    )


def unknown_options(o: Options) -> None:
    """What unknown cells of an occupancy grid become (every command that makes one)."""
    o.add(
        "--unknown",
        choices=UNKNOWN_POLICIES,
        dest="terrain.unknown",
        help="unknown cells as floor, as walls, or at --unknown-height",
    )
    o.add(
        "--unknown-height",
        type=float,
        dest="terrain.unknown_height",
        help="metres, for --unknown height",
    )


def octree_options(o: Options) -> None:
    t = o.group("octree and grid")
    t.add(
        "--max-memory",
        type=int,
        dest="max_memory",
        metavar="MIB",
        help="refuse an octree or a grid from voxels or points that would need more memory (MiB)",
    )
    t.add(
        "--resolution",
        type=float,
        dest="octree.resolution",
        help="voxel side in metres for scan input (cloud2world's default: 0.05, or for a "
        "survey wider than terrain.max_side - 1 cells of that, the coarser of its side over "
        "those cells and twice its mean point spacing)",
    )
    max_range_option(t)
    t.add(
        "--z-min",
        type=float,
        dest="octree.z_min",
        help="lowest voxel centre (metres) that counts for the 2D grid (default: no limit)",
    )
    t.add(
        "--z-max",
        type=float,
        dest="octree.z_max",
        help="highest voxel centre (metres) that counts for the 2D grid (default: no limit)",
    )
    t.add(
        "--grid",
        choices=GRID_KINDS,
        dest="octree.grid",
        help="occupancy (octomap_server's projection) or height (2.5D)",
    )
    unknown_options(t)
    t.add(
        "--height-stat",
        choices=HEIGHT_STATS,
        dest="octree.height_stat",
        help="--grid height: each column's highest, lowest or mean occupied z",
    )
    t.add(
        "--fill",
        choices=FILLS,
        dest="octree.fill",
        help="--grid height: fill empty columns from the nearest known one, by inverse "
        "distance weighting, or not",
    )
    t.add(
        "--fill-max-distance",
        type=float,
        dest="octree.fill_max_distance",
        help="metres: nearest fill leaves columns farther than this from a known one empty "
        "(default: 4 cells, at least 1 m)",
    )
    t.add(
        "--points",
        choices=VOXEL_POINTS,
        dest="octree.points",
        help="also write the occupied voxel centres as occupied_voxels.ply / .pcd",
    )


def scan_options(o: Options, *, bag: bool, insert: bool = True) -> None:
    """How scans are read and posed; ``insert``: the command inserts them into an octree."""
    s = o.group("scans and poses")
    if bag:
        s.add(
            "--topic",
            action="append",
            dest="scans.topics",
            help="scan topic (LaserScan/PointCloud2, repeatable) or one OccupancyGrid topic "
            "(default: the only sensible one)",
        )
        s.add(
            "--start",
            type=float,
            dest="scans.start",
            help="seconds from the bag's start, or absolute UNIX seconds (default: the start)",
        )
        s.add("--end", type=float, dest="scans.end", help="as --start (default: the end)")
        s.add(
            "--poses",
            choices=POSE_SOURCES,
            dest="scans.poses",
            help="where scan poses come from (auto: tf, else odometry)",
        )
        s.add(
            "--correct",
            choices=CORRECT_MODES,
            dest="scans.correct",
            help="correct the poses by scan matching and loop closure (auto: when they are "
            "odometry only, kept if the beams agree better; on: any poses; off: as recorded)",
        )
        s.add(
            "--fixed-frame",
            dest="scans.fixed_frame",
            help="frame to build the world in (default: map if present, else odom)",
        )
        s.add(
            "--odom-topic",
            dest="scans.odom_topic",
            help="nav_msgs/Odometry topic (poses odom; default: the only one)",
        )
        s.add(
            "--trajectory",
            dest="scans.trajectory",
            help="TUM trajectory file of the robot base (t x y z qx qy qz qw; default: none)",
        )
        s.add(
            "--mount",
            type=float,
            nargs=6,
            metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
            dest="scans.mount",
            help="sensor pose on the robot base (odometry/trajectory poses; default from "
            "/tf_static, else identity)",
        )
        s.add(
            "--max-gap",
            type=float,
            dest="scans.max_gap",
            help="longest tf/odometry gap, seconds, to interpolate across",
        )
    s.add(
        "--pose",
        type=float,
        nargs=6,
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        dest="scans.pose",
        help="a stationary sensor's pose in the fixed frame (metres, radians; default: none)",
    )
    if not insert:
        return
    s.add(
        "--insert",
        choices=INSERT_MODES,
        dest="scans.insert",
        help="raycast: free space too (OctoMap's insertPointCloud); endpoints: hits only, fast "
        "(auto: raycast for bags, endpoints for cloud files)",
    )


def path_or_url(text: str) -> Path | str:
    """A URL stays a string (Path would fold its '//')."""
    return text if is_url(text) else Path(text)


def stream_options(o: Options) -> None:
    g = o.group(
        "streaming and Dask (end points straight into grid tiles, no octree; memory bounded by "
        "the grid)"
    )
    g.add(
        "--stream",
        action="store_const",
        const=True,
        dest="stream.enabled",
        help="stream end points into tiles instead of the octree (clouds larger than memory)",
    )
    g.add(
        "--workers",
        type=int,
        dest="stream.workers",
        metavar="N",
        help="run the streamed work on a local Dask cluster of N worker processes",
    )
    g.add(
        "--scheduler",
        dest="stream.scheduler",
        metavar="ADDRESS",
        help="run the streamed work on an existing Dask cluster (tcp://HOST:8786; default: "
        "none); its workers must reach the input paths",
    )
    g.add(
        "--chunk-points",
        type=int,
        dest="stream.chunk_points",
        metavar="N",
        help="points read at a time",
    )
    g.add(
        "--tile-cells",
        type=int,
        dest="stream.tile_cells",
        metavar="N",
        help="grid tile side in cells, a power of two",
    )


def progress_option(o: Options) -> None:
    o.add(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )
