"""One typed configuration for every command, with defaults that match the references.

Layers, later wins: built-in defaults < a YAML config file (``--config``) < command-line flags.
The effective configuration is written beside every output as ``scan2terrain.yaml`` so a run can be
repeated with ``--config OUT/scan2terrain.yaml``.
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin, get_type_hints

from scan2terrain.errors import ConfigError

# The option vocabulary, declared once: the config fields are typed with these, the CLI takes
# its ``choices=`` from them, and :meth:`Config.validate` checks every field typed with one.
UnknownPolicy = Literal["free", "obstacle", "height"]
Simulator = Literal["gz", "classic", "both"]
Geometry = Literal["auto", "heightmap", "mesh", "boxes", "polylines", "voxels"]
#: Where walls made of scans put their faces (geometry/faces.py).
WallFaces = Literal["auto", "cells", "hits"]
GridKind = Literal["occupancy", "height"]
HeightStat = Literal["max", "min", "mean"]
Fill = Literal["none", "nearest", "idw"]
VoxelPoints = Literal["none", "ply", "pcd"]
PoseSource = Literal["auto", "tf", "odom", "trajectory", "fixed"]
InsertMode = Literal["auto", "raycast", "endpoints"]
#: Pose correction by scan matching and loop closure (slam/).
CorrectMode = Literal["auto", "on", "off"]
LocalOrigin = Literal["auto", "none"]
BitDepth = Literal[8, 16]

#: Filter kinds: 'none' and a name of filters.registry.FILTERS, which holds each one's code and
#: help (the registry checks at import that it implements exactly these).
FilterKind = Literal["none", "median", "majority", "paper", "thin_wall"]
FILTERS: tuple[FilterKind, ...] = get_args(FilterKind)
UNKNOWN_POLICIES: tuple[UnknownPolicy, ...] = get_args(UnknownPolicy)
SIMULATORS: tuple[Simulator, ...] = get_args(Simulator)
GEOMETRIES: tuple[Geometry, ...] = get_args(Geometry)
WALL_FACES: tuple[WallFaces, ...] = get_args(WallFaces)
GRID_KINDS: tuple[GridKind, ...] = get_args(GridKind)
HEIGHT_STATS: tuple[HeightStat, ...] = get_args(HeightStat)
FILLS: tuple[Fill, ...] = get_args(Fill)
VOXEL_POINTS: tuple[VoxelPoints, ...] = get_args(VoxelPoints)
POSE_SOURCES: tuple[PoseSource, ...] = get_args(PoseSource)
INSERT_MODES: tuple[InsertMode, ...] = get_args(InsertMode)
CORRECT_MODES: tuple[CorrectMode, ...] = get_args(CorrectMode)
LOCAL_ORIGINS: tuple[LocalOrigin, ...] = get_args(LocalOrigin)
BIT_DEPTHS: tuple[BitDepth, ...] = get_args(BitDepth)


@dataclass(frozen=True)
class Must:
    """A field's own rule, carried in its type (``Annotated[int, Must(...)]``): ``ok(value)``,
    said as ``want`` in the refusal. None passes (a field that may be None is typed so);
    :meth:`Config.validate` checks every field's rules in one loop."""

    ok: Callable[[Any], bool]
    want: str


def span(lo: float, hi: float, want: str, *, open_lo: bool = False) -> Must:
    """``lo <= value <= hi`` (``lo < value`` when ``open_lo``)."""
    return Must(lambda v: (lo < v if open_lo else lo <= v) and v <= hi, want)


def at_least(lo: float, want: str) -> Must:
    return span(lo, math.inf, want)


def positive(want: str) -> Must:
    return span(0, math.inf, want, open_lo=True)


def length(*counts: int, want: str) -> Must:
    return Must(lambda v: len(v) in counts, want)


#: Ranges of settings whose absurd values would exhaust memory or lose all precision.
MAX_FILTER = 99  #: filter window side, cells
MAX_METRES = 1e5  #: terrain heights
MIN_CELL, MAX_CELL = 1e-4, 1e5  #: pixel and voxel sizes, metres
MIN_VOXEL = 1e-3  #: OctoMap keys are 16-bit: at 1 mm the octree spans 65 m
MAX_SIDE = 1 << 20  #: canvas sides and shifts, heightmap and map tile sides, cells
MAX_ORIGIN = 1e9  #: a local origin's coordinates (a projected CRS spans < 1e8 m)

