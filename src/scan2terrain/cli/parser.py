"""The argument parser: one sub-command per command, built from the option groups of
:mod:`scan2terrain.cli.options`, each option's help ending in that command's real default."""

from __future__ import annotations

import argparse
import difflib
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from scan2terrain.cli.dispatch import COMMANDS
from scan2terrain.cli.options import (
    Options,
    cloud_filter_options,
    common,
    config_option,
    fidelity_option,
    geometry_options,
    georef_options,
    max_range_option,
    octree_options,
    out_options,
    overwrite_option,
    path_or_url,
    progress_option,
    run_options,
    scan_options,
    simulator_option,
    stream_options,
    unknown_options,
    view_options,
    voxel_options,
)
from scan2terrain.config import load_config
from scan2terrain.errors import ConfigError

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


class Parser(argparse.ArgumentParser):
    """argparse, with what a user reads first put first: a usage mistake is the error line (a
    mistyped option or choice with its nearest match: "did you mean --height?"), then a
    one-line usage and where the full help is; sub-commands are made of this class too."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        #: The top level's commands (empty in a command's own parser): each one's parser and
        #: the flags of its config options.
        self.commands: dict[str, tuple[Parser, dict[str, str]]] = {}

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
        self.refuse(self._command() or self, message)

    def refuse(self, parser: Parser, message: str) -> NoReturn:
        """The usage mistake ``message`` in ``parser``'s words: its line, then a short usage."""
        parser.exit(2, f"{parser.prog}: error: {message}\n{parser._short_usage()}\n")

    def _command(self) -> Parser | None:
        for word in getattr(self, "_given", []):
            if word in self.commands:
                return self.commands[word][0]
        return None

    def _unknown_options(self) -> list[str]:
        """Each option given that this parser (or the command it names) does not take, with
        the nearest one it does."""
        parser = self._command() or self
        if parser is self and self.commands:
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
            if a.nargs == argparse.PARSER:  # the command word
                words.append("COMMAND ...")
            elif not a.option_strings:
                words.append(_metavar(a) + (" ..." if a.nargs == "+" else ""))
            elif a.required:
                words.append(f"{a.option_strings[0]} {_metavar(a)}")
        return f"usage: {' '.join(words)} [options]\n`{self.prog} --help` lists them all"


class RaisingParser(Parser):
    """The parser of the Python API (``scan2terrain.api``): a usage mistake (a value of the
    wrong type, not a choice, a wrong count of values) raises :class:`ConfigError` with the
    words the command line prints after ``error:``, instead of exiting."""

    def refuse(self, parser: Parser, message: str) -> NoReturn:
        raise ConfigError(message)


def _metavar(action: argparse.Action) -> str:
    name = action.metavar if isinstance(action.metavar, str) else action.dest
    return name.upper()


_NUMBER = re.compile(r"-\d+(\.\d*)?(e-?\d+)?|-\.\d+")


def flags_of(parser: argparse.ArgumentParser, command: str | None) -> dict[str, str]:
    """Config key -> the flag that sets it, for ``command`` (its longest option string)."""
    commands = parser.commands if isinstance(parser, Parser) else {}
    return commands[command][1] if command in commands else {}


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
        # Read here as ``scan2terrain.__version__`` reads it: the package itself re-exports the
        # Python API, which is above the CLI (tests/test_architecture.py).
        from importlib.metadata import version

        print(f"{parser.prog} {version('scan2terrain')}")  # on stdout, as argparse's own
        parser.exit()


