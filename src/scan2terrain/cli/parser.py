"""The argument parser: one sub-command per command, built from the option groups of
:mod:`scan2terrain.cli.options`, each option's help ending in that command's real default."""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn, cast

from scan2terrain.cli.options import (
    cloud_filter_options,
    common,
    fidelity_option,
    geometry_options,
    georef_options,
    octree_options,
    path_or_url,
    progress_option,
    scan_options,
    stream_options,
    unknown_options,
    voxel_options,
)
from scan2terrain.config import (
    TOP_LEVEL_KEYS,
    load_config,
)

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
    # Clouds come at every scale, from a room to an airborne survey: see cloud_resolution.
    "cloud2world": {"octree.resolution": None},
    # A world is scored for one simulator: gz-sim's, unless told.
    "fidelity": {"world.simulator": "gz"},
}


class Parser(argparse.ArgumentParser):
    """argparse, with what a user reads first put first: a usage mistake is the error line (a
    mistyped option or choice with its nearest match: "did you mean --height?"), then a
    one-line usage and where the full help is; sub-commands are made of this class too."""

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        self._given = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> NoReturn:
        # An unknown option is reported first: a typo is why a required one seems missing.
        unknown = self._unknown_options()
        message = "; ".join(unknown) if unknown else _suggest_choice(message)
        # The top level reports what a command left over: in that command's words.
        parser = self._command() or self
        parser.exit(2, f"{parser.prog}: error: {message}\n{parser._short_usage()}\n")

    def _command(self) -> Parser | None:
        subs = [a for a in self._actions if isinstance(a, argparse._SubParsersAction)]
        for word in getattr(self, "_given", []):
            if subs and word in subs[0].choices:
                return cast(Parser, subs[0].choices[word])
        return None

    def _unknown_options(self) -> list[str]:
        """Each option given that this parser (or the command it names) does not take, with
        the nearest one it does."""
        parser = self._command() or self
        if parser is self and any(isinstance(a, argparse._SubParsersAction) for a in self._actions):
            return []  # no command named: the command word is the mistake
        known = [o for a in parser._actions for o in a.option_strings]
        words = getattr(parser, "_given", getattr(self, "_given", []))
        found = []
        for word in words:
            if word == "--":
                break
            name = word.split("=", 1)[0]
            if not name.startswith("-") or _NUMBER.fullmatch(name) or name == "-":
                continue
            if any(k == name or (name.startswith("--") and k.startswith(name)) for k in known):
                continue
            near = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
            hint = f" (did you mean {near[0]}?)" if near else ""
            found.append(f"unrecognized option {name}{hint}")
        return found

    def _short_usage(self) -> str:
        words = [self.prog]
        for a in self._actions:
            if isinstance(a, argparse._SubParsersAction):
                words.append("COMMAND ...")
            elif not a.option_strings:
                words.append(_metavar(a) + (" ..." if a.nargs == "+" else ""))
            elif a.required:
                words.append(f"{a.option_strings[0]} {_metavar(a)}")
        return f"usage: {' '.join(words)} [options]\n`{self.prog} --help` lists them all"


def _metavar(action: argparse.Action) -> str:
    name = action.metavar if isinstance(action.metavar, str) else action.dest
    return name.upper()


_NUMBER = re.compile(r"-\d+(\.\d*)?(e-?\d+)?|-\.\d+")


def flags_of(parser: argparse.ArgumentParser, command: str | None) -> dict[str, str]:
    """Config key -> the flag that sets it, for ``command`` (its longest option string)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if command is None or not subs or command not in subs[0].choices:
        return {}
    flags: dict[str, str] = {}
    for a in subs[0].choices[command]._actions:
        if a.option_strings and ("." in a.dest or a.dest in TOP_LEVEL_KEYS):
            flags.setdefault(a.dest, max(a.option_strings, key=len))
    return flags


def name_flags(message: str, flags: dict[str, str]) -> str:
    """An error's config keys (``octree.grid``) as the flags a user types (``--grid``), the
    keys said once at the end for a config file; keys already beside their flag stay."""
    keys = []
    for key in sorted(flags, key=len, reverse=True):
        flag = flags[key]
        pattern = re.compile(rf"(?<![\w.-]){re.escape(key)}(?![\w.])")
        if not pattern.search(message) or f"({flag})" in message:
            continue
        message = pattern.sub(flag, message)
        keys.append(key)
    if not keys:
        return message
    return f"{message} (in a config file: {', '.join(sorted(keys))})"


def _suggest_choice(message: str) -> str:
    """argparse's "invalid choice: 'box' (choose from ...)", with the nearest choice."""
    m = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
    if m is None:
        return message
    choices = re.findall(r"'([^']*)'", m.group(2))
    near = difflib.get_close_matches(m.group(1), choices, n=1, cutoff=0.5)
    return f"{message} (did you mean '{near[0]}'?)" if near else message


