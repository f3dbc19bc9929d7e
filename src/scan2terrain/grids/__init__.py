"""Grids: building and reshaping occupancy and height grids.

``transform`` holds the geometric operations on any grid-ordered array (crop/extend, rotate into
the world's axes, up-sample); ``occupancy`` turns map values into the three classes the terrain
needs.
"""

from scan2terrain.grids.occupancy import from_rank, invert_occupancy, to_rank, to_trinary
from scan2terrain.grids.transform import axis_align, canvas, upsample

__all__ = [
    "axis_align",
    "canvas",
    "from_rank",
    "invert_occupancy",
    "to_rank",
    "to_trinary",
    "upsample",
]
