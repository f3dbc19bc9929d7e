"""Pure, vectorised filters for label maps (occupancy grids) and grey images.

Every filter takes a 2D array and keyword options and returns a new array of the same shape and
dtype; bad arguments raise :class:`ValueError` naming the parameter. No I/O, no logging. The
filters a user can choose are listed in :mod:`scan2terrain.filters.registry`.
"""
