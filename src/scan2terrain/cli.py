"""Command line: parse arguments, build the config, call the pipeline, map errors to exit codes.

Exit codes: 0 success, 1 unexpected failure, 2 bad input or usage (one line on stderr).
Heavy modules (numpy, Pillow, lxml) are imported only once a command runs, so ``--help`` is fast.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scan2terrain.config import (
    FILLS,
    FILTERS,
    GEOMETRIES,
    HEIGHT_STATS,
    SIMULATORS,
    UNKNOWN_POLICIES,
    load_config,
)

if TYPE_CHECKING:
    from scan2terrain.config import Config
    from scan2terrain.readers.scans import ScanCounts
    from scan2terrain.world import Result

EXAMPLES = r"""
examples:
  scan2terrain map2world fixtures/maps/map_willow_garage_005/willow-full-0.05.yaml -o willow_world
  scan2terrain map2world fixtures/maps/map_tb3_world_mapsaver/map.yaml -o tb3 \
      --simulator gz --filter paper --height 2.5 --geometry heightmap --upsample 2
  scan2terrain image2world fixtures/images/heightmap_png_bowl/heightmap_bowl.png -o bowl \
      --resolution 0.1 --height 1.5 --invert
  scan2terrain map2world fixtures/maps/map_tb3_world_mapsaver/map.yaml -o tb3 \
      --config configs/indoor_gz.yaml --overwrite
  scan2terrain dem2world fixtures/terrain/dem_sfbay_squared_geotiff/dem_squared.tif -o sfbay
