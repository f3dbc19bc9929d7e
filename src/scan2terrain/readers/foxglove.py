"""Foxglove's own schemas in MCAP (protobuf and JSON) -> the objects the ROS paths give.

For :mod:`scan2terrain.readers._mcap`: channels whose messages are ``protobuf`` (schema encoding
``protobuf``) or ``json`` (schema encoding ``jsonschema``), as the Foxglove SDKs and dataset
converters (nuScenes and others) write them. A message is parsed, then, for the schemas the
pipeline uses, turned into a small object shaped like the ROS message it stands for, so the
readers downstream (:mod:`~scan2terrain.readers.scans`, :mod:`~scan2terrain.readers.tf`,
:mod:`~scan2terrain.readers.tracks`) read it as they read a ROS one. Choices:

* **Parsing.** protobuf with protobuf's dynamic descriptor pool, built from the
  ``FileDescriptorSet`` the MCAP schema record carries (what the file holds, so no generated
  classes and no per-schema package are needed, and any protobuf schema parses); JSON with
  :func:`json.loads` (the JSON schema is not validated, only parsed once to check it is JSON).
  JSON follows Foxglove's JSON schemas: times ``{"sec", "nsec"}``, bytes as base64 strings,
  a quaternion's missing ``w`` is 1. A message that does not parse, or JSON that is not an
  object, raises; :class:`~scan2terrain.readers.bag.Bag` says so in one line naming the file.
  Other schemas (images, scene entities...) are decoded (protobuf message or dict) and left
  unused, as a ROS bag's image topics are.
* **What each schema becomes.**

  - ``foxglove.PointCloud`` -> :class:`PointCloud`: the packed ``fields`` (name, byte offset,
    numeric type, little-endian) read as a strided numpy structured array, as
    :mod:`~scan2terrain.readers.pointcloud2` reads a PointCloud2; ``len(data) // point_stride``
    points (as Foxglove Studio counts them); at least two of x, y, z (a missing one is 0, as
    Foxglove draws it); points with a non-finite coordinate dropped.
  - ``foxglove.LaserScan`` -> :class:`LaserScan`: reading i at ``start_angle + i * (end_angle -
    start_angle) / (n - 1)``, read by REP 117 as a ROS LaserScan is. The schema has no
    ``range_min`` / ``range_max``: ``--max-range`` (``octree.max_range``) stands for the
    missing ``range_max``. With it, finite positive readings below it are hits, readings at or
    beyond it and ``+inf`` (no return) only clear, up to it: exactly the points of a ROS scan
    whose ``range_max`` it is (``range_min`` 0). Without it nothing says how far a no-return
    beam may clear: every finite positive reading is a hit and ``+inf`` is dropped (the plan
    says so). NaN (invalid), ``-inf`` (too close), 0 and negatives are always dropped.
  - Both carry ``pose``, the scan's origin in its ``frame_id``: :meth:`PointCloud.points` and
    :meth:`LaserScan.points` give points in that scan origin's frame and :attr:`local_pose` the
    origin, which the scan reader composes with the frame's pose (so rays start at the scan's
    origin, not the frame's). No pose, or the identity, is ``None``: nothing is composed.
  - ``foxglove.FrameTransform`` / ``foxglove.FrameTransforms`` -> :class:`Transforms`, a
    ``tf2_msgs/TFMessage`` look-alike (``transforms`` of ``TransformStamped`` look-alikes:
    ``header.frame_id`` the parent, ``child_frame_id``, ``transform.translation/rotation``), fed
    to the tf buffer exactly as ``/tf`` is (``static`` when the topic name says so, as for ROS).
    A missing rotation is the identity; a zero quaternion is refused by the buffer as ROS ones are.
  - ``foxglove.PoseInFrame`` -> :class:`PoseInFrame`, a ``nav_msgs/Odometry`` look-alike (the
    pose of the robot base in ``frame_id``; no child frame: ``base_link``).
  - ``foxglove.Grid`` -> :class:`Grid`, a ``nav_msgs/OccupancyGrid`` look-alike: square cells
    (``cell_size.x == cell_size.y``), ``len(data) // row_stride`` rows of ``column_count`` cells,
    row 0 at the pose's origin (as nav_msgs). The occupancy is the field named ``occupancy``
    (else ``data``, else the only field that is not a colour channel): INT8 / UINT8 values as
    nav_msgs' (0-100 occupied probability, -1 / 255 unknown), FLOAT32 / FLOAT64 as a
    probability in [0, 1] (x 100, rounded; NaN unknown). A grid with a field named
    ``elevation``, ``height`` or ``z`` (grid_map's layer names) and none named ``occupancy`` or
    ``data`` is a **height grid** instead: any numeric type, metres above the pose's z, NaN or
    inf no height; bag2world makes terrain of it as of a DEM (:attr:`Grid.heights`). The pose
    must be level (a yaw only). Other layouts are refused when the map is read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers.laserscan import laserscan_points
from scan2terrain.types import Transform

POINT_CLOUD = "foxglove.PointCloud"
LASER_SCAN = "foxglove.LaserScan"
FRAME_TRANSFORM = "foxglove.FrameTransform"
FRAME_TRANSFORMS = "foxglove.FrameTransforms"
POSE_IN_FRAME = "foxglove.PoseInFrame"
GRID = "foxglove.Grid"
SCAN_TYPES = frozenset({POINT_CLOUD, LASER_SCAN})
TF_TYPES = frozenset({FRAME_TRANSFORM, FRAME_TRANSFORMS})
#: How each schema the pipeline reads is used (for ``inspect``).
USES = {
    POINT_CLOUD: "read as scans (points)",
    LASER_SCAN: "read as scans (laser; no range_max: --max-range stands for it)",
    FRAME_TRANSFORM: "read as tf",
    FRAME_TRANSFORMS: "read as tf",
    POSE_IN_FRAME: "read as odometry",
    GRID: "read as an occupancy grid, or a height grid (an elevation field)",
}

#: foxglove.PackedElementField.NumericType -> numpy type (little-endian).
NUMERIC_TYPES: dict[int, str] = {
    1: "<u1",  # UINT8
    2: "<i1",  # INT8
    3: "<u2",  # UINT16
    4: "<i2",  # INT16
    5: "<u4",  # UINT32
    6: "<i4",  # INT32
    7: "<f4",  # FLOAT32
    8: "<f8",  # FLOAT64
}
_TYPE_NAMES = {1: "UINT8", 2: "INT8", 3: "UINT16", 4: "INT16", 5: "UINT32", 6: "INT32"}
_TYPE_NAMES |= {7: "FLOAT32", 8: "FLOAT64"}
_COLOURS = frozenset({"red", "green", "blue", "alpha"})
_OCCUPANCY_NAMES = ("occupancy", "data")
#: The fields a height grid is read from, in this order (grid_map's layer is ``elevation``).
ELEVATION_NAMES = ("elevation", "height", "z")
NS = 1_000_000_000


# --- the ROS-shaped objects ---------------------------------------------------------------------


@dataclass(frozen=True)
class Time:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class Header:
    stamp: Time
    frame_id: str


@dataclass(frozen=True)
class Vector3:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True)
class Quaternion:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass(frozen=True)
class Pose:
    position: Vector3 = field(default_factory=Vector3)
    orientation: Quaternion = field(default_factory=Quaternion)

    def transform(self) -> Transform | None:
        """The pose as a transform, None for the identity."""
        p, q = self.position, self.orientation
        if (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0):
            return None
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
            raise ValueError(f"pose position ({p.x}, {p.y}, {p.z}) is not finite")
        return Transform.from_quaternion((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


@dataclass(frozen=True)
class TfTransform:
    translation: Vector3
    rotation: Quaternion


@dataclass(frozen=True)
class TransformStamped:
    header: Header
    child_frame_id: str
    transform: TfTransform


@dataclass(frozen=True)
class Transforms:
    """``foxglove.FrameTransform(s)`` as a ``tf2_msgs/TFMessage``."""

    transforms: list[TransformStamped]


@dataclass(frozen=True)
class PoseWithCovariance:
    pose: Pose


@dataclass(frozen=True)
class PoseInFrame:
    """``foxglove.PoseInFrame`` as a ``nav_msgs/Odometry`` (no child frame)."""

    header: Header
    pose: PoseWithCovariance
    child_frame_id: str = ""


@dataclass(frozen=True)
class PackedField:
    name: str
    offset: int
    type: int


def _packed_dtype(fields: list[PackedField], stride: int, what: str) -> np.dtype[np.void]:
    names: list[str] = []
    formats: list[str] = []
    offsets: list[int] = []
    for f in fields:
        if f.type not in NUMERIC_TYPES:
            raise ValueError(f"{what} field {f.name!r} has an unknown numeric type {f.type}")
        size = int(NUMERIC_TYPES[f.type][2])
        if f.offset < 0 or f.offset + size > stride:
            raise ValueError(
                f"{what} field {f.name!r} (offset {f.offset}, {size} bytes) does not fit in its "
                f"stride of {stride} bytes"
            )
        if f.name in names:
            raise ValueError(f"{what} has two fields named {f.name!r}")
        names.append(f.name)
        formats.append(NUMERIC_TYPES[f.type])
        offsets.append(f.offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": stride})


@dataclass(frozen=True)
class PointCloud:
    """``foxglove.PointCloud``: ``header``, the scan origin ``local_pose``, and its points."""

    header: Header
    local_pose: Transform | None
    point_stride: int
    fields: list[PackedField]
    data: bytes

    def points(self, max_range: float = -1.0) -> tuple[NDArray[np.float64], float]:
        """The finite points (float64 (N, 3), in the cloud's origin frame, in data order) and
        the max range to insert them with (``max_range`` as given: clouds have none).

        Raises
        ------
        InputError
            (naming no file) Fewer than two coordinate fields, a field that does not fit or has
            an unknown type, two fields of one name.
        """
        try:
            return self._points(max_range)
        except ValueError as exc:
            raise InputError(None, str(exc)) from None

    def _points(self, max_range: float) -> tuple[NDArray[np.float64], float]:
        stride = self.point_stride
        axes = [f for f in self.fields if f.name in ("x", "y", "z")]
        if sum(1 for a in ("x", "y", "z") if any(f.name == a for f in axes)) < 2:
            raise ValueError(
                "PointCloud needs at least two of the fields x, y, z; it has "
                + (", ".join(f.name for f in self.fields) or "none")
            )
        if stride <= 0:
            if not self.data:
                return np.zeros((0, 3)), max_range
            raise ValueError(f"PointCloud point_stride is {stride}")
        records = np.frombuffer(
            self.data,
            dtype=_packed_dtype(axes, stride, "PointCloud"),
            count=len(self.data) // stride,
        )
        xyz = np.zeros((records.size, 3))
        with np.errstate(invalid="ignore"):  # a signalling NaN, dropped below
            for axis, name in enumerate(("x", "y", "z")):
                if name in records.dtype.names:  # type: ignore[operator]
                    xyz[:, axis] = records[name]
        with np.errstate(over="ignore", invalid="ignore"):
            total = xyz.sum()
        if not np.isfinite(total):
            finite = np.isfinite(xyz)
            xyz = np.compress(finite[:, 0] & finite[:, 1] & finite[:, 2], xyz, axis=0)
        return xyz, max_range


@dataclass(frozen=True)
class LaserScan:
    """``foxglove.LaserScan``: ``header``, the scan origin ``local_pose``, and its readings."""

    header: Header
    local_pose: Transform | None
    start_angle: float
    end_angle: float
    ranges: NDArray[np.float64]

    def points(self, max_range: float = -1.0) -> tuple[NDArray[np.float64], float]:
        """Points in the scan origin's frame (z = 0) and the max range to insert them with.

        With ``max_range`` > 0 (the scanner's range, which the schema lacks) the points of a ROS
        LaserScan with that ``range_max`` and ``range_min`` 0 (:func:`laserscan_points`): hits
        below it, clear-only beams for readings at or beyond it and for ``+inf``. Without (-1:
        no cut), every finite positive reading is a hit and ``+inf`` is dropped. NaN, ``-inf``
        and readings <= 0 are dropped either way (REP 117)."""
        r = self.ranges
        n = r.size
        if not (math.isfinite(self.start_angle) and math.isfinite(self.end_angle)):
            raise InputError(
                None,
                f"LaserScan angles must be finite (start {self.start_angle}, end {self.end_angle})",
            )
        increment = (self.end_angle - self.start_angle) / (n - 1) if n > 1 else 0.0
        cut = max_range > 0
        with np.errstate(invalid="ignore"):
            positive = r > 0  # False for NaN and -inf
            finite = positive & np.isfinite(r)
            kept = positive if cut else finite  # +inf clears only as far as a cut says
        cleaned = np.where(kept, r, np.nan)
        # Without a cut, a range_max beyond every reading (all are hits; capped to stay finite).
        top = float(r[finite].max()) if finite.any() else 0.0
        limit = max_range if cut else min(top * 2 + 1, np.finfo(np.float64).max)
        scan = SimpleNamespace(
            ranges=cleaned,
            angle_min=self.start_angle,
            angle_increment=increment,
            range_min=0.0,
            range_max=limit,
        )
        pts, cutoff = laserscan_points(scan)
        return pts, (cutoff if cut else -1.0)


@dataclass(frozen=True)
class GridInfo:
    width: int
    height: int
    resolution: float
    origin: Pose


@dataclass(frozen=True)
class Grid:
    """``foxglove.Grid`` as a ``nav_msgs/OccupancyGrid``: ``header``, ``info``, and ``data``
    (int8, row-major, row 0 at the origin), decoded from its field when first read."""

    header: Header
    info: GridInfo
    cell_size: tuple[float, float]
    row_stride: int
    cell_stride: int
    fields: list[PackedField]
    raw: bytes = field(repr=False)

    @property
    def is_elevation(self) -> bool:
        """Whether the grid holds heights: a field named ``elevation``, ``height`` or ``z`` and
        none named ``occupancy`` or ``data``."""
        names = {f.name for f in self.fields}
        return not names & set(_OCCUPANCY_NAMES) and bool(names & set(ELEVATION_NAMES))

    @property
    def data(self) -> NDArray[np.int8]:
        """Occupancy values as nav_msgs has them (see the module docstring).

        Raises
        ------
        ValueError
            Cells that are not square, a layout that does not fit, or no occupancy field.
        """
        chosen = self._occupancy_field()
        values = self._cells(chosen)
        kind = np.dtype(NUMERIC_TYPES[chosen.type])
        if kind.kind == "f":
            with np.errstate(invalid="ignore"):
                p = values.astype(np.float64)
                if np.any(np.isfinite(p) & ((p < 0) | (p > 1))):
                    raise ValueError(
                        f"Grid field {chosen.name!r} ({_TYPE_NAMES[chosen.type]}) holds values "
                        "outside [0, 1]; float cells are read as occupancy probabilities "
                        f"(name the field one of {', '.join(ELEVATION_NAMES)} for heights)"
                    )
                return np.where(np.isfinite(p), np.rint(p * 100), -1).astype(np.int8)
        if kind.itemsize != 1:
            raise ValueError(
                f"Grid field {chosen.name!r} is {_TYPE_NAMES[chosen.type]}; occupancy is read "
                "from INT8, UINT8, FLOAT32 or FLOAT64 cells"
            )
        out: NDArray[np.int8] = np.array(values).view(np.int8)  # a copy: 255 -> -1
        return out

    @property
    def heights(self) -> NDArray[np.float64]:
        """The elevation field's values (metres above the grid's pose; NaN or inf: no height),
        row 0 at the origin.

        Raises
        ------
        ValueError
            Cells that are not square, a layout that does not fit, or no elevation field.
        """
        by_name = {f.name: f for f in self.fields}
        names = [n for n in ELEVATION_NAMES if n in by_name]
        if not names:
            raise ValueError(f"Grid has no field named {', '.join(ELEVATION_NAMES)}")
        out: NDArray[np.float64] = self._cells(by_name[names[0]]).astype(np.float64)
        return out

    def _cells(self, chosen: PackedField) -> NDArray[np.generic]:
        """The field's values as an (H, W) strided view of the bytes, the layout checked."""
        sx, sy = self.cell_size
        if sx != sy:
            raise ValueError(f"Grid cells are {sx} x {sy} m; only square cells are read")
        w, h = self.info.width, self.info.height
        if w <= 0 or self.row_stride <= 0 or self.cell_stride <= 0:
            raise ValueError(
                f"Grid of {w} columns, row_stride {self.row_stride}, cell_stride {self.cell_stride}"
            )
        if self.cell_stride * w > self.row_stride:
            raise ValueError(
                f"Grid rows of {w} cells of {self.cell_stride} bytes do not fit in "
                f"row_stride {self.row_stride}"
            )
        dtype = _packed_dtype([chosen], self.cell_stride, "Grid")
        cells = np.ndarray(  # a strided view of the bytes: rows row_stride apart
            shape=(h, w), dtype=dtype, buffer=self.raw, strides=(self.row_stride, self.cell_stride)
        )
        values: NDArray[np.generic] = cells[chosen.name]
        return values

    def _occupancy_field(self) -> PackedField:
        by_name = {f.name: f for f in self.fields}
        for name in _OCCUPANCY_NAMES:
            if name in by_name:
                return by_name[name]
        others = [f for f in self.fields if f.name not in _COLOURS]
        if len(others) == 1 and others[0].name not in ELEVATION_NAMES:
            return others[0]
        listed = ", ".join(f.name for f in self.fields) or "none"
        raise ValueError(
            f"Grid has no occupancy field (named 'occupancy', 'data', or its only non-colour "
            f"field); its fields: {listed}"
        )
