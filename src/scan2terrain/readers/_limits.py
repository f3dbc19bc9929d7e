"""What a number read from a file may be, against the physical world: one named limit each.

A file's header can hold any bit pattern; these are the values a real file of the places a robot
drives can hold. Each reader checks the numbers it reads against the limit that fits, with
:func:`within`, and refuses the file in one line naming the file, the field and the value.
Limits a real user could need wider are also options (see each one's comment).
"""

from __future__ import annotations

import math

from scan2terrain.errors import InputError

#: The smallest spacing of samples, metres: pixel sizes, grid resolutions, coordinate scales. A
#: micrometre is below any survey instrument's precision.
MIN_SPACING_M = 1e-6
#: The largest pixel or cell, metres: about one degree of arc on the Earth.
MAX_SPACING_M = 1.2e5
#: The same two in degrees of arc, for geographic rasters and scales (1e-11 degree is about a
#: micrometre).
MIN_SPACING_DEG, MAX_SPACING_DEG = 1e-11, 1.0
#: A coordinate's distance from its CRS origin, metres: a projected CRS spans under 1e8 m, the
#: Earth's geocentric coordinates stay under 7e6 m.
MAX_COORDINATE_M = 1e9
#: The smallest size of a coordinate other than 0, metres: float32's smallest normal number. A
#: point nearer to 0 is no measurement but a damaged number (a denormal, a text's 1e-300).
MIN_COORDINATE_M = 1.1754943508222875e-38
#: Elevations, metres from the datum, either sign: what a planet has (Olympus Mons is 22 km
#: high; the deepest trench 11 km deep). dem2world's ``--max-elevation`` widens it.
MAX_ELEVATION_M = 1e5
#: A body's semi-axes, metres, as a geographic CRS's ellipsoid gives them: from a small asteroid
#: mapped in latitude and longitude (Bennu's radius is 245 m) to a gas giant (Jupiter's 7.1e7 m).
MIN_BODY_RADIUS_M, MAX_BODY_RADIUS_M = 10.0, 1e8


def within(path: object, field: str, value: float, *, lo: float, hi: float, unit: str) -> float:
    """``value`` when it is finite and ``lo <= |value| <= hi`` (``lo`` may be 0); else one
    :class:`InputError` naming the file, the field and the value."""
    if not (math.isfinite(value) and lo <= abs(value) <= hi):
        raise InputError(
            str(path),
            f"{field} = {value:.6g} {unit} makes no sense: its size must be within "
            f"{lo:g}..{hi:g} {unit}",
        )
    return value


def exact_after_scaling(path: object, field: str, scale: float, offset: float, span: float) -> None:
    """Refuse integer coordinates ``offset + k * scale`` (``|k * scale| <= span``) that float64
    cannot hold to within their own step: beyond 2^52 steps of ``scale`` from 0, neighbouring
    values merge (an offset of 1e17 m with a 1 mm scale puts every point in a 16 m bin)."""
    largest = abs(offset) + abs(span)
    if math.isfinite(largest) and math.ulp(largest) <= abs(scale) / 2:
        return
    raise InputError(
        str(path),
        f"{field}: offset {offset:.6g} with scale {scale:.6g} cannot be held exactly in "
        "float64 (neighbouring coordinates would merge)",
    )