(paths are relative to a clone of the repository: fixtures/ holds the bundled samples)
"""[1:]

#: Defaults a command sets before the config file and the flags (which both override them).
COMMAND_DEFAULTS: dict[str, dict[str, Any]] = {
    # A DEM spans hundreds of metres of height: 8 bits would be steps of range / 255.
    "dem2world": {"terrain.bit_depth": 16, "world.simulator": "gz", "filter.kind": "none"},
}


def _common(p: argparse.ArgumentParser) -> None:
    """Options every world command takes (their defaults are added by :func:`_state_defaults`)."""
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
        choices=(8, 16),
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
        help="paper = the paper's modified median (keeps horizontal/vertical runs of 3);"
        " thin_wall = it, also keeping diagonal walls",
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


def _geometry_options(p: argparse.ArgumentParser) -> None:
    """Options of the commands whose grid is occupancy (walls), not heights."""
    g = p.add_argument_group("walls (occupancy grids)")
    g.add_argument(
        "--geometry",
        choices=GEOMETRIES,
        dest="world.geometry",
        help="how occupied cells become walls: one extruded mesh (STL/DAE/OBJ; exact, and the "
        "fastest in physics), the fewest boxes that cover them, SDF polylines, or a heightmap "
        "(slowest; 1-cell walls are knife edges); auto: mesh for occupancy grids, "
        "heightmap for height grids; map frame = world frame in both simulators for all but "
        "heightmap (README: which geometry to pick)",
    )
    g.add_argument(
        "--simplify",
        type=float,
        dest="world.simplify",
        help="metres: straighten mesh/polyline outlines within this tolerance, keeping every "
        "cell on its side (0: cell edges)",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="scan2terrain",
        description="Turn maps, images and scans into Gazebo worlds lined up with the map frame.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version="%(prog)s 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    m = sub.add_parser(
        "map2world",
        help="ROS map_server map (YAML + image) -> Gazebo world folder",
        description="Read a map_server map exactly as map_server does, filter it and write a "
        "Gazebo world (gz-sim and/or Classic: walls as one mesh by default, or boxes, polylines "
        "or a heightmap), the filtered map as map_server YAML+PGM lined up with the world, a "
        "spawn pose (spawn.yaml), a preview and the effective config.",
        epilog="examples:\n"
        "  scan2terrain map2world fixtures/maps/map_tb3_world_mapsaver/map.yaml -o tb3\n"
        "  scan2terrain map2world fixtures/maps/map_tb3_world_mapsaver/map.yaml -o tb3_terrain "
        "--geometry heightmap\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    m.add_argument("map", type=Path, help="map_server YAML file")
    _common(m)
    _geometry_options(m)
    _unknown_options(m)

    i = sub.add_parser(
        "image2world",
        help="any image -> Gazebo world folder (luminance is height)",
        description="Read any image (PNG/JPG/TIFF/BMP/PGM, grey/RGB/RGBA/palette/16-bit), take "
        "its luminance as height (white = --height metres) and write a Gazebo heightmap world.",
        epilog="example:\n"
        "  scan2terrain image2world fixtures/images/heightmap_png_bowl/heightmap_bowl.png "
        "-o bowl --resolution 0.05 --height 2\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    i.add_argument("image", type=Path, help="image file")
    _common(i)
    i.add_argument("--resolution", type=float, dest="image.resolution", help="metres per pixel")
    i.add_argument(
        "--origin",
        type=float,
        nargs="+",
        metavar=("X", "Y"),
        dest="image.origin",
        help="pose x y [yaw] of the lower-left corner (default: centred on 0, 0)",
    )
    t = sub.add_parser(
        "octree2world",
        help="OctoMap .bt file or OctoMap text scan file -> Gazebo world folder",
        description="Project an OctoMap octree (a .bt file, or a scan file ray-cast into a new "
        "octree with OctoMap's model) to a 2D occupancy grid as octomap_server does (or a 2.5D "
        "height grid) and write the same world folder as map2world. A scan input also writes "
        "the octree as octree.bt.",
        epilog="examples:\n"
        "  scan2terrain octree2world fixtures/octomap/geb079.bt -o geb079 --z-min 0.1 --z-max 1.8\n"
        "  scan2terrain octree2world fixtures/octomap/scan.dat.bz2 -o fr079 --resolution 0.1 "
        "--grid height --progress\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    t.add_argument("tree", type=Path, help=".bt file, or OctoMap scan file (.dat[.bz2|.gz])")
    _common(t)
    _geometry_options(t)
    _octree_options(t)
    _progress_option(t)
    _bag_commands(sub)
    _dem_command(sub)
    _state_defaults(sub)
    return parser


def _state_defaults(sub: Any) -> None:
    """Append ``(default: X)`` to the help of every option that sets a config value, X being
    that command's effective default (the config's, after its ``COMMAND_DEFAULTS``): one
    source, so help cannot drift from behaviour. Options whose default is None say in their
    own words what happens without them."""
    for command, parser in sub.choices.items():
        cfg = load_config(None, {}, defaults=COMMAND_DEFAULTS.get(command))
        for action in parser._actions:
            if not ("." in action.dest or action.dest == "max_pixels"):
                continue
            if isinstance(action, argparse._StoreConstAction) or action.help is None:
                continue
            value: Any = cfg
            for part in action.dest.split("."):
                value = getattr(value, part)
            if value is not None:
                action.help = f"{action.help} (default: {_shown(value)})"


def _shown(value: object) -> str:
    power = isinstance(value, int) and value >= 1 << 20 and value & (value - 1) == 0
    return f"2^{value.bit_length() - 1}" if power and isinstance(value, int) else str(value)


def _unknown_options(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
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


def _octree_options(p: argparse.ArgumentParser) -> None:
    t = p.add_argument_group("octree and grid")
    t.add_argument(
        "--resolution",
        type=float,
        dest="octree.resolution",
        help="voxel side in metres for scan input",
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
        choices=("occupancy", "height"),
        dest="octree.grid",
        help="occupancy (octomap_server's projection) or height (2.5D)",
    )
    _unknown_options(t)
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
        choices=("none", "ply", "pcd"),
        dest="octree.points",
        help="also write the occupied voxel centres as occupied_voxels.ply / .pcd",
    )


def _pose6(text: str) -> list[float]:
    return [float(v) for v in text.replace(",", " ").split()]


def _scan_options(p: argparse.ArgumentParser, *, bag: bool) -> None:
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
            choices=("auto", "tf", "odom", "trajectory", "fixed"),
            dest="scans.poses",
            help="where scan poses come from (auto: tf, else odometry)",
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
    s.add_argument(
        "--insert",
        choices=("auto", "raycast", "endpoints"),
        dest="scans.insert",
        help="raycast: free space too (OctoMap's insertPointCloud); endpoints: hits only, fast "
        "(auto: raycast for bags, endpoints for cloud files)",
    )


def _bag_commands(sub: Any) -> None:
    b = sub.add_parser(
        "bag2world",
        help="ROS1/ROS 2 bag or MCAP (LaserScan, PointCloud2 or a map) -> Gazebo world folder",
        description="Read a bag with no ROS installed (ROS1 .bag, rosbag2 folder, .db3, .mcap), "
        "pose every scan (tf, odometry, a TUM trajectory or one fixed pose), insert the scans "
        "into the voxel octree (OctoMap's model) and write the same world folder as "
        "octree2world, plus octree.bt. A bag with only a map topic goes the map2world way.",
        epilog="examples:\n"
        "  scan2terrain bag2world fixtures/bags/bag1_fuse_tb3_sim_scan_odom -o tb3_world\n"
        "  scan2terrain bag2world fixtures/bags/bag1_embark_luminar_pointcloud -o road "
        "--topic /luminar_pointcloud --pose 0 0 1.8 0 0 0 --insert endpoints --grid height "
        "--resolution 0.2\n"
        "  scan2terrain bag2world fixtures/bags/bag1_leg_tracker_room_scan -o room "
        "--pose 0 0 0.3 0 0 0 --resolution 0.05\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    b.add_argument("bag", type=Path, nargs="+", help="bag file(s) or rosbag2 folder")
    _common(b)
    _geometry_options(b)
    _octree_options(b)
    _scan_options(b, bag=True)
    _stream_options(b)
    _progress_option(b)

    c = sub.add_parser(
        "cloud2world",
        help="point-cloud files (PCD, PLY, XYZ, CSV, LAS/LAZ) -> Gazebo world folder",
        description="Read point-cloud files (float64 kept until a local origin is subtracted), "
        "insert them into the voxel octree (end points only by default; --insert raycast casts "
        "rays from --pose, the cloud being in the sensor frame) and write the world folder.",
        epilog="examples:\n"
        "  scan2terrain cloud2world fixtures/clouds/pc_hdl32_scan_pcd_ply_twin/251370668.pcd "
        "-o hdl32 --z-min -1.2 --z-max 0.5\n"
        "  scan2terrain cloud2world fixtures/clouds/pc_laz_autzen_trim/autzen_trim.laz "
        "-o terrain --las-classes 2 --grid height --resolution 1\n"
        "  scan2terrain cloud2world fixtures/clouds/pc_laz_autzen_trim/*.laz -o city "
        "--grid height --resolution 0.5 --stream --workers 2\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument(
        "clouds",
        type=_path_or_url,
        nargs="+",
        help="point-cloud file(s); with --stream also LAS/LAZ URLs (http(s)://, s3://, ...)",
    )
    _common(c)
    _geometry_options(c)
    _octree_options(c)
    _scan_options(c, bag=False)
    _stream_options(c)
    _progress_option(c)

    v = sub.add_parser(
        "convert",
        help="point-cloud file or bag -> one point-cloud file",
        description="Convert between point-cloud formats (PCD, PLY, XYZ, CSV, LAS, LAZ), or merge "
        "a bag's scans (hits only, posed in the fixed frame) into one cloud file.",
        epilog="examples:\n"
        "  scan2terrain convert fixtures/clouds/pc_hdl32_scan_pcd_ply_twin/251370668.pcd "
        "hdl32.ply\n"
        "  scan2terrain convert fixtures/bags/bag1_embark_luminar_pointcloud merged.laz "
        "--topic /luminar_pointcloud --pose 0 0 1.8 0 0 0\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    v.add_argument("source", type=Path, nargs="+", help="input cloud file(s) or bag")
    v.add_argument("target", type=Path, help="output cloud file (format by extension)")
    v.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    v.add_argument("--config", type=Path, help="YAML config file; flags override it")
    _scan_options(v, bag=True)
    v.add_argument(
        "--las-classes",
        type=int,
        nargs="+",
        dest="scans.las_classes",
        help="LAS classes to keep (default: all)",
    )
    v.add_argument(
        "--max-range", type=float, dest="octree.max_range", help="drop bag hits beyond (m)"
    )
    v.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on failure")
    v.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")

    n = sub.add_parser(
        "inspect",
        help="what a bag holds and what bag2world would use",
        description="List a bag's topics, types, counts, duration and tf frames, and which "
        "topics and poses bag2world would use and why.",
        epilog="example:\n  scan2terrain inspect fixtures/bags/bag1_sick_lms1xx_radar_tf\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    n.add_argument("bag", type=Path, nargs="+", help="bag file(s) or rosbag2 folder")
    n.add_argument("--config", type=Path, help="YAML config file; flags override it")
    _scan_options(n, bag=True)
    n.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on failure")
    n.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")


def _path_or_url(text: str) -> Path | str:
    """A URL stays a string (Path would fold its '//')."""
    from scan2terrain.readers.cloudfile import is_url

    return text if is_url(text) else Path(text)


def _stream_options(p: argparse.ArgumentParser) -> None:
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


def _progress_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )


def _dem_command(sub: Any) -> None:
    d = sub.add_parser(
        "dem2world",
        help="elevation model (single-band GeoTIFF) -> Gazebo world at true elevations",
        description="Read a DEM (GeoTIFF, projected or geographic; no GDAL needed) and write a "
        "world whose ground is at the DEM's elevations: the DEM centre is the world origin "
        "(x east, y north, metres; the CRS offset is printed and written in the SDF), world "
        "z = elevation. Pixels stay the DEM's own when they are square in metres, else are "
        "resampled bilinearly onto square pixels that fill the 2^n+1 image; the image is padded "
        "to 2^n+1 at the lowest height. Defaults for DEMs: --simulator gz, --bit-depth 16, "
        "--filter none (Gazebo Classic needs --bit-depth 8). Any --filter is a plain median; "
        "--height and --invert do not apply; canvas options count heightmap pixels.",
        epilog="examples:\n"
        "  scan2terrain dem2world fixtures/terrain/dem_sfbay_squared_geotiff/dem_squared.tif "
        "-o sfbay\n"
        "  scan2terrain dem2world fixtures/terrain/dem_moon_polar_geotiff/dem_moon.tif -o moon "
        "--dem-passthrough\n"
        "  scan2terrain dem2world fixtures/terrain/dem_sfbay_squared_geotiff/dem_squared.tif "
        "-o sfbay_both --simulator both --bit-depth 8\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    d.add_argument("dem", type=Path, help="DEM file (single-band GeoTIFF)")
    _common(d)
    g = d.add_argument_group("elevation model")
    g.add_argument(
        "--resolution",
        type=float,
        dest="dem.resolution",
        help="heightmap pixel size in metres (default: the DEM's own); also the pixel size of "
        "a TIFF without georeference, which is refused without it",
    )
    g.add_argument(
        "--dem-passthrough",
        action="store_const",
        const=True,
        dest="dem.passthrough",
        help="also copy the GeoTIFF into a model and write world_gz_dem.sdf that loads it "
        "directly (gz-sim >= 7 built with GDAL)",
    )


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    import warnings

    def show(message: Any, category: Any, *_: Any, **__: Any) -> None:
        print(f"scan2terrain: warning: {message}", file=sys.stderr)

    # Restored on return: main() is also called in-process (tests, scripts), and the hook
    # must not outlive the command.
    saved, warnings.showwarning = warnings.showwarning, show
    try:
        code = _run(args)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except BrokenPipeError:
        # The reader of our stdout left (``scan2terrain inspect bag | head``): what it read is
        # what it asked for, and every output file is already in place.
        _drop_stdout()
        return 0
    except KeyboardInterrupt:
        print("scan2terrain: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        from scan2terrain.errors import Scan2TerrainError

        if args.verbose:
            import traceback

            traceback.print_exc()
        if isinstance(exc, Scan2TerrainError):
            print(f"scan2terrain: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        print(
            f"scan2terrain: internal error: {type(exc).__name__}: {_one_line(exc)} "
            "(run with -v for the traceback, and please report it)",
            file=sys.stderr,
        )
        return 1
    finally:
        warnings.showwarning = saved


def _one_line(exc: BaseException, limit: int = 400) -> str:
    """An error's text on one line (libraries quote whole files or message definitions),
    cut at ``limit`` characters."""
    text = re.sub(r"\s*[\r\n]+\s*", " ", str(exc)).strip()
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _drop_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's flush at exit does not fail again."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout without a file descriptor (tests' capture)
        pass


def _run(args: argparse.Namespace) -> int:
    from scan2terrain.config import load_config
    from scan2terrain.steps import refuse_existing

    overrides: dict[str, Any] = {
        k: v for k, v in vars(args).items() if "." in k or k == "max_pixels"
    }
    cfg = load_config(args.config, overrides, defaults=COMMAND_DEFAULTS.get(args.command))
    out = getattr(args, "out", None)
    side_inputs = [p for p in (args.config, cfg.scans.trajectory) if p is not None]
    if out is not None and side_inputs:  # files besides the command's input never go either
        refuse_existing(out, args.overwrite, tuple(side_inputs))
    if args.command in ("bag2world", "cloud2world", "convert", "inspect"):
        return _run_scans(args, cfg)
    if args.command == "map2world":
        from scan2terrain.commands.maps import map2world

        result = map2world(args.map, args.out, cfg, overwrite=args.overwrite)
    elif args.command == "octree2world":
        from scan2terrain.commands.voxels import octree2world

        with ProgressBar(enabled=_show_progress(args)) as bar:
            result = octree2world(
                args.tree, args.out, cfg, overwrite=args.overwrite, progress=bar.update
            )
    elif args.command == "dem2world":
        from scan2terrain.commands.dem import dem2world

        result = dem2world(args.dem, args.out, cfg, overwrite=args.overwrite)
    else:
        from scan2terrain.commands.maps import image2world

        result = image2world(args.image, args.out, cfg, overwrite=args.overwrite)
    if not args.quiet:
        print(report(result))
    return 0


def _run_scans(args: argparse.Namespace, cfg: Config) -> int:
    from scan2terrain.commands import scans

    if args.command == "inspect":
        print(scans.inspect_bag(args.bag, cfg))
        return 0
    if args.command == "convert":
        text = scans.convert(args.source, args.target, cfg, overwrite=args.overwrite)
        if not args.quiet:
            print(text)
        return 0
    show = _show_progress(args)
    if args.command == "cloud2world":
        with TaskBar(enabled=show) as tasks:
            result = scans.cloud2world(
                args.clouds, args.out, cfg, overwrite=args.overwrite, stream_progress=tasks.update
            )
    else:
        with (
            ProgressBar(enabled=show) as bar,
            TaskBar(enabled=show) as tasks,
        ):
            progress = bar.update if bar.enabled else None  # no bar: no counting pass
            result = scans.bag2world(
                args.bag,
                args.out,
                cfg,
                overwrite=args.overwrite,
                progress=progress,
                stream_progress=tasks.update,
            )
    if not args.quiet:
        print(report(result))
    return 0


def _show_progress(args: argparse.Namespace) -> bool:
    """--progress / --no-progress, else when stderr is a terminal; never with --quiet."""
    show = sys.stderr.isatty() if args.progress is None else args.progress
    return bool(show) and not args.quiet


class ProgressBar:
    """Scans/s, points/s and ETA on stderr (tqdm), updated at most a few times a second. Rates
    count from entering the block, not from the first update (which comes after a scan)."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self._bar: Any = None
        self._last = 0
        self._start = 0.0

    def __enter__(self) -> ProgressBar:
        self._start = time.monotonic()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()

    def update(self, counts: ScanCounts, total: int) -> None:
        if not self.enabled:
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total or None,
                unit="scan",
                file=sys.stderr,
                dynamic_ncols=True,
                mininterval=0.25,
            )
        self._bar.update(counts.messages - self._last)
        self._last = counts.messages
        self._bar.set_postfix_str(_rate(counts.points, self._start), refresh=False)


