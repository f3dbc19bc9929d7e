"""The options, declared once per group and attached to every command that takes it (each sets a
config value, ``dest="section.key"``; choices come from the config's vocabulary, defaults are
added to the help by ``parser._state_defaults``)."""

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
    UNKNOWN_POLICIES,
    VOXEL_POINTS,
    WALL_FACES,
)
from scan2terrain.filters.registry import FILTERS as FILTER_REGISTRY


def common(p: argparse.ArgumentParser, *, heights: bool = True) -> None:
    """Options every world command takes (their defaults are added by :func:`_state_defaults`);
    ``heights``: the grid's heights are set by the user (--height, --invert), which a DEM's
    elevations are not."""
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder (must not exist)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument("--config", type=Path, help="YAML config file (see configs/); flags override it")
    g = p.add_argument_group("world")
    g.add_argument(
        "--simulator",
        choices=SIMULATORS,
        dest="world.simulator",
        help="gz-sim (SDF 1.9), Gazebo Classic (SDF 1.6) or both",
    )
    g.add_argument(
        "--model-name",
        dest="world.model_name",
        help="terrain model name (default: input name + content digest, unique)",
    )
    g.add_argument(
        "--sampling",
        type=int,
        dest="world.sampling",
        help="heightmap vertex sampling (default: 1 for gz, 2 for classic)",
    )
    t = p.add_argument_group("terrain")
    if heights:
        t.add_argument(
            "--height",
            type=float,
            dest="terrain.height",
            help="metres: wall height (maps) or height of white (images)",
        )
    t.add_argument(
        "--upsample",
        type=int,
        dest="terrain.upsample",
        help="integer factor: each cell becomes k x k pixels",
    )
    t.add_argument(
        "--bit-depth",
        type=int,
        choices=BIT_DEPTHS,
        dest="terrain.bit_depth",
        help="heightmap PNG depth; 16 needs gz-sim Garden or newer",
    )
    c = p.add_argument_group("canvas (the paper's options, in cells)")
    c.add_argument(
        "--width",
        type=int,
        dest="canvas.width",
        help="crop or extend to this width (default: the input's)",
    )
    c.add_argument(
        "--canvas-height",
        type=int,
        dest="canvas.height",
        help="crop or extend to this height (default: the input's)",
    )
    c.add_argument(
        "--offset-x",
        type=int,
        dest="canvas.offset_x",
        help="shift the input right by this many cells (negative crops)",
    )
    c.add_argument(
        "--offset-y",
        type=int,
        dest="canvas.offset_y",
        help="shift the input up by this many cells (negative crops)",
    )
    if heights:
        c.add_argument(
            "--invert",
            action="store_const",
            const=True,
            dest="canvas.invert",
            help="swap free and occupied (maps) or black and white (images)",
        )
    f = p.add_argument_group("filter")
    f.add_argument(
        "--filter",
        choices=FILTERS,
        dest="filter.kind",
        help="none: off; " + "; ".join(f"{k}: {f.help}" for k, f in FILTER_REGISTRY.items()),
    )
    f.add_argument(
        "--no-filter",
        action="store_const",
        const=False,
        dest="filter.enabled",
        help="turn filtering off",
    )
    f.add_argument(
        "--filter-size",
        type=int,
        dest="filter.size",
        help="window side for median/majority (odd)",
    )
    f.add_argument(
        "--speckle-min-cells",
        type=int,
        dest="filter.speckle_min_cells",
        help="remove occupied specks smaller than this many cells (0: off)",
    )
    o = p.add_argument_group("output")
    o.add_argument(
        "--no-preview",
        action="store_const",
        const=False,
        dest="output.preview",
        help="do not write preview.png",
    )
    o.add_argument(
        "--max-pixels", type=int, dest="max_pixels", help="refuse larger images and grids"
    )
    p.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on failure")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")


def fidelity_option(p: argparse.ArgumentParser) -> None:
    """The replay of the recording in the world (commands that build a world from scans)."""
    g = p.add_argument_group("fidelity (a world made from scans)")
    g.add_argument(
        "--no-fidelity",
        action="store_const",
        const=False,
        dest="output.fidelity",
        help="do not replay the recorded beams in the written world (fidelity.yaml, "
        "fidelity.png and the report's fidelity line)",
    )