class _Version(argparse.Action):
    """--version: the installed package's version (its metadata: one source, pyproject.toml),
    read only when asked."""

    def __init__(self, option_strings: list[str], dest: str, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=help)

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        import scan2terrain

        print(f"{parser.prog} {scan2terrain.__version__}")  # on stdout, as argparse's own
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="scan2terrain",
        description="Turn maps, images and scans into Gazebo worlds lined up with the map frame.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action=_Version, help="print the version and exit")
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
    common(m)
    geometry_options(m, voxels=False)
    unknown_options(m)

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
    common(i)
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
    common(t)
    geometry_options(t)
    octree_options(t)
    voxel_options(t)
    fidelity_option(t)
    progress_option(t)
    bag_commands(sub)
    dem_command(sub)
    fidelity_command(sub)
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
            if not ("." in action.dest or action.dest in TOP_LEVEL_KEYS):
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


def bag_commands(sub: Any) -> None:
    b = sub.add_parser(
        "bag2world",
        help="ROS1/ROS 2 bag or MCAP (LaserScan, PointCloud2 or a map) -> Gazebo world folder",
        description="Read a bag with no ROS installed (ROS1 .bag, rosbag2 folder, .db3, .mcap, "
        "or a CARMEN log: .clf, .log, plain, .gz or .bz2), "
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
    b.add_argument("bag", type=Path, nargs="+", help="bag file(s), rosbag2 folder, or CARMEN log")
    common(b)
    geometry_options(b)
    octree_options(b)
    voxel_options(b)
    scan_options(b, bag=True)
    fidelity_option(b)
    stream_options(b)
    progress_option(b)

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
        type=path_or_url,
        nargs="+",
        help="point-cloud file(s); with --stream also LAS/LAZ URLs (http(s)://, s3://, ...)",
    )
    common(c)
    geometry_options(c)
    octree_options(c)
    voxel_options(c)
    scan_options(c, bag=False)
    cloud_filter_options(c)
    georef_options(c)
    stream_options(c)
    progress_option(c)

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
    v.add_argument("source", type=Path, nargs="+", help="input cloud file(s), bag, or CARMEN log")
    v.add_argument("target", type=Path, help="output cloud file (format by extension)")
    v.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    v.add_argument("--config", type=Path, help="YAML config file; flags override it")
    scan_options(v, bag=True)
    cloud_filter_options(v)
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
    n.add_argument("bag", type=Path, nargs="+", help="bag file(s), rosbag2 folder, or CARMEN log")
    n.add_argument("--config", type=Path, help="YAML config file; flags override it")
    scan_options(n, bag=True)
    n.add_argument(
        "--max-range",
        type=float,
        dest="octree.max_range",
        help="metres: as bag2world's (a Foxglove LaserScan's no-return readings clear this far)",
    )
    n.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on failure")
    n.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")


def fidelity_command(sub: Any) -> None:
    f = sub.add_parser(
        "fidelity",
        help="score any Gazebo world against a recording: its beams replayed in the world",
        description="Cast every recorded beam (a bag's LaserScan/PointCloud2, posed as "
        "bag2world poses them, --correct included, or an OctoMap scan file) from its sensor "
        "pose into "
        "the world's collision geometry as the simulator builds it (meshes: STL, OBJ, DAE; "
        "boxes, cylinders, spheres, planes, polylines, heightmaps; model:// includes through "
        "the models/ folder beside the world, GZ_SIM_RESOURCE_PATH, IGN_GAZEBO_RESOURCE_PATH "
        "and GAZEBO_MODEL_PATH), and compare the simulated ranges with the recorded ones. "
        "The world frame is taken as the recording's fixed frame. Writes fidelity.yaml, "
        "fidelity.png and trajectory.tum (the sensor poses used) to OUT.",
        epilog="examples:\n"
        "  scan2terrain bag2world fixtures/bags/bag1_fuse_tb3_sim_scan_odom -o tb3_world "
        "--no-fidelity\n"
        "  scan2terrain fidelity tb3_world/world_gz.sdf fixtures/bags/bag1_fuse_tb3_sim_scan_odom "
        "-o tb3_fidelity --mount 0 0 0.2 0 0 0\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    f.add_argument("world", type=Path, help="world file (.sdf or .world)")
    f.add_argument(
        "recording", type=Path, nargs="+", help="bag file(s), rosbag2 folder, or OctoMap scan file"
    )
    f.add_argument("-o", "--out", type=Path, required=True, help="output folder (must not exist)")
    f.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    f.add_argument("--config", type=Path, help="YAML config file; flags override it")
    f.add_argument(
        "--simulator",
        choices=("gz", "classic"),
        dest="world.simulator",
        help="whose physics builds the world: where a heightmap lies and how it is sampled",
    )
    scan_options(f, bag=True, insert=False)
    f.add_argument("--max-range", type=float, dest="octree.max_range", help="drop hits beyond (m)")
    f.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on failure")
    f.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")


def dem_command(sub: Any) -> None:
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
        "heights are the DEM's own elevations (no wall height, no inversion); canvas options "
        "count heightmap pixels.",
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
    common(d, heights=False)
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
    g.add_argument(
        "--max-elevation",
        type=float,
        metavar="M",
        dest="dem.max_elevation",
        help="refuse a DEM with an elevation (nodata excluded) further than M metres above or "
        "below the datum: a planet's are within 100 km; widen it for a trusted file",
    )