_SIDE = span(1, MAX_SIDE, f"1..{MAX_SIDE} cells")
_SHIFT = span(-MAX_SIDE, MAX_SIDE, f"within +-{MAX_SIDE} cells")
_PROBABILITY = Must(lambda v: 0 < v < 1, "in (0, 1)")
_POSE6 = length(6, want="[x, y, z, roll, pitch, yaw]")


# Rules named, not lambdas: an annotation is evaluated with its class's namespace as globals.
def _odd_window(n: int) -> bool:
    return 3 <= n <= MAX_FILTER and n % 2 == 1


def _finite_non_negative(x: float) -> bool:
    return 0 <= x < math.inf


def _las_classes(codes: list[int]) -> bool:
    return all(0 <= k <= 255 for k in codes)


def _address(text: str) -> bool:
    return "://" in text


def _model_name(name: str) -> bool:
    return name.replace("_", "").replace("-", "").isalnum()


def _local_origin(v: Any) -> bool:
    return v in LOCAL_ORIGINS or (
        isinstance(v, list)
        and len(v) == 3
        and all(isinstance(x, (int, float)) and abs(x) <= MAX_ORIGIN for x in v)
    )


def _max_side(n: int) -> bool:
    return 3 <= n <= MAX_SIDE + 1 and (n - 1) & (n - 2) == 0


def _tile_cells(n: int) -> bool:
    return 1 <= n <= 1 << 14 and n & (n - 1) == 0


@dataclass
class CanvasConfig:
    """The paper's canvas options, in cells of the input grid.

    ``width``/``height`` crop or extend the grid to that many cells (None keeps the size);
    ``offset_x``/``offset_y`` shift the input inside that canvas (positive moves it right/up, a
    negative offset crops). The origin is updated so every kept cell stays where it was in the map
    frame: cropping never loses the georeferencing.
    """

    width: Annotated[int | None, _SIDE] = None
    height: Annotated[int | None, _SIDE] = None
    offset_x: Annotated[int, _SHIFT] = 0
    offset_y: Annotated[int, _SHIFT] = 0
    invert: bool = False


@dataclass
class FilterConfig:
    """Filtering of the occupancy grid (or the grey image) before it becomes terrain."""

    enabled: bool = True
    #: none, or a name in filters.registry.FILTERS: median | majority | paper (the paper's
    #: modified median) | thin_wall (also diagonals)
    kind: FilterKind = "thin_wall"
    #: Window side for median/majority (odd, >= 3); paper/thin_wall always use 3x3.
    size: Annotated[int, Must(_odd_window, f"odd, 3..{MAX_FILTER}")] = 3
    #: Remove occupied specks of fewer cells than this (8-connected) after filtering; 0 = off.
    speckle_min_cells: Annotated[int, at_least(0, ">= 0")] = 0


@dataclass
class TerrainConfig:
    """How cells become ground heights and pixels."""

    #: Height of occupied cells (maps) or of a white pixel (images), metres.
    height: Annotated[
        float, span(0, MAX_METRES, f"in (0, {MAX_METRES:g}] metres", open_lo=True)
    ] = 2.0
    #: free | obstacle | height: unknown cells as floor, as walls, or at ``unknown_height``.
    unknown: UnknownPolicy = "free"
    unknown_height: Annotated[float, span(0, MAX_METRES, f"in [0, {MAX_METRES:g}] metres")] = 0.5
    #: Integer up-sampling: each cell becomes k x k pixels (thin walls get flat tops).
    upsample: Annotated[int, span(1, 16, "1..16")] = 1
    #: 8 (every Gazebo) or 16 (gz-sim Garden and newer).
    bit_depth: BitDepth = 8
    #: Largest heightmap side (2^n+1 pixels); a bigger grid is written as terrain tiles of this
    #: side placed edge to edge, neighbours sharing their border samples.
    max_side: Annotated[int, Must(_max_side, f"2^n+1, 3..{MAX_SIDE + 1}")] = 4097