def geometry_options(p: argparse.ArgumentParser, *, voxels: bool = True) -> None:
    """Options of the commands whose grid is occupancy (walls), not heights; ``voxels``: the
    command holds voxels (an octree), so --geometry voxels is offered."""
    g = p.add_argument_group("walls (occupancy grids)")
    g.add_argument(
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
    g.add_argument(
        "--simplify",
        type=float,
        dest="world.simplify",
        help="metres: straighten mesh/polyline outlines within this tolerance, keeping every "
        "cell on its side (0: cell edges)",
    )
    g.add_argument(
        "--wall-faces",
        choices=WALL_FACES,
        dest="world.wall_faces",
        help="where mesh/boxes/polylines walls put their faces: on the cell boundaries, or "
        "half a cell into the wall toward observed free space, where a scan's end points lie "
        "on average (a wall seen from one side keeps half a cell, one seen from both its cells)",
    )


def cloud_filter_options(p: argparse.ArgumentParser) -> None:
    """Clean-up of cloud files before they are used (cloud2world, convert)."""
    g = p.add_argument_group("cloud files")
    g.add_argument(
        "--outliers",
        type=float,
        metavar="SD",
        dest="scans.outliers",
        help="drop statistical outliers: points whose mean distance to their nearest neighbours "
        "is over the mean + SD standard deviations (e.g. 2; default: off)",
    )
    g.add_argument(
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


def georef_options(p: argparse.ArgumentParser) -> None:
    """Where georeferenced clouds (UTM, state plane) are on the earth (cloud2world)."""
    g = p.add_argument_group("georeference")
    g.add_argument(
        "--local-origin",
        nargs="+",
        action=_LocalOrigin,
        metavar="ORIGIN",
        dest="scans.local_origin",
        help="subtracted from the clouds' coordinates: auto (their rounded centre, when they "
        "lie beyond 1 km of 0), none, or this point (the effective config records the one used)",
    )
    g.add_argument(
        "--crs",
        dest="scans.crs",
        metavar="CRS",
        help="the clouds' projected CRS (EPSG:32610, WKT, ...), for <spherical_coordinates> in "
        "the worlds (default: a LAS/LAZ file's own)",
    )


def voxel_options(p: argparse.ArgumentParser) -> None:
    """Options of --geometry voxels (the commands that hold voxels)."""
    g = p.add_argument_group("voxels (--geometry voxels)")
    g.add_argument(
        "--chunk",
        type=float,
        dest="world.chunk",
        help="metres: the voxel mesh is cut into cubes this size, one collision and visual each",
    )
    g.add_argument(
        "--voxel-size",
        type=float,
        dest="world.voxel_size",
        help="metres: mesh coarser voxels, the octree's resolution times a power of two "
        "(a coarse voxel is occupied if any of its voxels is; default: the octree's)",
    )
    g.add_argument(
        "--max-triangles",
        type=int,
        dest="world.max_triangles",
        help="refuse a voxel world of more triangles than this",
    )
    g.add_argument(
        "--min-voxels",
        type=int,
        dest="world.min_voxels",
        help="leave out occupied voxels in 3D components (26-connected) of fewer voxels "
        "(0: keep all)",
    )


def unknown_options(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """What unknown cells of an occupancy grid become (every command that makes one)."""
    p.add_argument(
        "--unknown",
        choices=UNKNOWN_POLICIES,
        dest="terrain.unknown",
        help="unknown cells as floor, as walls, or at --unknown-height",
    )
    p.add_argument(
        "--unknown-height",
        type=float,
        dest="terrain.unknown_height",
        help="metres, for --unknown height",
    )


def octree_options(p: argparse.ArgumentParser) -> None:
    t = p.add_argument_group("octree and grid")
    t.add_argument(
        "--max-memory",
        type=int,
        dest="max_memory",
        metavar="MIB",
        help="refuse an octree or a grid from voxels or points that would need more memory (MiB)",
    )
    t.add_argument(
        "--resolution",
        type=float,
        dest="octree.resolution",
        help="voxel side in metres for scan input (cloud2world's default: 0.05, or for a "
        "survey wider than terrain.max_side - 1 cells of that, the coarser of its side over "
        "those cells and twice its mean point spacing)",
    )
    t.add_argument(
        "--max-range",
        type=float,
        dest="octree.max_range",
        help="metres; longer beams are cut there and only clear (< 0: unlimited)",
    )
    t.add_argument(
        "--z-min",
        type=float,
        dest="octree.z_min",
        help="lowest voxel centre (metres) that counts for the 2D grid (default: no limit)",
    )
    t.add_argument(
        "--z-max",
        type=float,
        dest="octree.z_max",
        help="highest voxel centre (metres) that counts for the 2D grid (default: no limit)",
    )
    t.add_argument(
        "--grid",
        choices=GRID_KINDS,
        dest="octree.grid",
        help="occupancy (octomap_server's projection) or height (2.5D)",
    )
    unknown_options(t)
    t.add_argument(
        "--height-stat",
        choices=HEIGHT_STATS,
        dest="octree.height_stat",
        help="--grid height: each column's highest, lowest or mean occupied z",
    )
    t.add_argument(
        "--fill",
        choices=FILLS,
        dest="octree.fill",
        help="--grid height: fill empty columns from the nearest known one, by inverse "
        "distance weighting, or not",
    )
    t.add_argument(
        "--fill-max-distance",
        type=float,
        dest="octree.fill_max_distance",
        help="metres: nearest fill leaves columns farther than this from a known one empty "
        "(default: 4 cells, at least 1 m)",
    )
    t.add_argument(
        "--points",
        choices=VOXEL_POINTS,
        dest="octree.points",
        help="also write the occupied voxel centres as occupied_voxels.ply / .pcd",
    )


def scan_options(p: argparse.ArgumentParser, *, bag: bool, insert: bool = True) -> None:
    """How scans are read and posed; ``insert``: the command inserts them into an octree."""
    s = p.add_argument_group("scans and poses")
    if bag:
        s.add_argument(
            "--topic",
            action="append",
            dest="scans.topics",
            help="scan topic (LaserScan/PointCloud2, repeatable) or one OccupancyGrid topic "
            "(default: the only sensible one)",
        )
        s.add_argument(
            "--start",
            type=float,
            dest="scans.start",
            help="seconds from the bag's start, or absolute UNIX seconds (default: the start)",
        )
        s.add_argument("--end", type=float, dest="scans.end", help="as --start (default: the end)")
        s.add_argument(
            "--poses",
            choices=POSE_SOURCES,
            dest="scans.poses",
            help="where scan poses come from (auto: tf, else odometry)",
        )
        s.add_argument(
            "--correct",
            choices=CORRECT_MODES,
            dest="scans.correct",
            help="correct the poses by scan matching and loop closure (auto: when they are "
            "odometry only, kept if the beams agree better; on: any poses; off: as recorded)",
        )
        s.add_argument(
            "--fixed-frame",
            dest="scans.fixed_frame",
            help="frame to build the world in (default: map if present, else odom)",
        )
        s.add_argument(
            "--odom-topic",
            dest="scans.odom_topic",
            help="nav_msgs/Odometry topic (poses odom; default: the only one)",
        )
        s.add_argument(
            "--trajectory",
            dest="scans.trajectory",
            help="TUM trajectory file of the robot base (t x y z qx qy qz qw; default: none)",
        )
        s.add_argument(
            "--mount",
            type=float,
            nargs=6,
            metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
            dest="scans.mount",
            help="sensor pose on the robot base (odometry/trajectory poses; default from "
            "/tf_static, else identity)",
        )
        s.add_argument(
            "--max-gap",
            type=float,
            dest="scans.max_gap",
            help="longest tf/odometry gap, seconds, to interpolate across",
        )
    else:
        s.add_argument(
            "--las-classes",
            type=int,
            nargs="+",
            dest="scans.las_classes",
            help="LAS/LAZ classes to keep, e.g. 2 for ground (default: all)",
        )
    s.add_argument(
        "--pose",
        type=float,
        nargs=6,
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        dest="scans.pose",
        help="a stationary sensor's pose in the fixed frame (metres, radians; default: none)",
    )
    if not insert:
        return
    s.add_argument(
        "--insert",
        choices=INSERT_MODES,
        dest="scans.insert",
        help="raycast: free space too (OctoMap's insertPointCloud); endpoints: hits only, fast "
        "(auto: raycast for bags, endpoints for cloud files)",
    )


def path_or_url(text: str) -> Path | str:
    """A URL stays a string (Path would fold its '//')."""
    from scan2terrain.readers.las import is_url

    return text if is_url(text) else Path(text)


def stream_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "streaming and Dask (end points straight into grid tiles, no octree; memory bounded by "
        "the grid)"
    )
    g.add_argument(
        "--stream",
        action="store_const",
        const=True,
        dest="stream.enabled",
        help="stream end points into tiles instead of the octree (clouds larger than memory)",
    )
    g.add_argument(
        "--workers",
        type=int,
        dest="stream.workers",
        metavar="N",
        help="run the streamed work on a local Dask cluster of N worker processes",
    )
    g.add_argument(
        "--scheduler",
        dest="stream.scheduler",
        metavar="ADDRESS",
        help="run the streamed work on an existing Dask cluster (tcp://HOST:8786; default: "
        "none); its workers must reach the input paths",
    )
    g.add_argument(
        "--chunk-points",
        type=int,
        dest="stream.chunk_points",
        metavar="N",
        help="points read at a time",
    )
    g.add_argument(
        "--tile-cells",
        type=int,
        dest="stream.tile_cells",
        metavar="N",
        help="grid tile side in cells, a power of two",
    )


def progress_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )
