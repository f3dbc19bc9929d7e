"""Coordinate reference systems of georeferenced clouds, with pyproj: what a CRS given by the
user or a LAS/LAZ file is, and where a point of it lies on the earth (a world's
``<spherical_coordinates>``). pyproj is imported only here, when a CRS is known."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config, LocalOrigin
from scan2terrain.errors import ConfigError
from scan2terrain.types import EarthAnchor

#: Grid distance (in the CRS's units) to the point whose azimuth gives the world's heading.
_STEP = 100.0


def parse_crs(text: str, *, what: str = "scans.crs") -> Any:
    """The pyproj CRS of ``text`` (``EPSG:32610``, WKT, PROJ string), projected (a world's x
    and y are lengths); ConfigError naming ``what`` otherwise."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_user_input(text)
    except CRSError as exc:
        raise ConfigError(f"{what} = {_short(text)!r}: not a CRS pyproj knows ({exc})") from exc
    if not crs.is_projected:
        raise ConfigError(
            f"{what} = {_short(text)!r} ({crs.name}) is not a projected CRS: its x and y are"
            " not lengths, so a world cannot be built in them"
        )
    return crs


def crs_name(crs: Any) -> str:
    """A (parsed) CRS's short name for notes: ``EPSG:32610 (WGS 84 / UTM zone 10N)``."""
    code = crs.to_authority()
    return f"{':'.join(code)} ({crs.name})" if code else crs.name


def short_form(crs: Any) -> str:
    """What a config file records of a CRS: its authority code when it has one, else WKT."""
    code = crs.to_authority(min_confidence=90)
    return ":".join(code) if code else str(crs.to_wkt())


def earth_anchor(crs: Any, x: float, y: float, z: float) -> EarthAnchor:
    """The WGS 84 position of the point (x, y, z) of the (parsed) ``crs`` (z: elevation in
    its vertical unit, taken as its horizontal one when it has none), and the heading of its
    x axis there: east along the grid turns from true east by the meridian convergence."""
    from pyproj import Geod, Transformer

    to_wgs84 = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = to_wgs84.transform(x, y)
    lon2, lat2 = to_wgs84.transform(x + _STEP, y)
    if not all(math.isfinite(v) for v in (lon, lat, lon2, lat2)):
        raise ConfigError(
            f"scans.crs {crs_name(crs)}: the world's origin ({x:.3f}, {y:.3f}) is outside it"
        )
    azimuth, _, metres = Geod(ellps="WGS84").inv(lon, lat, lon2, lat2)
    unit = crs.axis_info[0].unit_conversion_factor  # metres per CRS unit
    heading = (90.0 - azimuth + 180.0) % 360.0 - 180.0
    return EarthAnchor(lat, lon, z * unit, heading, _STEP * unit / metres)


def _short(text: str) -> str:
    return text if len(text) <= 60 else text[:57] + "..."


def file_crs(paths: Sequence[Path | str], notes: list[str]) -> str | None:
    """The CRS the LAS/LAZ files among ``paths`` declare (their GeoTIFF keys or WKT), as a
    config records it; None when none does, or when they disagree (a note says so)."""
    import laspy  # type: ignore[import-untyped]

    found: dict[str, str] = {}
    for path in paths:
        if not str(path).lower().endswith((".las", ".laz")) or "://" in str(path):
            continue
        try:
            with laspy.open(str(path)) as f:
                crs = f.header.parse_crs()
        except Exception as exc:  # laspy and pyproj raise many kinds on odd VLRs
            notes.append(f"{Path(path).name}: its CRS could not be read ({exc}); none used")
            continue
        if crs is not None:
            found[short_form(crs)] = Path(path).name
    if len(found) > 1:
        notes.append(
            "the files declare different CRSs (" + ", ".join(f"{n}: {c[:40]}" for c, n in
            found.items()) + "): none used for <spherical_coordinates> (set --crs)"
        )  # fmt: skip
        return None
    return next(iter(found), None)


def georeferenced(
    cfg: Config, origin: NDArray[np.float64], paths: Sequence[Path | str], notes: list[str]
) -> Config:
    """``cfg`` as it was used: the local origin subtracted (``scans.local_origin`` as
    [x, y, z], unless none was) and the clouds' CRS (``scans.crs``, from the files when not
    given), so the effective config records both and the worlds can say where they are."""
    sc = cfg.scans
    crs = sc.crs if sc.crs is not None else file_crs(paths, notes)
    if crs is not None:
        parsed = parse_crs(crs)
        axis = parsed.axis_info[0]
        if sc.crs is None:
            notes.append(f"CRS {crs_name(parsed)}, from the file(s): worlds placed on the earth")
        if abs(axis.unit_conversion_factor - 1.0) > 1e-9:
            notes.append(
                f"warning: the CRS's unit is the {axis.unit_name} ({axis.unit_conversion_factor:g}"
                " m), and the world is built in the clouds' own numbers as metres: it is"
                f" {1 / axis.unit_conversion_factor:.4g} times too large (convert the clouds to a"
                " metric CRS first, e.g. pdal translate with filters.reprojection)"
            )
    local: LocalOrigin | list[float] = sc.local_origin
    if np.any(origin != 0) or isinstance(local, list):
        local = [float(v) for v in origin]
    return dataclasses.replace(cfg, scans=dataclasses.replace(sc, local_origin=local, crs=crs))