@dataclass
class WorldConfig:
    """The Gazebo side."""

    #: gz (gz-sim, SDF 1.9, DART + bullet collision detector) | classic (Gazebo 11, SDF 1.6)
    #: | both (two worlds side by side, one model folder each).
    simulator: Simulator = "both"
    #: Model name; None derives a unique one from the input name and the terrain's content.
    model_name: Annotated[str | None, Must(_model_name, "letters, digits, '_' and '-' only")] = None
    #: Vertex sampling written into the SDF (None: 1 for gz, 2 for classic, each one's default).
    sampling: Annotated[int | None, at_least(1, ">= 1")] = None
    #: How occupancy grids become walls: mesh (extruded outlines: STL, DAE, OBJ) | boxes (the
    #: fewest boxes covering the occupied cells) | polylines (SDF <polyline>), each
    #: ``terrain.height`` high on a ground plane, map frame = world frame in both simulators;
    #: or heightmap. auto: mesh for occupancy grids (exact and the fastest in physics), a
    #: heightmap for heights (images, DEMs, height grids, ``terrain.unknown: height``).
    geometry: Geometry = "auto"
    #: Outline simplification for mesh/polylines: staircases straightened within this many
    #: metres, never moving a cell centre across (the walls cover the same cells); 0 = cell edges.
    simplify: Annotated[float, Must(_finite_non_negative, ">= 0 metres (0: exact)")] = 0.0
    #: Walls' faces (mesh, boxes, polylines): on the cell boundaries (cells: a map's cells are
    #: the truth), or half a cell into a wall toward observed free space, where a scan's end
    #: points lie on average, on a grid of half the cell size (hits); auto: hits for grids
    #: made from scans and octrees, cells for maps and images (the replay measures the gain).
    wall_faces: WallFaces = "auto"
    #: voxels: the side of the cubes (metres) the voxel mesh is cut into, one collision and
    #: visual each (bounded meshes keep Gazebo's mesh loading and broadphase fast).
    chunk: Annotated[float, span(0, MAX_METRES, f"in (0, {MAX_METRES:g}] metres", open_lo=True)] = (
        16.0
    )
    #: voxels: refuse (before writing) a world of more triangles than this.
    max_triangles: Annotated[int, at_least(1, ">= 1")] = 20_000_000
    #: voxels: occupied voxels in 3D connected components (26-connected) of fewer voxels than
    #: this are left out; 0 or 1 keeps all.
    min_voxels: Annotated[int, at_least(0, ">= 0")] = 0
    #: voxels: mesh coarser voxels than the octree's: its resolution times a power of two (a
    #: coarse voxel is occupied if any of its voxels is, as OctoMap's inner nodes); None: the
    #: octree's own.
    voxel_size: Annotated[
        float | None,
        span(
            MIN_VOXEL,
            MAX_CELL,
            f"{MIN_VOXEL:g}..{MAX_CELL:g} metres, or null (the octree's resolution)",
        ),
    ] = None


@dataclass
class OutputConfig:
    preview: bool = True
    #: Scan worlds: replay the recorded beams in the written world(s) (fidelity.yaml/.png).
    fidelity: bool = True
    map_yaml: bool = True
    #: Largest map_server image side (pixels); a bigger map is written as tiles, each with its
    #: own YAML and origin.
    map_max_side: Annotated[int, span(1, MAX_SIDE, f"1..{MAX_SIDE}")] = 16384


@dataclass
class ImageConfig:
    """Inputs that carry no geometry of their own (image2world)."""

    #: Metres per pixel.
    resolution: Annotated[
        float, span(MIN_CELL, MAX_CELL, f"{MIN_CELL:g}..{MAX_CELL:g} m/pixel")
    ] = 0.05
    #: Pose [x, y, yaw] of the image's lower-left corner; None centres it on the origin.
    origin: Annotated[list[float] | None, length(2, 3, want="[x, y] or [x, y, yaw]")] = None


@dataclass
class OctreeConfig:
    """The voxel octree (octree2world): OctoMap's defaults."""

    #: Voxel side in metres, for scan inputs (a .bt file carries its own). None (cloud2world's
    #: default): ``DEFAULT_RESOLUTION``, or coarser for surveys, clouds too wide for
    #: ``terrain.max_side`` cells of it (see :func:`cloud_resolution`).
    resolution: Annotated[
        float | None,
        span(
            MIN_VOXEL,
            MAX_CELL,
            f"{MIN_VOXEL:g}..{MAX_CELL:g} metres, or null (from the clouds' extent)",
        ),
    ] = 0.05
    #: Beams longer than this (metres) are cut there and only clear; < 0 = unlimited (OctoMap).
    max_range: float = -1.0
    hit: Annotated[float, _PROBABILITY] = 0.7
    miss: Annotated[float, _PROBABILITY] = 0.4
    clamp_min: Annotated[float, _PROBABILITY] = 0.1192
    clamp_max: Annotated[float, _PROBABILITY] = 0.971
    occupancy: Annotated[float, _PROBABILITY] = 0.5
    #: Voxels whose centre z is in [z_min, z_max] (metres) make the 2D grid; None = unbounded,
    #: as octomap_server's occupancy_min_z / occupancy_max_z.
    z_min: float | None = None
    z_max: float | None = None
    #: occupancy (octomap_server's projection) | height (2.5D: a column statistic of occupied z).
    grid: GridKind = "occupancy"
    #: max | min | mean of a column's heights (grid: height): its points' z where the grid is
    #: made from points (clouds, bags, OctoMap scan files), voxel centres from a .bt file.
    height_stat: HeightStat = "max"
    #: none | nearest | idw: how empty columns of a height grid are filled.
    fill: Fill = "nearest"
    #: Empty columns farther than this (metres) from a known one stay empty (nearest fill);
    #: None: 4 cells, at least 1 m (a fixed distance shorter than a coarse cell fills nothing).
    fill_max_distance: Annotated[
        float | None, positive("> 0 metres, or null (4 cells, at least 1 m)")
    ] = None
    #: none | ply | pcd: also write the occupied voxel centres as OUT/occupied_voxels.<ext>.
    points: VoxelPoints = "none"

    @property
    def z_band(self) -> tuple[float, float]:
        """``[z_min, z_max]`` in metres, unbounded ends as infinities."""
        return (
            -math.inf if self.z_min is None else self.z_min,
            math.inf if self.z_max is None else self.z_max,
        )


