"""Small frozen types passed between the stages: readers -> grids -> filters -> exporters.

Frame and unit conventions (see DESIGN.md):

* Lengths in metres, angles in radians, counter-clockwise.
* A grid's ``data[row, col]`` follows ROS ``nav_msgs/OccupancyGrid``: row 0 is the *lowest* y of the
  map, column 0 the lowest x. Cell (row, col) has its centre at
  ``origin + R(yaw) @ ((col + 0.5) * resolution, (row + 0.5) * resolution)`` in the map frame.
* Images (PNG, PGM) are stored top row first, so ``image = np.flipud(data)``; readers and exporters
  do that flip, nothing else does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Occupancy values, as in nav_msgs/OccupancyGrid.
UNKNOWN = -1
FREE = 0
OCCUPIED = 100


def normalise_frame(name: str) -> str:
    """The one rule for tf frame names: surrounding whitespace and leading ``/`` removed.

    ROS 1 tf wrote ``/base_link`` for ``base_link``; ``"/base_link"``, ``" base_link"`` and
    ``"base_link"`` all name the same frame.
    """
    return name.strip().lstrip("/")


@dataclass(frozen=True)
class Scan:
    """One posed scan in the fixed (map) frame, as every scan reader yields it.

    Attributes
    ----------
    points : float64 (N, 3)
        Metres, fixed frame. For a LaserScan, clear-only beams lie beyond ``max_range``.
    origin : float64 (3,)
        The sensor's position, fixed frame.
    max_range : float
        Beams longer than this are cut there and only clear (-1: unlimited).
    stamp_ns : int
        The scan's header stamp (bag time if the stamp is zero; 0 for a scan file).
    topic : str
        The bag topic ('' for a scan file).
    heading : float
        Yaw of the sensor's x axis in the fixed frame (radians CCW).
    rotation : float64 (3, 3) or None
        The sensor frame's orientation in the fixed frame (None: not known, e.g. a scan file
        without a pose); with ``origin``, the sensor pose (``trajectory.tum``).
    """

    points: NDArray[np.float64]
    origin: NDArray[np.float64]
    max_range: float = -1.0
    stamp_ns: int = 0
    topic: str = ""
    heading: float = 0.0
    rotation: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class Beams:
    """Recorded beams for the replay (``replay/beams.py``): every posed scan's sensor pose, and
    the beams with a return (all, or a deterministic sample), fixed frame, metres.

    ``origins`` (S, 3), ``rotations`` (S, 3, 3) and ``stamps_ns`` (S,) are per scan, in the
    order read (the trajectory actually used); ``scan`` (N,) is each beam's scan and
    ``vectors`` (N, 3) float32 its recorded end point less that scan's origin (direction times
    the recorded range). ``returns`` counts every beam with a return, kept or not.
    """

    origins: NDArray[np.float64]
    rotations: NDArray[np.float64]
    stamps_ns: NDArray[np.int64]
    scan: NDArray[np.int32]
    vectors: NDArray[np.float32]
    returns: int


@dataclass(frozen=True)
class Figures:
    """How the simulated ranges of a set of beams compare with the recorded ones: metres, and
    shares of the beams (0..1). Errors are simulated - recorded over the beams that hit
    something; ``nothing`` is the share that hit nothing, ``short``/``long`` the shares that
    hit more than 0.2 m before / beyond the recorded range, ``inside`` the share whose first
    hit faced away from the sensor (it lies inside one of the world's solids). None: no
    beam."""

    beams: int
    median: float | None
    p95: float | None
    signed_median: float | None
    within_5cm: float | None
    within_10cm: float | None
    nothing: float | None
    short: float | None
    long: float | None
    inside: float | None


@dataclass(frozen=True)
class Fidelity:
    """The replay of a recording in one written world: the figures over all beams and per
    tenth of the recording, and what the picture needs (fixed frame)."""

    world: str  #: the world file replayed in
    pose_source: str
    returns: int  #: beams with a return in the recording
    overall: Figures
    tenths: tuple[Figures, ...]
    ends: NDArray[np.float64]  #: (N, 3) the recorded end points, x y z
    errors: NDArray[np.float64]  #: (N,) |simulated - recorded|, inf: hit nothing
    trajectory: NDArray[np.float64]  #: (S, 2) the sensor's x y per scan


@dataclass(frozen=True)
class PoseCorrection:
    """Corrected poses of a recording's scans (``slam/``), and how to move any sensor pose by
    them: the correction of a pose at time t is the planar rigid motion ``D(t) = C(t) P(t)^-1``
    (corrected times prior, in the fixed frame), interpolated between the corrected scans'
    stamps and held before the first and after the last; so other topics move with the scans.

    ``prior`` and ``corrected`` (K, 3) are x, y (metres) and yaw (radians) of the sensor in the
    fixed frame at ``stamps_ns`` (K,), increasing; ``prior_xyz`` (K, 3) and ``prior_xyzw``
    (K, 4) its full prior pose, for ``trajectory_raw.tum``. ``notes`` say what was done.
    """

    stamps_ns: NDArray[np.int64]
    prior: NDArray[np.float64]
    corrected: NDArray[np.float64]
    prior_xyz: NDArray[np.float64]
    prior_xyzw: NDArray[np.float64]
    notes: tuple[str, ...] = ()

    def deltas(self, stamps_ns: NDArray[np.int64]) -> NDArray[np.float64]:
        """(N, 3) x, y, yaw of ``D(t)`` at each stamp."""
        p, c = self.prior, self.corrected
        dyaw = np.unwrap(c[:, 2] - p[:, 2])
        cos, sin = np.cos(dyaw), np.sin(dyaw)
        dx = c[:, 0] - (cos * p[:, 0] - sin * p[:, 1])
        dy = c[:, 1] - (sin * p[:, 0] + cos * p[:, 1])
        t = np.asarray(stamps_ns, dtype=np.float64)
        knots = self.stamps_ns.astype(np.float64)
        return np.stack([np.interp(t, knots, v) for v in (dx, dy, dyaw)], axis=1)

    def apply(
        self, stamps_ns: NDArray[np.int64], rotations: NDArray[np.float64],
        translations: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
        """Sensor poses (rotations (N, 3, 3), translations (N, 3)) moved by ``D`` at their
        stamps."""
        d = self.deltas(stamps_ns)
        cos, sin = np.cos(d[:, 2]), np.sin(d[:, 2])
        rz = np.zeros((len(d), 3, 3))
        rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1] = cos, -sin, sin, cos
        rz[:, 2, 2] = 1.0
        r = rz @ rotations
        t = np.einsum("kij,kj->ki", rz, translations)
        t[:, :2] += d[:, :2]
        return r, t


@dataclass(frozen=True)
class Pose2D:
    """Pose of a grid's lower-left corner in the map frame (metres, radians CCW)."""

    x: float
    y: float
    yaw: float = 0.0

    def transform(
        self, u: NDArray[np.float64], v: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Map grid-local metric coordinates (u along columns, v along rows) to the map frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * u - s * v, self.y + s * u + c * v


@dataclass(frozen=True)
class OccupancyGrid:
    """A 2D occupancy grid.

    Attributes
    ----------
    data : int8 array, shape (H, W)
        -1 unknown, 0 free ... 100 occupied, row 0 at the lowest y.
    resolution : float
        Cell side in metres, > 0.
    origin : Pose2D
        Pose of the lower-left corner of cell (0, 0) in the map frame.
    """

    data: NDArray[np.int8]
    resolution: float
    origin: Pose2D

    def __post_init__(self) -> None:
        if self.data.ndim != 2 or self.data.dtype != np.int8:
            raise ValueError(
                f"data must be a 2D int8 array, got {self.data.dtype} {self.data.shape}"
            )
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise ValueError(f"resolution must be a positive number, got {self.resolution}")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.data.shape[0]), int(self.data.shape[1]))

    def with_data(self, data: NDArray[np.int8], origin: Pose2D | None = None) -> OccupancyGrid:
        return OccupancyGrid(data, self.resolution, self.origin if origin is None else origin)


