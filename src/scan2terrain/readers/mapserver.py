"""ROS map_server maps: a YAML file plus an image, read exactly as nav2's map_server does.

Reference: nav2 ``nav2_map_server/src/map_io.cpp`` (``loadMapYaml`` and ``loadMapFromFile``):

* ``shade`` is the mean of R, G and B in [0, 1]; in trinary mode an alpha channel is averaged in
  as a fourth channel (opaque = 1), as map_server does "to preserve existing behaviour".
* ``occ = shade if negate else 1 - shade``.
* trinary: ``occ > occupied_thresh`` -> 100, ``occ < free_thresh`` -> 0, else -1.
* scale: a non-opaque pixel -> -1, then as trinary, with the values in between mapped to
  ``rint(100 * (occ - free) / (occupied - free))``.
* raw: ``round(255 * shade)`` when it lies in 0..100, else -1 (negate is not applied).
* Image row y becomes grid row H - 1 - y (row 0 of the grid is the map's lowest y).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.readers._limits import MAX_COORDINATE_M, MAX_SPACING_M, MIN_SPACING_M, within
from scan2terrain.readers._pixels import DEFAULT_MAX_PIXELS, Channels, open_pixels
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN, OccupancyGrid, Pose2D

MODES = ("trinary", "scale", "raw")
#: A map may reach this many of its cells from the coordinate origin. Beyond, float64 map
#: coordinates no longer keep its cell edges apart for the outlines and meshes made from them
#: (an origin of 1e308 m made the mesh triangulation fail); UTM coordinates (1e7 m) at 1 mm
#: cells are within it.
MAX_REACH_CELLS = 2.0**34
#: ... and at most this many metres (a million km: beyond any coordinate on a planet; meshes are
#: float32, and 1e300 m cells overflowed the outlines).
MAX_REACH_M = 1e9
#: An origin yaw beyond this many radians is a corrupt number, not an angle (a real map's is
#: within +-pi; Gazebo's parser refuses pose values beyond 1e7).
MAX_YAW_RAD = 1e6
#: A map YAML is a few hundred bytes; a larger file is not read.
MAX_YAML_BYTES = 1 << 20


@dataclass(frozen=True)
class MapMetadata:
    """The fields of a map_server YAML, validated. Paths are absolute."""

    yaml_path: Path
    image: Path
    resolution: float
    origin: Pose2D
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str


def read_map_yaml(
    path: Path, *, max_pixels: int = DEFAULT_MAX_PIXELS
) -> tuple[MapMetadata, OccupancyGrid]:
    """Read a map_server YAML and its image into an :class:`OccupancyGrid`.

    Raises
    ------
    InputError
        Naming the YAML or image file and the problem, for every malformed input.
    """
    meta = read_map_metadata(path)
    channels = open_pixels(meta.image, max_pixels)
    data = occupancy_from_pixels(channels, meta)
    problem = extent_problem(data.shape, meta.resolution, meta.origin)
    if problem:
        raise InputError(path, problem)
    return meta, OccupancyGrid(np.ascontiguousarray(np.flipud(data)), meta.resolution, meta.origin)


def extent_problem(shape: tuple[int, ...], resolution: float, origin: Pose2D) -> str | None:
    """Why a map of ``shape`` cells placed by ``resolution`` and ``origin`` cannot be built on
    (a non-finite or non-positive number, cells outside
    :data:`~scan2terrain.readers._limits.MIN_SPACING_M` ..
    :data:`~scan2terrain.readers._limits.MAX_SPACING_M`, or a corner too far from 0: see
    :data:`MAX_REACH_CELLS` and :data:`MAX_REACH_M`), or None. Also used for OccupancyGrid
    messages."""
    if not (math.isfinite(resolution) and resolution > 0):
        return f"resolution {resolution} is not a positive number of metres"
    if not MIN_SPACING_M <= resolution <= MAX_SPACING_M:
        return (
            f"resolution = {resolution:.6g} m makes no sense: its size must be within "
            f"{MIN_SPACING_M:g}..{MAX_SPACING_M:g} m"
        )
    if not all(math.isfinite(v) for v in (origin.x, origin.y, origin.yaw)):
        return f"origin ({origin.x}, {origin.y}, {origin.yaw}) is not finite"
    if abs(origin.yaw) > MAX_YAW_RAD:
        return f"origin yaw {origin.yaw:g} rad is no angle (beyond +-{MAX_YAW_RAD:g} rad): corrupt"
    reach = max(abs(origin.x), abs(origin.y)) + math.hypot(*shape[:2]) * resolution
    if not reach <= min(MAX_REACH_CELLS * resolution, MAX_REACH_M):
        return (
            f"the map reaches {reach:.3g} m from 0, more than {MAX_REACH_M:g} m or 2^34 of its "
            f"{resolution:g} m cells: its origin or resolution is corrupt"
        )
    return None


def read_map_metadata(path: Path) -> MapMetadata:
    """Parse and validate the YAML half of a map_server map."""
    import yaml

    path = Path(path)
    size = regular_file(path, "map YAML file")
    if size > MAX_YAML_BYTES:
        raise InputError(
            path, f"larger than {MAX_YAML_BYTES:,} bytes: not a map_server YAML ({size:,} bytes)"
        )
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        where = ""
        mark = getattr(exc, "problem_mark", None)
        if mark is not None:
            where = f" at line {mark.line + 1}, column {mark.column + 1}"
        raise InputError(path, f"malformed YAML{where}") from exc
    except UnicodeDecodeError:
        raise InputError(path, "not a text file (expected a map_server YAML)") from None
    except RecursionError:
        raise InputError(path, "malformed YAML (nested too deeply)") from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise InputError(path, f"malformed YAML ({_short(exc)})") from exc
    except OSError as exc:
        raise InputError(path, f"cannot read the map YAML ({exc.strerror or exc})") from exc
    if not isinstance(doc, dict):
        raise InputError(path, "expected a map_server YAML mapping with image, resolution, origin")

    image_field = _required(doc, "image", path)
    if not isinstance(image_field, str) or not image_field.strip():
        raise InputError(path, "'image' must be a file name")
    if "\0" in image_field:
        raise InputError(path, "'image' holds a NUL byte")
    image = Path(image_field).expanduser()
    if not image.is_absolute():
        try:
            image = (path.resolve().parent / image).resolve()
        except (OSError, RuntimeError):  # a link loop, a name too long: named when opened
            image = Path.cwd() / path.parent / image

    resolution = _number(doc, "resolution", path)
    if not resolution > 0:
        raise InputError(path, f"'resolution' must be > 0 metres per pixel, got {resolution}")
    # A pixel of a micrometre to a degree of arc (1e-300 m failed deep in the outlines).
    within(path, "resolution", resolution, lo=MIN_SPACING_M, hi=MAX_SPACING_M, unit="m")

    origin_field = _required(doc, "origin", path)
    if not isinstance(origin_field, list):
        raise InputError(path, "'origin' must be a list [x, y, yaw]")
    if len(origin_field) != 3:
        # nav2's loadMapYaml refuses any other length, and ROS1's map_server reads origin[2].
        raise InputError(
            path,
            "'origin' must be [x, y, yaw] (3 numbers, as nav2's map_server requires), not "
            f"{len(origin_field)}",
        )
    try:
        ox, oy, yaw = (float(v) for v in origin_field)
    except (TypeError, ValueError):
        raise InputError(path, "'origin' must hold numbers [x, y, yaw]") from None
    except OverflowError:  # an integer beyond any float
        raise InputError(path, "'origin' must hold finite numbers") from None
    if not all(math.isfinite(v) for v in (ox, oy, yaw)):
        raise InputError(path, "'origin' must hold finite numbers")
    within(path, "origin x", ox, lo=0.0, hi=MAX_COORDINATE_M, unit="m")
    within(path, "origin y", oy, lo=0.0, hi=MAX_COORDINATE_M, unit="m")

    negate_field = doc.get("negate", 0)
    if isinstance(negate_field, bool) or negate_field in (0, 1):
        negate = bool(negate_field)
    else:
        raise InputError(path, f"'negate' must be 0, 1, true or false, got {_short(negate_field)}")

    occ = _number(doc, "occupied_thresh", path)
    free = _number(doc, "free_thresh", path)
    if not 0.0 <= free < occ <= 1.0:
        raise InputError(
            path,
            f"thresholds out of order: need 0 <= free_thresh ({free}) < occupied_thresh ({occ})"
            " <= 1",
        )

    mode_field = doc.get("mode", "trinary")
    mode = str(mode_field).strip().lower()
    if mode not in MODES:
        raise InputError(
            path, f"'mode' must be one of {', '.join(MODES)}, got {_short(mode_field)}"
        )

    return MapMetadata(path, image, resolution, Pose2D(ox, oy, yaw), negate, occ, free, mode)


def occupancy_from_pixels(channels: Channels, meta: MapMetadata) -> NDArray[np.int8]:
    """Pixel samples (top row first) to occupancy values -1/0..100, top row first."""
    full = float(channels.max_value)
    if meta.mode == "trinary" and channels.alpha is not None:
        # map_server averages alpha in as a fourth channel in trinary mode.
        shade = (channels.mean_colour() * 3.0 + channels.alpha / full) / 4.0
    else:
        shade = channels.mean_colour()

    if meta.mode == "raw":
        percent = np.floor(shade * 255.0 + 0.5)  # std::round, half away from zero (>= 0 here)
        inside = percent <= OCCUPIED
        return np.where(inside, percent, UNKNOWN).astype(np.int8)

    occ = shade if meta.negate else 1.0 - shade
    out = np.full(occ.shape, UNKNOWN, dtype=np.int8)
    if meta.mode == "scale":
        between = (occ >= meta.free_thresh) & (occ <= meta.occupied_thresh)
        scaled = np.rint((occ - meta.free_thresh) / (meta.occupied_thresh - meta.free_thresh) * 100)
        out[between] = scaled[between].astype(np.int8)
    out[occ > meta.occupied_thresh] = OCCUPIED
    out[occ < meta.free_thresh] = FREE
    if meta.mode == "scale" and channels.alpha is not None:
        out[channels.alpha != channels.max_value] = UNKNOWN
    return out


def _required(doc: dict[str, Any], key: str, path: Path) -> Any:
    if key not in doc:
        raise InputError(path, f"missing required key '{key}'")
    return doc[key]


def _number(doc: dict[str, Any], key: str, path: Path) -> float:
    value = _required(doc, key, path)
    if isinstance(value, str):
        # YAML 1.1 (PyYAML) reads "5e-2" as a string; map_server's yaml-cpp reads it as 0.05.
        with contextlib.suppress(ValueError):
            value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(path, f"'{key}' must be a number, got {_short(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits
        raise InputError(path, f"'{key}' must be a finite number, got {_short(value)}") from None
    if not math.isfinite(number):
        raise InputError(path, f"'{key}' must be finite, got {number}")
    return number


def _short(value: object, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters, for one-line messages."""
    text = repr(value) if not isinstance(value, BaseException) else str(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