@dataclass
class ScansConfig:
    """Scans from bags and cloud files (bag2world, cloud2world, convert)."""

    #: Topics to read: LaserScan/PointCloud2 topics, or one OccupancyGrid topic; None picks
    #: automatically (one sensible choice, else the choices are listed).
    topics: list[str] | None = None
    #: Time range: seconds from the bag's first message, or absolute UNIX seconds (>= 1e9).
    start: float | None = None
    end: float | None = None
    #: auto (tf, else odometry) | tf | odom | trajectory | fixed
    poses: PoseSource = "auto"
    #: Correct the poses by scan matching and loop closure: on (whatever the source) | off |
    #: auto (only odometry poses: no frame above the odometry frame in tf, or poses odom; kept
    #: only when the recording's beams agree better with the corrected map).
    correct: CorrectMode = "auto"
    #: The frame the world is built in; None: 'map' if the tf tree has it, else 'odom'.
    fixed_frame: str | None = None
    #: Odometry topic (poses: odom); None picks the bag's only nav_msgs/Odometry topic.
    odom_topic: str | None = None
    #: TUM trajectory file (t x y z qx qy qz qw) of the robot base (poses: trajectory).
    trajectory: str | None = None
    #: Sensor pose on the robot base [x, y, z, roll, pitch, yaw] (odom / trajectory poses);
    #: None: from /tf_static when it links the base to the sensor frame, else identity.
    mount: Annotated[list[float] | None, _POSE6] = None
    #: Pose [x, y, z, roll, pitch, yaw] of a stationary sensor in the fixed frame (poses: fixed).
    pose: Annotated[list[float] | None, _POSE6] = None
    #: raycast (free space too, as OctoMap's insertPointCloud) | endpoints (hits only, fast;
    #: for clouds that are already registered) | auto (raycast for bags, endpoints for files).
    insert: InsertMode = "auto"
    #: Longest gap (seconds) in tf or odometry that poses are interpolated across.
    max_gap: Annotated[float, positive("> 0 seconds")] = 1.0
    #: LAS/LAZ classes to keep (e.g. [2]: ground); None keeps every point.
    las_classes: Annotated[
        list[int] | None,
        Must(_las_classes, "LAS classification codes, 0..255"),
    ] = None
    #: Which message of an OccupancyGrid topic: -1 is the last, 0 the first.
    map_message: int = -1
    #: Cloud files: subtract a local origin (auto: when the points lie beyond 1 km of the
    #: origin, e.g. UTM, the rounded centre of their bounding box) | none | [x, y, z] (this
    #: one, in the clouds' own coordinates). The effective config records the origin that
    #: was subtracted as [x, y, z], so a rerun, or another tile of the survey, shares it.
    local_origin: Annotated[
        LocalOrigin | list[float],
        Must(_local_origin, f"auto, none or [x, y, z] within {MAX_ORIGIN:g} of 0"),
    ] = "auto"
    #: Cloud files: their coordinate reference system (what pyproj reads: "EPSG:32610", WKT),
    #: for worlds placed on the earth (<spherical_coordinates>); None: a LAS/LAZ file's own.
    crs: str | None = None
    #: Cloud files: statistical outlier removal (Open3D's neighbour search): a point whose mean
    #: distance to its ``outlier_neighbours`` nearest points is above the mean of all such
    #: distances + this many standard deviations is dropped; None = off.
    outliers: Annotated[
        float | None,
        span(0, 100, "in (0, 100] standard deviations, or null (off)", open_lo=True),
    ] = None
    outlier_neighbours: Annotated[int, span(1, 1000, "1..1000")] = 20


