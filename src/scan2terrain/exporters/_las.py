"""A :class:`~scan2terrain.types.Cloud` as LAS/LAZ bytes, written by laspy (LAZ compressed by its
lazrs backend), keeping what LAS can hold of it.

* Point format: a LAS cloud's own, when it holds all the cloud's attributes; otherwise the first
  of 0, 1, 2, 3, 6, 7, 8 that holds them (the one that holds most, if none holds all): GPS time
  needs 1, colour 2, both 3; a classification above 31, return numbers above 7, ``scan_angle``,
  ``overlap``, ``scanner_channel`` need 6 or 7, ``nir`` 8. Version 1.2 (0-3) or 1.4 (6-8), or a
  LAS cloud's own.
* Attributes LAS has no dimension for (``normal_x``, ``curvature``, ``alpha``, ...) become
  extra-bytes dimensions of their own type. A value a dimension cannot hold (a class of 300,
  an intensity of 2.5) is not written: the dimension stays 0 and :attr:`LasBytes.lost` says so.
* Coordinates are integers ``X = round((x - offset) / scale)`` per axis: a LAS cloud's own
  scales and offsets, or else the coarsest decimal scale (1 m ... 1e-7 m) and an offset (0, the
  minimum, its floor, its floor to 10 ... 1e6 m) that give every coordinate back exactly
  (``X * scale + offset == x``, as laspy and our reader compute it), so that a LAS file
  converted to a text, PLY or PCD file and back is the same file; failing that, to the last
  bits of a float64 (8 ulp of the largest coordinate: decimal text such as ``636083.30`` is on
  the 0.01 m grid, though not exactly ``63608330 * 0.01`` in binary). Coordinates on no such
  grid are rounded to 1 mm from the floor of their minimum, and ``lost`` says how far they
  moved.
* The records (VLRs and EVLRs: the CRS) of a LAS cloud are copied, and its global encoding (the
  GPS time type), system identifier, file source id and creation date; the generating software
  is scan2terrain, and a cloud without a creation date gets day 0 of year 0 (unknown), so the
  bytes depend on the cloud only.
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import POINT_ATTRIBUTES, Cloud, LasLayout

#: LAS coordinate resolution of the fallback grid, metres.
LAS_SCALE = 0.001
INT32_MAX = 2**31 - 1
_INT32 = (-(2**31), INT32_MAX)
#: Byte offset of the LAS header's creation day-of-year and year (two uint16).
LAS_DATE = slice(90, 94)
#: Point formats chosen for a cloud, in order of preference (no waveform formats).
_FORMATS = (0, 1, 2, 3, 6, 7, 8)
#: Decimal scales tried for coordinates, coarsest first.
_SCALES = tuple(10.0**-k for k in range(8))
#: Values checked for a candidate grid before all of them are.
_SAMPLE = 4096


class LasBytes(NamedTuple):
    data: bytes
    lost: tuple[str, ...]  #: what the file could not hold, in words


def las_bytes(cloud: Cloud, *, compress: bool) -> LasBytes:
    """The cloud as a LAS (or, ``compress``, LAZ) file; ValueError for coordinates that span
    more than LAS's int32 integers can at 1 mm (2147 km)."""
    import laspy  # type: ignore[import-untyped]

    lost: list[str] = []
    layout = cloud.las
    attrs = {k: v for k, v in cloud.attributes.items() if np.asarray(v).ndim == 1}
    fid = _point_format(attrs, layout)
    point_format = laspy.PointFormat(fid)
    standard = set(point_format.dimension_names)
    extra = [k for k in attrs if k not in standard and k not in POINT_ATTRIBUTES]
    unheld = [k for k in attrs if k not in standard and k in POINT_ATTRIBUTES]
    if unheld:
        lost.append(f"{', '.join(unheld)} (not in LAS point format {fid})")
    for name in extra:
        dtype = _extra_dtype(attrs[name])
        point_format.add_extra_dimension(laspy.ExtraBytesParams(name[:32], dtype))
    version = layout.version if layout and layout.point_format == fid else _version(fid)
    header = laspy.LasHeader(point_format=point_format, version=version)
    scales, offsets, moved = _grid(cloud.points, layout)
    header.scales, header.offsets = scales, offsets
    if moved:
        lost.append(moved)
    header.generating_software = "scan2terrain"
    if layout is not None:
        header.global_encoding.value = layout.global_encoding
        header.system_identifier = layout.system_identifier
        header.file_source_id = layout.file_source_id
        vlrs = [laspy.VLR(v.user_id, v.record_id, v.description, v.data) for v in layout.vlrs]
        evlrs = [v for v, r in zip(vlrs, layout.vlrs, strict=True) if r.extended]
        header.vlrs.extend(v for v, r in zip(vlrs, layout.vlrs, strict=True) if not r.extended)
        if evlrs and header.version.minor >= 4:
            from laspy.vlrs.vlrlist import VLRList  # type: ignore[import-untyped]

            header.evlrs = VLRList(evlrs)
        elif evlrs:
            small = [v for v in evlrs if len(v.record_data) < 65536]
            header.vlrs.extend(small)
            if len(small) < len(evlrs):
                lost.append(f"{len(evlrs) - len(small)} extended LAS record(s) (LAS {version})")
    n = len(cloud.points)
    record = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    for axis, name in enumerate("XYZ"):
        record.array[name] = np.round((cloud.points[:, axis] - offsets[axis]) / scales[axis])
    for name in [k for k in attrs if k in standard] + extra:
        dim = record.point_format.dimension_by_name(name[:32])
        values, problem = _fitted(attrs[name], dim)
        if problem:
            lost.append(f"{name} ({problem})")
            continue
        record[name[:32]] = values
    las = laspy.LasData(header=header, points=record)
    out = io.BytesIO()
    las.write(out, do_compress=compress)
    day, year = layout.creation if layout is not None else (0, 0)
    with out.getbuffer() as view:  # laspy stamps today's date: the cloud's, or 0 = unknown
        view[LAS_DATE] = np.array([day, year], dtype="<u2").tobytes()
    return LasBytes(out.getvalue(), tuple(lost))


