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
from dataclasses import dataclass

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
    """

    points: NDArray[np.float64]
    origin: NDArray[np.float64]
    max_range: float = -1.0
    stamp_ns: int = 0
    topic: str = ""
    heading: float = 0.0


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
    """

    x: float
    y: float
    z: float
    yaw: float
    why: str


@dataclass(frozen=True)
class Start:
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