@dataclass
class StreamConfig:
    """Streaming, tiled rasterisation of end points straight into grid columns (no octree), for
    clouds larger than memory; the same work on Dask with ``workers`` or ``scheduler``."""

    #: Off: points go through the octree (ray casting possible). On: end points only, streamed.
    enabled: bool = False
    #: Points read and rasterised at a time: the fixed working set.
    chunk_points: Annotated[int, span(1, 1 << 30, "1..2^30")] = 2_000_000
    #: Grid tiles are this many cells a side (a power of two): the unit of allocation, merging
    #: and of what a Dask task sends back (24 bytes a cell).
    tile_cells: Annotated[int, Must(_tile_cells, "a power of two up to 16384")] = 256
    #: Dask: a local cluster of this many worker processes; 0 = no Dask (single process).
    workers: Annotated[int, span(0, 1024, "0..1024")] = 0
    #: Dask: an existing scheduler's address (tcp://HOST:PORT); workers must reach the inputs.
    scheduler: Annotated[str | None, Must(_address, "an address such as tcp://HOST:8786")] = None

    @property
    def distributed(self) -> bool:
        """The streamed work runs on Dask (local workers or a scheduler)."""
        return bool(self.workers or self.scheduler)

    @property
    def active(self) -> bool:
        """End points are streamed into tiles: asked for, or implied by Dask."""
        return self.enabled or self.distributed


@dataclass
class DemConfig:
    """Digital elevation models (dem2world)."""

    #: Heightmap pixel size in metres; None = the DEM's own (the finer axis when its pixels are
    #: not square). Also the pixel size of a TIFF that carries no georeference.
    resolution: Annotated[
        float | None, span(MIN_CELL, MAX_CELL, f"{MIN_CELL:g}..{MAX_CELL:g} metres")
    ] = None
    #: Also write world_gz_dem.sdf, a gz-sim world that loads the GeoTIFF itself (gz-sim >= 7
    #: built with GDAL).
    passthrough: bool = False
    #: Refuse a DEM with a valid elevation further than this from the datum, metres, either
    #: sign: readers/_limits.py's MAX_ELEVATION_M (what a planet has; a corrupt strip read as
    #: float32 gave 2.6e38 m), widened for a trusted file of something else.
    max_elevation: Annotated[
        float, span(0, MAX_ORIGIN, f"> 0 and <= {MAX_ORIGIN:g} metres", open_lo=True)
    ] = 1e5