def build_parser(parser_class: type[Parser] = Parser) -> Parser:
    """The command line's parser (``parser_class``: :class:`RaisingParser` for the Python API;
    its sub-commands' parsers are of the same class)."""
    parser = parser_class(
        prog="scan2terrain",
        description="Turn maps, images and scans into Gazebo worlds lined up with the map frame.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action=_Version, help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    add = _adder(parser, sub)

    m = add(
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
    )
    m.add("map", type=Path, help="map_server YAML file")
    common(m)
    geometry_options(m, voxels=False)
    unknown_options(m)

    i = add(
        "image2world",
        help="any image -> Gazebo world folder (luminance is height)",
        description="Read any image (PNG/JPG/TIFF/BMP/PGM, grey/RGB/RGBA/palette/16-bit), take "
        "its luminance as height (white = --height metres) and write a Gazebo heightmap world.",
        epilog="example:\n"
        "  scan2terrain image2world fixtures/images/heightmap_png_bowl/heightmap_bowl.png "
        "-o bowl --resolution 0.05 --height 2\n",
    )
    i.add("image", type=Path, help="image file")
    common(i)
    i.add("--resolution", type=float, dest="image.resolution", help="metres per pixel")
    i.add(
        "--origin",
        type=float,
        nargs="+",
        metavar=("X", "Y"),
        dest="image.origin",
        help="pose x y [yaw] of the lower-left corner (default: centred on 0, 0)",
    )
    t = add(
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
    )
    t.add("tree", type=Path, help=".bt file, or OctoMap scan file (.dat[.bz2|.gz])")
    common(t)
    geometry_options(t)
    octree_options(t)
    voxel_options(t)
    fidelity_option(t)
    progress_option(t)
    bag_commands(add)
    dem_command(add)
    fidelity_command(add)
    view_command(add)
    return parser


Adder = Callable[..., Options]


def _adder(parser: Parser, sub: Any) -> Adder:
    """``add(name, help=..., description=..., epilog=...)``: a command's parser, recorded in
    ``parser.commands``, as the :class:`Options` its options are declared through (with that
    command's effective defaults: the config's, after its own)."""

    def add(name: str, **kw: Any) -> Options:
        p = sub.add_parser(name, formatter_class=argparse.RawDescriptionHelpFormatter, **kw)
        o = Options(p, load_config(None, {}, defaults=dict(COMMANDS[name].defaults)))
        parser.commands[name] = (p, o.flags)
        return o

    return add


def bag_commands(add: Adder) -> None:
    b = add(
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
    )
    b.add("bag", type=Path, nargs="+", help="bag file(s), rosbag2 folder, or CARMEN log")
    common(b)
    geometry_options(b)
    octree_options(b)
    voxel_options(b)
    scan_options(b, bag=True)
    fidelity_option(b)
    stream_options(b)
    progress_option(b)

    c = add(
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
    )
    c.add(
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

    v = add(
        "convert",
        help="point-cloud file or bag -> one point-cloud file",
        description="Convert between point-cloud formats (PCD, PLY, XYZ, CSV, LAS, LAZ), or merge "
        "a bag's scans (hits only, posed in the fixed frame) into one cloud file.",
        epilog="examples:\n"
        "  scan2terrain convert fixtures/clouds/pc_hdl32_scan_pcd_ply_twin/251370668.pcd "
        "hdl32.ply\n"
        "  scan2terrain convert fixtures/bags/bag1_embark_luminar_pointcloud merged.laz "
        "--topic /luminar_pointcloud --pose 0 0 1.8 0 0 0\n",
    )
    v.add("source", type=Path, nargs="+", help="input cloud file(s), bag, or CARMEN log")
    v.add("target", type=Path, help="output cloud file (format by extension)")
    overwrite_option(v)
    config_option(v)
    scan_options(v, bag=True)
    cloud_filter_options(v)
    max_range_option(v)
    run_options(v)

    n = add(
        "inspect",
        help="what a bag holds and what bag2world would use",
        description="List a bag's topics, types, counts, duration and tf frames, and which "
        "topics and poses bag2world would use and why.",
        epilog="example:\n  scan2terrain inspect fixtures/bags/bag1_sick_lms1xx_radar_tf\n",
    )
    n.add("bag", type=Path, nargs="+", help="bag file(s), rosbag2 folder, or CARMEN log")
    config_option(n)
    scan_options(n, bag=True)
    max_range_option(n)
    run_options(n)


def fidelity_command(add: Adder) -> None:
    f = add(
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
        "fidelity.png, fidelity_ends.ply (each beam's end point and error) and trajectory.tum "
        "(the sensor poses used) to OUT.",
        epilog="examples:\n"
        "  scan2terrain bag2world fixtures/bags/bag1_fuse_tb3_sim_scan_odom -o tb3_world "
        "--no-fidelity\n"
        "  scan2terrain fidelity tb3_world/world_gz.sdf fixtures/bags/bag1_fuse_tb3_sim_scan_odom "
        "-o tb3_fidelity --mount 0 0 0.2 0 0 0\n",
    )
    f.add("world", type=Path, help="world file (.sdf or .world)")
    f.add(
        "recording", type=Path, nargs="+", help="bag file(s), rosbag2 folder, or OctoMap scan file"
    )
    out_options(f)
    config_option(f)
    simulator_option(f, both=False)
    scan_options(f, bag=True, insert=False)
    max_range_option(f)
    run_options(f)


def view_command(add: Adder) -> None:
    w = add(
        "view",
        help="a world folder in the browser: collisions, spawn pose, trajectory, fidelity",
        description="Serve a world folder written by scan2terrain as a 3D page (viser; works "
        "offline): each world's collision geometry as its simulator builds it (gz-sim's, with "
        "a switch to Classic's where they differ), the spawn pose, trajectory.tum and the "
        "fidelity.yaml figures when present. Prints the URL and serves until Ctrl-C; writes "
        "nothing.",
        epilog="example:\n"
        "  scan2terrain map2world fixtures/maps/map_nav2_warehouse_003/warehouse.yaml "
        "-o warehouse_world\n"
        "  scan2terrain view warehouse_world --no-browser\n",
    )
    w.add("world", type=Path, help="world folder (written by scan2terrain)")
    view_options(w)
    run_options(w)


def dem_command(add: Adder) -> None:
    d = add(
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
    )
    d.add("dem", type=Path, help="DEM file (single-band GeoTIFF)")
    common(d, heights=False)
    g = d.group("elevation model")
    g.add(
        "--resolution",
        type=float,
        dest="dem.resolution",
        help="heightmap pixel size in metres (default: the DEM's own); also the pixel size of "
        "a TIFF without georeference, which is refused without it",
    )
    g.add(
        "--dem-passthrough",
        action="store_const",
        const=True,
        dest="dem.passthrough",
        help="also copy the GeoTIFF into a model and write world_gz_dem.sdf that loads it "
        "directly (gz-sim >= 7 built with GDAL)",
    )
    g.add(
        "--max-elevation",
        type=float,
        metavar="M",
        dest="dem.max_elevation",
        help="refuse a DEM with an elevation (nodata excluded) further than M metres above or "
        "below the datum: a planet's are within 100 km; widen it for a trusted file",
    )
