"""Hand-made GeoTIFFs (tifffile) for the DEM tests: a raster with its pixel scale, tie point,
GeoKeys and nodata tags."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import tifffile

PROJECTED_METRE = {1024: 1, 1025: 1, 3076: 9001}
GEOGRAPHIC_DEG = {1024: 2, 1025: 1, 2048: 4326, 2054: 9102}


def write_geotiff(
    path: Path,
    raster: np.ndarray,
    *,
    scale: tuple[float, float] | None = (1.0, 1.0),
    tie: tuple[float, float] = (0.0, 0.0),
    keys: dict[int, int] | None = None,
    nodata: str | None = None,
    extra: tuple[Any, ...] = (),
    photometric: str | None = None,
) -> Path:
    """A GeoTIFF of ``raster`` (row 0 = north) with the raster's corner (0, 0) at ``tie``."""
    tags: list[Any] = []
    if scale is not None:
        tags += [
            (33550, "d", 3, (scale[0], scale[1], 0.0), True),
            (33922, "d", 6, (0.0, 0.0, 0.0, tie[0], tie[1], 0.0), True),
        ]
    k = PROJECTED_METRE if keys is None else keys
    if k:
        directory = [1, 1, 0, len(k)]
        for key, value in sorted(k.items()):
            directory += [key, 0, 1, value]
        tags.append((34735, "H", len(directory), tuple(directory), True))
    if nodata is not None:
        tags.append((42113, "s", 0, nodata, True))
    tags += list(extra)
    tifffile.imwrite(path, raster, extratags=tags, photometric=photometric)
    return path