@dataclass
class Config:
    canvas: CanvasConfig = field(default_factory=CanvasConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    image: ImageConfig = field(default_factory=ImageConfig)
    octree: OctreeConfig = field(default_factory=OctreeConfig)
    scans: ScansConfig = field(default_factory=ScansConfig)
    dem: DemConfig = field(default_factory=DemConfig)
    stream: StreamConfig = field(default_factory=StreamConfig)
    #: Refuse images with more pixels than this (decompression bombs).
    max_pixels: Annotated[int, positive("> 0")] = 1 << 28
    #: MiB a grid made from voxels or points may take (octree2world, bag2world, cloud2world):
    #: estimated from its cells before it is allocated, and refused above this.
    max_memory: Annotated[int, positive("> 0 (MiB)")] = 8192

    def validate(self) -> Config:
        """Raise :class:`ConfigError` naming the first bad value; return self. Each field's own
        rules are in its type (:class:`Must`); the rules across fields are here."""
        c, w, o, sc = self, self.world, self.octree, self.scans
        _check_fields(c)
        walls = w.geometry not in ("auto", "heightmap", "voxels")
        voxels = w.geometry == "voxels"
        for ok, key, value, want in (
            (
                not voxels or o.grid == "occupancy",
                "octree.grid",
                o.grid,
                "occupancy with world.geometry voxels (the voxels themselves are the world)",
            ),
            (
                not voxels or c.terrain.unknown == "free",
                "terrain.unknown",
                c.terrain.unknown,
                "free with world.geometry voxels (unknown voxels are empty space)",
            ),
            (
                not voxels or not c.stream.active,
                "world.geometry",
                w.geometry,
                "not voxels with --stream, --workers or --scheduler (streaming keeps no voxels)",
            ),
            (
                not walls or c.terrain.unknown != "height",
                "terrain.unknown",
                c.terrain.unknown,
                f"free or obstacle with world.geometry {w.geometry} (walls have one height)",
            ),
            (
                not walls or o.grid == "occupancy",
                "octree.grid",
                o.grid,
                f"occupancy with world.geometry {w.geometry} (walls come from occupied cells)",
            ),
            (
                c.canvas.width is None
                or c.canvas.height is None
                or c.canvas.width * c.canvas.height <= c.max_pixels,
                "canvas.width",
                (c.canvas.width, c.canvas.height),
                f"width x height <= max_pixels ({c.max_pixels})",
            ),
            (o.miss < 0.5 < o.hit, "octree.hit/miss", (o.hit, o.miss), "miss < 0.5 < hit"),
            (o.clamp_min < o.clamp_max, "octree.clamp_min", o.clamp_min, "< clamp_max"),
            (
                o.z_min is None or o.z_max is None or o.z_min <= o.z_max,
                "octree.z_min",
                o.z_min,
                "<= z_max",
            ),
            (
                sc.outliers is None or not c.stream.active,
                "scans.outliers",
                sc.outliers,
                "null with --stream, --workers or --scheduler (a streamed piece sees only its "
                "points)",
            ),
            (
                sc.start is None or sc.end is None or sc.start <= sc.end,
                "scans.start",
                sc.start,
                "<= scans.end",
            ),
            (
                not (c.stream.workers and c.stream.scheduler),
                "stream.workers",
                c.stream.workers,
                "0 when stream.scheduler is given (one or the other)",
            ),
        ):
            _check(ok, key, value, want)
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def for_grid(self, grid: GridKind, *, scans: bool = False) -> Config:
        """This config with ``world.geometry: auto`` resolved for a ``grid`` of ``occupancy``
        or ``height``: a mesh of walls for occupancy (unless unknown cells have a height of
        their own), a heightmap for heights; and ``world.wall_faces: auto``: hits for a grid
        made from ``scans``, else cells. The effective config then says what was built."""
        w = self.world
        if w.geometry == "auto":
            walls = grid == "occupancy" and self.terrain.unknown != "height"
            w = dataclasses.replace(w, geometry="mesh" if walls else "heightmap")
        if w.wall_faces == "auto":
            w = dataclasses.replace(w, wall_faces="hits" if scans else "cells")
        return self if w == self.world else dataclasses.replace(self, world=w)

    def for_poses(self, poses: str, *, corrected: bool) -> Config:
        """This config with ``scans.poses: auto`` resolved to the source the scans were posed
        from (``poses``: tf, odom, trajectory or fixed; "" for a map, which leaves it), and
        ``scans.correct: auto`` to what was decided (on: corrected poses kept; else off), so
        the effective config says how the scans were posed, and a rerun with it poses them
        the same way."""
        sc = self.scans
        if poses and sc.poses == "auto" and poses in POSE_SOURCES:
            sc = dataclasses.replace(sc, poses=poses)
        if poses and sc.correct == "auto":
            sc = dataclasses.replace(sc, correct="on" if corrected else "off")
        return self if sc == self.scans else dataclasses.replace(self, scans=sc)

    def for_insert(self, default: Literal["raycast", "endpoints"]) -> Config:
        """This config with ``scans.insert: auto`` resolved to the command's ``default``
        (raycast for bags, endpoints for cloud files and for streaming, which inserts end
        points only), so the effective config says how the scans went in."""
        if self.scans.insert != "auto":
            return self
        return dataclasses.replace(self, scans=dataclasses.replace(self.scans, insert=default))


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """A section's field types, rules included (evaluated once per class)."""
    if cls not in _HINTS:
        _HINTS[cls] = get_type_hints(cls, include_extras=True)
    return _HINTS[cls]


def _unannotated(hint: Any) -> tuple[Any, tuple[Must, ...]]:
    """A field's type without its rules, and its rules."""
    if get_origin(hint) is Annotated:
        base, *rules = get_args(hint)
        return base, tuple(r for r in rules if isinstance(r, Must))
    return hint, ()


def _check_fields(target: Any, prefix: str = "") -> None:
    """Every field of ``target`` (and of its sections) against its type's rules: a Literal of
    the vocabulary holds one of its values; a value held (not None) passes its Must rules."""
    for f in fields(target):
        value = getattr(target, f.name)
        where = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            _check_fields(value, f"{where}.")
            continue
        hint, rules = _unannotated(_hints(type(target))[f.name])
        if get_origin(hint) is Literal:
            choices = get_args(hint)
            # bool is an int: True must not pass for 1, nor 8.0 for 8.
            ok = any(value == v and type(value) is type(v) for v in choices)
            _check(ok, where, value, f"one of {choices}")
        for rule in rules:
            if value is not None:
                _check(rule.ok(value), where, value, rule.want)


def _check(ok: bool, name: str, value: object, want: str) -> None:
    if not ok:
        raise ConfigError(f"{name} = {value!r} is invalid: must be {want}")


def load_config(
    path: Path | None = None,
    overrides: dict[str, Any] | None = None,
    *,
    defaults: dict[str, Any] | None = None,
) -> Config:
    """Defaults, then a command's own ``defaults``, then the YAML file at ``path``, then
    ``overrides`` (both dicts {"section.key": value})."""

    cfg = Config()
    for dotted, value in (defaults or {}).items():
        _apply(cfg, _nest(dotted, value), "command defaults")
    if path is not None:
        doc = _read_yaml(Path(path))
        if doc is not None:
            if not isinstance(doc, dict):
                raise ConfigError(f"{path}: config must be a mapping of sections")
            _apply(cfg, doc, str(path))
    for dotted, value in (overrides or {}).items():
        if value is None:
            continue
        _apply(cfg, _nest(dotted, value), "command line")
    return cfg.validate()


#: A config file is a few kB; anything past this is not one.
MAX_CONFIG_BYTES = 1 << 20


def _read_yaml(path: Path) -> Any:
    import yaml

    try:
        if not path.is_file():
            what = "not found" if not path.exists() else "not a regular file"
            raise ConfigError(f"{path}: config file {what}")
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ConfigError(f"{path}: config file larger than {MAX_CONFIG_BYTES} bytes")
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{path}: malformed config YAML ({type(exc).__name__})") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file ({exc.strerror or exc})") from exc


