"""Reading SDF elements for :mod:`.world`: numbers (finite, within :data:`MAX_COORDINATE`),
shape fields with SDF 1.9's defaults, polyline points and ``<pose>`` transforms, each failure one
:class:`~scan2terrain.errors.InputError` naming the file and the element's line.

Poses: ``x y z roll pitch yaw`` (radians, or degrees with ``degrees="true"``), rotation
``Rz(yaw) Ry(pitch) Rx(roll)`` as gz-math's; ``rotation_format="quat_xyzw"`` takes
``x y z qx qy qz qw``. A pose ``relative_to`` (SDF 1.5: ``frame``) a frame other than its
parent's is refused: frames are not resolved.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lxml import etree
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers.poses import rpy_matrix

#: Largest length or coordinate (metres) taken as a number rather than a mistake.
MAX_COORDINATE = 1e7
#: Defaults of SDF 1.9 (sdformat's ``sdf/1.9/*_shape.sdf``) for elements left out.
DEFAULTS = {
    "box/size": "1 1 1",
    "cylinder/radius": "1",
    "cylinder/length": "1",
    "sphere/radius": "1",
    "capsule/radius": "0.5",
    "capsule/length": "1",
    "ellipsoid/radii": "1 1 1",
    "plane/normal": "0 0 1",
    "mesh/scale": "1 1 1",
    "heightmap/size": "1 1 1",
    "heightmap/pos": "0 0 0",
    "heightmap/sampling": "1",
    "polyline/height": "1",
}


def rotation_quaternion(x: float, y: float, z: float, w: float) -> NDArray[np.float64]:
    """The rotation of the unit quaternion (x, y, z, w)."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


IDENTITY = np.eye(4)
IDENTITY.flags.writeable = False


def where(el: etree._Element) -> str:
    """An element as messages name it: ``line 12: <collision name="c">``."""
    name = el.get("name")
    named = f' name="{name}"' if name else ""
    return f"line {el.sourceline}: <{el.tag}{named}>"


def numbers(
    el: etree._Element, source: Path, count: int, text: str | None = None
) -> NDArray[np.float64]:
    """``count`` finite numbers within :data:`MAX_COORDINATE` from ``el``'s text (or ``text``,
    a default), float64."""
    raw = el.text if text is None else text
    words = (raw or "").split()
    try:
        values = np.array([float(w) for w in words], dtype=np.float64)
    except ValueError:
        values = np.zeros(0)
    if len(values) != count or len(words) != count:
        raise InputError(
            source, f"{where(el)} must be {count} numbers, got {(raw or '').strip()!r}"
        )
    if not np.isfinite(values).all():
        raise InputError(source, f"{where(el)} holds a number that is not finite")
    if np.abs(values).max(initial=0.0) > MAX_COORDINATE:
        raise InputError(
            source,
            f"{where(el)}: {(raw or '').strip()!r} is beyond {MAX_COORDINATE:g} m",
        )
    return values


def points(line: etree._Element, source: Path) -> NDArray[np.float64]:
    """A ``<polyline>``'s ``<point>`` values, (N, 2): parsed at once, and point by point
    only to name the one at fault."""
    points = list(line.iterchildren("point"))
    words = " ".join(p.text or "" for p in points).split()
    try:
        xy = np.array(words, dtype=np.float64).reshape(-1, 2)
    except ValueError:
        xy = None
    if xy is None or len(xy) != len(points) or not np.isfinite(xy).all():
        for p in points:
            numbers(p, source, 2)
        raise InputError(source, f"{where(line)}: its <point>s are not pairs of numbers")
    if np.abs(xy).max(initial=0.0) > MAX_COORDINATE:
        for p in points:
            numbers(p, source, 2)
    return xy


def field(shape: etree._Element, name: str, source: Path, count: int) -> NDArray[np.float64]:
    """A shape's numeric child (``size``, ``radius``, ...), its SDF default when absent."""
    child = shape.find(name)
    if child is None:
        return numbers(shape, source, count, DEFAULTS[f"{shape.tag}/{name}"])
    return numbers(child, source, count)


def pose(el: etree._Element, source: Path, parents: tuple[str, ...]) -> NDArray[np.float64]:
    """The 4x4 transform of ``el``'s ``<pose>`` child (identity without one)."""
    child = el.find("pose")
    return IDENTITY if child is None else pose_of(child, source, parents)


def pose_of(el: etree._Element, source: Path, parents: tuple[str, ...]) -> NDArray[np.float64]:
    """The 4x4 transform of the ``<pose>`` element ``el``; ``parents`` are the frame names that
    mean its parent (``relative_to`` anything else is refused)."""
    frame = el.get("relative_to") or el.get("frame") or ""
    if frame and frame not in parents:
        raise InputError(
            source,
            f"{where(el)} is relative_to {frame!r}: poses relative to another frame "
            "than the parent's are not supported",
        )
    quaternion = el.get("rotation_format", "euler_rpy") == "quat_xyzw"
    degrees = el.get("degrees", "false").strip().lower() in ("true", "1")
    if not (el.text or "").strip():
        return IDENTITY
    values = numbers(el, source, 7 if quaternion else 6)
    out = np.eye(4)
    out[:3, 3] = values[:3]
    if quaternion:
        q = values[3:]
        length = float(np.linalg.norm(q))
        if length == 0:
            raise InputError(source, f"{where(el)}: the quaternion is zero")
        out[:3, :3] = rotation_quaternion(*(q / length))
    else:
        angles = np.radians(values[3:]) if degrees else values[3:]
        out[:3, :3] = rpy_matrix(*(float(a) for a in angles))  # finite: numbers() checks
    return out