@dataclass(frozen=True)
class HeightGrid:
    """A 2.5D height grid in the same cell layout as :class:`OccupancyGrid`.

    Attributes
    ----------
    heights : float32 array, shape (H, W)
        Ground height of each cell in metres (map frame z). Meaningful where ``known``.
    known : bool array, shape (H, W)
        Cells that hold a height.
    resolution : float
        Cell side in metres.
    origin : Pose2D
        Pose of the lower-left corner of cell (0, 0).
    """

    heights: NDArray[np.float32]
    known: NDArray[np.bool_]
    resolution: float
    origin: Pose2D

    def __post_init__(self) -> None:
        if self.heights.ndim != 2 or self.heights.shape != self.known.shape:
            raise ValueError("heights and known must be 2D arrays of the same shape")
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise ValueError(f"resolution must be a positive number, got {self.resolution}")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.heights.shape[0]), int(self.heights.shape[1]))


@dataclass(frozen=True)
class Transform:
    """A rigid transform (rotation then translation), e.g. the pose of a sensor frame in the fixed
    frame: ``p_fixed = rotation @ p_sensor + translation``. float64 throughout."""

    rotation: NDArray[np.float64]  #: (3, 3), orthonormal, det +1
    translation: NDArray[np.float64]  #: (3,), metres

    @staticmethod
    def identity() -> Transform:
        return Transform(np.eye(3), np.zeros(3))

    @staticmethod
    def from_quaternion(
        translation: tuple[float, float, float] | NDArray[np.float64],
        quaternion_xyzw: tuple[float, float, float, float] | NDArray[np.float64],
    ) -> Transform:
        """From a ROS translation and quaternion (x, y, z, w; normalised here)."""
        q = np.asarray(quaternion_xyzw, dtype=np.float64)
        n = float(np.linalg.norm(q))
        if not (n > 0 and math.isfinite(n)):
            raise ValueError(f"quaternion {tuple(q)} has no direction")
        x, y, z, w = q / n
        r = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        return Transform(r, np.asarray(translation, dtype=np.float64).reshape(3).copy())

    def apply(self, points: NDArray[np.floating]) -> NDArray[np.float64]:
        """Transform points (N, 3) into float64 (N, 3)."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.rotation.T + self.translation  # type: ignore[no-any-return]

    def compose(self, other: Transform) -> Transform:
        """``self * other``: apply ``other`` first, then ``self`` (tf2's multiplication)."""
        return Transform(
            self.rotation @ other.rotation, self.rotation @ other.translation + self.translation
        )

    def inverse(self) -> Transform:
        rt = self.rotation.T
        return Transform(rt, -(rt @ self.translation))


@dataclass(frozen=True)
class Spawn:
    """Where a robot can start, in the map frame.

    ``(x, y)`` is the centre of the robot's footprint (metres), ``z`` the highest ground under
    it (metres, so a robot whose model origin is at its lowest point rests there), ``yaw`` its
    heading (radians CCW from the map's x axis); ``why`` says how the spot was chosen.
    ``ground`` is False when no ground has room for a robot and the spot is on an obstacle
    (``why`` says why).
    """

    x: float
    y: float
    z: float
    yaw: float
    why: str
    ground: bool = True


@dataclass(frozen=True)
class EarthAnchor:
    """Where a world's origin is on the earth, as SDF's ``<spherical_coordinates>`` says it:
    WGS 84 latitude and longitude (degrees), elevation (metres), and ``heading_deg``, the
    angle counter-clockwise from east to the world's x axis (gz-math: ENU = R(heading) local).
    ``scale``: the source projection's scale factor there (grid distance / true distance), so
    a point d metres away is off by about ``|scale - 1| d`` in Gazebo's tangent-plane frame."""

    latitude_deg: float
    longitude_deg: float
    elevation: float
    heading_deg: float
    scale: float


@dataclass(frozen=True)
class StartPose:
    """Where the robot was when the recording began (map frame), to spawn it there again."""

    pose: Pose2D
    why: str


@dataclass
class ScanCounts:
    """What happened to the scans of a run (for the report)."""

    messages: int = 0
    inserted: int = 0
    points: int = 0
    unposed: int = 0
    empty: int = 0
    first_unposed: str = ""


# --- point clouds ------------------------------------------------------------------------------

#: Per-point attributes known by name: LAS's dimensions (laspy's names, the vocabulary every
#: cloud reader maps its fields to: PDAL's ``Intensity``, CloudCompare's ``scalar_intensity`` and
#: PCL's ``intensity`` are all ``intensity``) and the integer type each has in LAS; a text
#: column of such a name is narrowed to that type when no value changes. Colours (``red``,
#: ``green``, ``blue``) are 8-bit (uint8) or 16-bit (uint16) as the file stores them.
POINT_ATTRIBUTES: dict[str, str] = {
    "intensity": "u2",
    "return_number": "u1",
    "number_of_returns": "u1",
    "scan_direction_flag": "u1",
    "edge_of_flight_line": "u1",
    "classification": "u1",
    "synthetic": "u1",
    "key_point": "u1",
    "withheld": "u1",
    "overlap": "u1",
    "scanner_channel": "u1",
    "scan_angle_rank": "i1",
    "scan_angle": "i2",
    "user_data": "u1",
    "point_source_id": "u2",
    "gps_time": "f8",
    "red": "u2",
    "green": "u2",
    "blue": "u2",
    "nir": "u2",
}
#: A cloud's colour attributes (LAS's and PLY's names), 8 or 16 bits.
COLOUR_ATTRIBUTES = ("red", "green", "blue")


@dataclass(frozen=True)
class LasVlr:
    """One variable-length record of a LAS file, as stored (``extended``: an EVLR)."""

    user_id: str
    record_id: int
    description: str
    data: bytes
    extended: bool = False

    @property
    def is_crs(self) -> bool:
        """A coordinate reference system record (GeoTIFF keys, OGC WKT; liblas' WKT copy)."""
        return self.user_id == "LASF_Projection" or (
            self.user_id == "liblas" and self.record_id == 2112
        )


@dataclass(frozen=True)
class LasLayout:
    """How a LAS/LAZ file stored its points, so that they can be written the same way.

    ``vlrs`` are the file's records (the CRS among them) but for those a writer makes itself
    (LASzip's and the extra-bytes description); ``creation`` is (day of year, year), (0, 0) when
    the file gives none; ``scales`` and ``offsets`` are per axis: ``x = X * scale + offset``.
    """

    version: str
    point_format: int
    scales: tuple[float, float, float]
    offsets: tuple[float, float, float]
    vlrs: tuple[LasVlr, ...] = ()
    global_encoding: int = 0
    system_identifier: str = ""
    file_source_id: int = 0
    creation: tuple[int, int] = (0, 0)

    @property
    def crs(self) -> tuple[LasVlr, ...]:
        return tuple(v for v in self.vlrs if v.is_crs)


@dataclass(frozen=True)
class Cloud:
    """The points of a point-cloud file, and what else it says of them.

    Attributes
    ----------
    points : float64 array, shape (N, 3), N >= 1
        x, y, z as stored (metres for ROS/PCL data; LAS in its CRS units), in the file's own
        frame, finite only.
    path : Path
        The file read.
    format : str
        What was read, e.g. ``"pcd binary_compressed"``, ``"ply binary_little_endian"``,
        ``"laz 1.2 point format 3"``, ``"csv"``.
    records : int
        Points in the file (of the requested LAS classes) before non-finite ones were dropped.
    colours : uint8 array, shape (N, 3), or None
        Red, green, blue (0..255) of each point, row for row with ``points``; None unless
        colours were asked for and the file has them.
    attributes : name -> array, shape (N,)
        Every other per-point field of the file (when asked for), by :data:`POINT_ATTRIBUTES`
        name where one fits, else the file's own, in the file's order and number type; colour
        as ``red``, ``green``, ``blue`` of 8 or 16 bits.
    las : LasLayout or None
        A LAS/LAZ file's point format, scales, offsets and records (its CRS), when attributes
        were asked for.
    unread : tuple of str
        Fields the file has that no attribute carries (a PCD field of COUNT > 1, a PLY list,
        a text column that is not numbers), as ``"name (why)"``.
    """

    points: NDArray[np.float64]
    path: Path
    format: str
    records: int
    colours: NDArray[np.uint8] | None = None
    attributes: Mapping[str, NDArray[Any]] = field(default_factory=dict)
    las: LasLayout | None = None
    unread: tuple[str, ...] = ()

    def take(self, keep: NDArray[np.bool_]) -> Cloud:
        """The cloud of the points where ``keep`` (bool (N,)) is True, their colours and
        attributes with them."""
        return replace(
            self,
            points=np.ascontiguousarray(self.points[keep]),
            colours=None if self.colours is None else np.ascontiguousarray(self.colours[keep]),
            attributes={k: np.ascontiguousarray(v[keep]) for k, v in self.attributes.items()},
        )