def _nest(dotted: str, value: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    cur = out
    parts = dotted.split(".")
    for p in parts[:-1]:
        cur[p] = {}
        cur = cur[p]
    cur[parts[-1]] = value
    return out


def _apply(target: Any, doc: dict[str, Any], source: str, prefix: str = "") -> None:
    hints = _hints(type(target))
    names = {f.name for f in fields(target)}
    for key, value in doc.items():
        where = f"{prefix}{key}"
        if key not in names:
            raise ConfigError(f"{source}: unknown config key '{where}' (known: {sorted(names)})")
        current = getattr(target, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: '{where}' must be a mapping")
            _apply(current, value, source, f"{where}.")
        else:
            setattr(target, key, _coerce(value, _unannotated(hints[key])[0], where, source))


def _coerce(value: Any, hint: Any, where: str, source: str) -> Any:
    """``value`` (from YAML or a flag) as the field's type ``hint``: the first of its kinds
    (``float | None``, ``LocalOrigin | list[float]``) it converts to exactly; a word of the
    vocabulary is taken as it is (validate checks it)."""
    kinds = get_args(hint) if get_origin(hint) in (Union, types.UnionType) else (hint,)
    if value is None:
        if type(None) in kinds:
            return None
        raise ConfigError(f"{source}: '{where}' may not be empty")
    for kind in kinds:
        try:
            return _as(value, kind, where, source)
        except (TypeError, ValueError, OverflowError) as exc:
            if isinstance(exc, ConfigError):
                raise
    text = " | ".join(_kind_text(k) for k in kinds)
    raise ConfigError(f"{source}: '{where}' has the wrong type ({value!r:.60}; expected {text})")


def _kind_text(kind: Any) -> str:
    """A field's type as a YAML author reads it: ``int``, ``list[float]``, ``null``, the words of
    a vocabulary (``'auto' | 'none'``)."""
    if kind is type(None):
        return "null"
    if get_origin(kind) is Literal:
        return " | ".join(repr(v) for v in get_args(kind))
    return str(kind) if get_origin(kind) is not None else str(kind.__name__)


def _as(value: Any, kind: Any, where: str, source: str) -> Any:
    """``value`` as one ``kind``, or TypeError / ValueError."""
    if get_origin(kind) is Literal:  # the vocabulary: its values' type
        kind = type(get_args(kind)[0])
    if get_origin(kind) is list:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
            raise TypeError
        (item,) = get_args(kind)
        return [_as(v, item, where, source) for v in value]
    if kind is bool:
        if isinstance(value, bool):
            return value
        raise TypeError
    if kind is int:
        if isinstance(value, bool) or float(value) != int(value):
            raise TypeError
        return _bounded(int(value), where, source)
    if kind is float:
        if isinstance(value, bool):
            raise TypeError
        return _finite(value, where, source)
    if kind is str:
        if isinstance(value, (list, dict)):
            raise TypeError
        return str(value)
    if kind is type(None):
        raise TypeError
    raise TypeError(f"no conversion to {kind}")


#: No setting is a number beyond this (metres, seconds, cells, points): larger values are
#: typing mistakes, and they overflow the integer types of the arrays they size.
LIMIT = 1e12


def _finite(value: Any, where: str, source: str) -> float:
    number = float(value)
    if not (math.isfinite(number) and abs(number) <= LIMIT):
        raise ConfigError(
            f"{source}: '{where}' = {value!r:.60} is invalid: must be a finite number "
            f"within +-{LIMIT:g}"
        )
    return number


def _bounded(number: int, where: str, source: str) -> int:
    if abs(number) > LIMIT:
        raise ConfigError(
            f"{source}: '{where}' = {str(number)[:24]} is invalid: must be within +-{LIMIT:g}"
        )
    return number


#: The config keys outside any section (options set them by these names, not ``section.key``).
TOP_LEVEL_KEYS = ("max_pixels", "max_memory")


#: The octree's voxel side where none is given: OctoMap's usual indoor resolution.
DEFAULT_RESOLUTION = 0.05


def octree_resolution(cfg: Config) -> float:
    """The voxel side the octree is built at: ``octree.resolution``, or the default."""
    r = cfg.octree.resolution
    return DEFAULT_RESOLUTION if r is None else r


def cloud_resolution(
    lo: Sequence[float], hi: Sequence[float], points: int, cfg: Config
) -> tuple[float, str]:
    """cloud2world's resolution for ``points`` points within ``lo``..``hi`` (metres) when none
    is given, and the reason in words. ``DEFAULT_RESOLUTION`` at robot scale. A survey (the
    longer horizontal side over ``terrain.max_side - 1`` cells of the default, the largest
    heightmap Gazebo is given) gets the coarser of a size bound and twice the points' mean
    spacing over the area, ``2 * sqrt(area / points)``: about four points a cell. At one point
    a cell (the spacing itself) a third of the cells would get none (Poisson): holes in a
    height grid and speckle in an occupancy grid. The size bound: an occupancy grid's longer
    side fits one map of ``max_side - 1`` cells; a height grid (terrain, written as tiles when
    larger than one heightmap) holds at most the cells of one full heightmap,
    ``(max_side - 1)^2``, over the area, whatever its shape (and no finer than the default), so
    a long strip keeps the cells its points allow. Both rounded up to two significant digits.
    Robot-scale clouds keep the default: their points lie on walls and objects in 3D, where the
    area says nothing of their spacing."""
    dx = max(float(hi[0]) - float(lo[0]), 0.0)
    dy = max(float(hi[1]) - float(lo[1]), 0.0)
    side = max(dx, dy)
    cells = cfg.terrain.max_side - 1
    if side <= cells * DEFAULT_RESOLUTION:
        return DEFAULT_RESOLUTION, f"resolution {DEFAULT_RESOLUTION:g} m (the default)"
    if cfg.octree.grid == "height" and dx * dy > 0:
        # No finer than robot scale's default either: a thin strip has a small area.
        res = max(two_digits_up(math.sqrt(dx * dy) / cells), DEFAULT_RESOLUTION)
        bound = (
            f"the clouds span {dx:,.0f} x {dy:,.0f} m, over {cells}^2 cells (one full"
            f" terrain.max_side heightmap's) at {DEFAULT_RESOLUTION:g} m"
        )
    else:
        res = two_digits_up(side / cells)
        bound = (
            f"the clouds span {side:,.0f} m, over terrain.max_side {cells + 1} cells at"
            f" {DEFAULT_RESOLUTION:g} m"
        )
    spacing = math.sqrt(dx * dy / points) if points > 0 else 0.0
    if spacing > 0 and two_digits_up(2 * spacing) > res:
        res = two_digits_up(2 * spacing)
        return res, (
            f"resolution {res:g} m (chosen: the clouds span {dx:,.0f} x {dy:,.0f} m with"
            f" {points:,} points, about four a cell; --resolution sets it)"
        )
    return res, f"resolution {res:g} m (chosen: {bound}; --resolution sets it)"


def two_digits_up(x: float) -> float:
    """``x`` > 0 rounded up to two significant digits (0.1234 -> 0.13)."""
    step = 10.0 ** (math.floor(math.log10(x)) - 1)
    return round(math.ceil(x / step - 1e-9) * step, 12)
