"""Pure, vectorised filters for label maps (occupancy grids) and grey images.

Every filter takes a 2D array and keyword options and returns a new array of the same shape and
dtype; bad arguments raise :class:`ValueError` naming the parameter. No I/O, no logging.
"""

from scan2terrain.filters.majority import majority_filter
from scan2terrain.filters.median import median_filter, paper_median_filter, thin_wall_median_filter
from scan2terrain.filters.speckle import remove_speckles

__all__ = [
    "majority_filter",
    "median_filter",
    "paper_median_filter",
    "remove_speckles",
    "thin_wall_median_filter",
]
