"""Where a world built from georeferenced clouds lies on the earth: the local origin that was
subtracted from the clouds' coordinates (``scans.local_origin``, recorded in the effective
config), and with a CRS (``scans.crs``, or a LAS/LAZ file's own) the WGS 84 position and
heading of each world's origin for ``<spherical_coordinates>``."""

from __future__ import annotations

from scan2terrain.config import Config
from scan2terrain.readers.crs import crs_name, earth_anchor, parse_crs
from scan2terrain.types import EarthAnchor


def georeference(
    cfg: Config, offset: tuple[float, float], z_offset: float = 0.0
) -> tuple[str, EarthAnchor | None]:
    """For one simulator's world, whose frame is the map frame less ``offset`` (x, y) and
    ``z_offset``: a comment saying how world coordinates map back to the clouds' own, and the
    world origin's place on the earth (None without a CRS). ("", None) when the clouds were
    used as they are and no CRS is known."""
    origin = cfg.scans.local_origin
    crs = cfg.scans.crs
    if not isinstance(origin, list) and crs is None:
        return "", None
    x0, y0, z0 = origin if isinstance(origin, list) else (0.0, 0.0, 0.0)
    ox, oy, oz = x0 + offset[0], y0 + offset[1], z0 + z_offset
    line = (
        f" Georeference: world (x, y, z) = source coordinates - ({ox:.6f}, {oy:.6f}, {oz:.6f})"
        f" (the local origin {x0:.6f}, {y0:.6f}, {z0:.6f}, scans.local_origin"
    )
    line += ")" if offset == (0.0, 0.0) and z_offset == 0.0 else ", and this world's offset)"
    if crs is None:
        return line + "; no CRS known (scans.crs).\n", None

    parsed = parse_crs(crs)
    anchor = earth_anchor(parsed, ox, oy, oz)
    line += (
        f"; CRS {crs_name(parsed)}: the world origin is at latitude {anchor.latitude_deg:.9f},"
        f" longitude {anchor.longitude_deg:.9f}, elevation {anchor.elevation:.3f} m, its x axis"
        f" {anchor.heading_deg:.6f} deg counter-clockwise from east (<spherical_coordinates>;"
        f" the projection's scale there is {anchor.scale:.6f}).\n"
    )
    return line, anchor