class TaskBar:
    """Streamed tasks done and points/s on stderr (tqdm)."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self._bar: Any = None
        self._last = 0
        self._start = 0.0

    def __enter__(self) -> TaskBar:
        self._start = time.monotonic()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()

    def update(self, done: int, total: int, points: int) -> None:
        if not self.enabled:
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total, unit="task", file=sys.stderr, dynamic_ncols=True, mininterval=0.25
            )
        self._bar.update(done - self._last)
        self._last = done
        self._bar.set_postfix_str(_rate(points, self._start), refresh=False)


def _rate(points: int, start: float) -> str:
    """Points per second since ``start`` (time.monotonic), as the bars show it."""
    elapsed = max(time.monotonic() - start, 1e-3)
    return f"{points / elapsed / 1e6:.2f} M points/s"


def _spawn_lines(simulator: str, pose: tuple[float, ...]) -> list[str]:
    """Where to spawn a robot (spawn.yaml), and the commands that put ROBOT.sdf there."""
    x, y, z, _, _, yaw = (f"{v:g}" for v in pose)
    head = f"    spawn a robot at x={x} y={y} z={z} yaw={yaw} (spawn.yaml), e.g.:"
    if simulator == "gz":
        qz, qw = math.sin(pose[5] / 2), math.cos(pose[5] / 2)
        req = (
            f'sdf_filename: "ROBOT.sdf", name: "robot", pose: {{position: {{x: {x}, y: {y},'
            f" z: {z}}}, orientation: {{z: {qz:.6g}, w: {qw:.6g}}}}}"
        )
        return [
            head,
            "      gz service -s /world/scan2terrain/create --reqtype gz.msgs.EntityFactory"
            f" --reptype gz.msgs.Boolean --timeout 5000 --req '{req}'",
            "      ros2 run ros_gz_sim create -world scan2terrain -file ROBOT.sdf -name robot"
            f" -x {x} -y {y} -z {z} -Y {yaw}",
        ]
    return [
        head,
        f"      gz model --spawn-file=ROBOT.sdf --model-name=robot -x {x} -y {y} -z {z} -Y {yaw}",
        "      rosrun gazebo_ros spawn_model -sdf -file ROBOT.sdf -model robot"
        f" -x {x} -y {y} -z {z} -Y {yaw}",
    ]


def report(result: Result) -> str:
    """How to open what was written, for a human."""
    from scan2terrain.steps import minus

    out = result.out
    walls = result.geometry != "heightmap"
    rows, cols = result.tiles
    side = f"{result.heightmap_side}x{result.heightmap_side} px"
    ground = f"heightmap {side}" if rows * cols == 1 else f"{rows}x{cols} heightmap tiles of {side}"
    lines = [
        f"Wrote {out}/ ({result.geometry}: {result.walls}; walls {result.size_z:g} m high)"
        if walls
        else f"Wrote {out}/ ({ground} at {result.resolution:g} m/px, heights up to "
        f"{result.size_z:g} m)"
    ]
    for w in result.worlds:
        p = w.placement
        # Absolute paths: the resource variables are read by a simulator started anywhere.
        models, world = w.models.absolute(), w.world.absolute()
        if p.simulator == "gz":
            lines += [
                "  gz-sim (Garden or newer; DART physics, the default engine):",
                f"    GZ_SIM_RESOURCE_PATH={models} gz sim {world}",
                f"    (Fortress: IGN_GAZEBO_RESOURCE_PATH={models} ign gazebo {world})",
                "    map frame = world frame: a map point (x, y) is world (x, y).",
            ]
        elif walls:
            lines += [
                "  Gazebo Classic:",
                f"    GAZEBO_MODEL_PATH={models} gazebo {world}",
                "    map frame = world frame: a map point (x, y) is world (x, y).",
            ]
        else:
            ox, oy = p.offset
            lines += [
                "  Gazebo Classic:",
                f"    GAZEBO_MODEL_PATH={models} gazebo {world}",
                "    Classic cannot move a heightmap: the terrain is centred on the world origin,",
                f"    a map point (x, y) is world ({minus('x', ox)}, {minus('y', oy)}).",
            ]
        if w.map_yaml is not None:
            lines.append(f"    navigation map lined up with this world: {w.map_yaml}")
        if w.spawn is not None:
            lines += _spawn_lines(p.simulator, w.spawn)
    if result.preview is not None:
        lines.append(f"  preview ({result.preview_label}): {result.preview}")
    for note in result.notes:
        lines.append(f"  {note}")
    lines.append(f"  effective config: {result.config}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