def _version(fid: int) -> str:
    return "1.2" if fid <= 3 else "1.4"


def _point_format(attrs: dict[str, NDArray[Any]], layout: LasLayout | None) -> int:
    """The point format for these attributes: the layout's if it holds them all, else the
    first of :data:`_FORMATS` that holds the most of them, values and all."""
    import laspy

    known = [k for k in attrs if k in POINT_ATTRIBUTES]
    if layout is not None:
        names = set(laspy.PointFormat(layout.point_format).dimension_names)
        if all(k in names for k in known):
            return layout.point_format
    best, held = 0, -1
    for fid in _FORMATS:
        pf = laspy.PointFormat(fid)
        names = set(pf.dimension_names)
        count = sum(k in names and not _fitted(attrs[k], pf.dimension_by_name(k))[1] for k in known)
        if count > held:
            best, held = fid, count
        if held == len(known):
            break
    return best


def _fitted(values: NDArray[Any], dim: Any) -> tuple[NDArray[Any], str]:
    """``values`` in the type of a laspy dimension, or why they do not fit it."""
    values = np.asarray(values)
    target = np.dtype("u1") if dim.dtype is None else np.dtype(dim.dtype)  # bit fields: <= 8
    if target.kind == "f":
        if values.dtype.kind not in "iuf":
            return values, "not numbers"
        return values.astype(target), ""
    if values.dtype.kind == "f":
        if not np.isfinite(values).all() or not (values == np.round(values)).all():
            return values, "not whole numbers"
    elif values.dtype.kind not in "iu":
        return values, "not numbers"
    if len(values) and (values.min() < dim.min or values.max() > dim.max):
        return values, f"values outside {dim.min}..{dim.max}"
    return values.astype(target), ""


def _extra_dtype(values: NDArray[Any]) -> str:
    """The extra-bytes type for an attribute: its own, float64 for any other."""
    code = np.asarray(values).dtype.str[1:]
    return code if code in ("u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8") else "f8"


def _grid(
    points: NDArray[np.float64], layout: LasLayout | None
) -> tuple[list[float], list[float], str]:
    """Scales and offsets per axis on which every coordinate lies exactly, and "" ; or the 1 mm
    grid and what rounding to it did."""
    scales, offsets = [], []
    worst = 0.0
    for axis in range(3):
        values = points[:, axis]
        lo, hi = float(values.min()), float(values.max())
        if (hi - lo) / LAS_SCALE > _INT32[1] - 1:
            raise ValueError(
                f"points span {hi - lo:.0f} m, more than LAS can hold at {LAS_SCALE} m (2147 km)"
            )
        given = [] if layout is None else [(layout.scales[axis], layout.offsets[axis])]
        found = _exact_grid(values, lo, hi, given)
        if found is None:
            found = (LAS_SCALE, float(np.floor(lo)))
            back = np.round((values - found[1]) / found[0]) * found[0] + found[1]
            worst = max(worst, float(np.abs(back - values).max()))
        scales.append(found[0])
        offsets.append(found[1])
    moved = f"coordinates rounded to {LAS_SCALE} m, moved up to {worst:.2g} m" if worst else ""
    return scales, offsets, moved


def _exact_grid(
    values: NDArray[np.float64], lo: float, hi: float, given: list[tuple[float, float]]
) -> tuple[float, float] | None:
    sample = np.concatenate([values[:: max(1, len(values) // _SAMPLE)], [lo, hi]])
    # Exactly, else to the last bits of a float64 (decimal text: 636083.3 is not 63608330 *
    # 0.01 in binary, yet lies on the 0.01 m grid).
    noise = 8 * float(np.spacing(max(abs(lo), abs(hi))))
    for tolerance in (0.0, noise):
        for scale, offset in _candidates(lo, given):
            if not (_INT32[0] <= (lo - offset) / scale and (hi - offset) / scale <= _INT32[1]):
                continue
            if _on_grid(sample, scale, offset, tolerance) and _on_grid(
                values, scale, offset, tolerance
            ):
                return scale, offset
    return None


def _candidates(lo: float, given: list[tuple[float, float]]) -> Iterable[tuple[float, float]]:
    yield from given
    floors = [float(np.floor(lo / 10.0**k) * 10.0**k) for k in range(7)]
    offsets = list(dict.fromkeys([0.0, lo, *floors]))
    for scale in _SCALES:
        for offset in offsets:
            yield scale, offset


def _on_grid(values: NDArray[np.float64], scale: float, offset: float, tolerance: float) -> bool:
    """Every value is ``X * scale + offset`` for an integer X, computed as laspy does, to
    ``tolerance``."""
    ints = np.round((values - offset) / scale)
    if tolerance == 0.0:
        return bool(np.array_equal(ints * scale + offset, values))
    return bool(np.abs(ints * scale + offset - values).max() <= tolerance)
