"""Removal of small connected specks of one label."""

from __future__ import annotations

from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from scan2terrain.filters._common import check_2d

__all__ = ["remove_speckles"]

ScalarT = TypeVar("ScalarT", bound=np.generic)

#: Neighbourhoods for scipy.ndimage.label: 4-connected (a cross) and 8-connected (full 3x3).
_STRUCTURES = {
    4: np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool),
    8: np.ones((3, 3), dtype=bool),
}


def remove_speckles(
    labels: NDArray[ScalarT],
    *,
    value: int,
    min_cells: int,
    replace_with: int,
    connectivity: int = 8,
) -> NDArray[ScalarT]:
    """Replace connected components of ``value`` smaller than ``min_cells`` by ``replace_with``.

    Parameters
    ----------
    labels : integer or bool array, shape (H, W)
        Label map, e.g. an int8 occupancy grid (-1 unknown, 0 free, 100 occupied).
    value : int
        The label whose small components are removed, e.g. 100 for specks of noise in free space.
    min_cells : int
        Components with fewer cells than this are replaced; ``min_cells <= 1`` changes nothing.
    replace_with : int
        The label written over removed components, e.g. 0 (free).
    connectivity : {4, 8}
        4: cells are connected through edges only; 8: through edges and corners.

    Returns
    -------
    array, shape (H, W), same dtype as ``labels``
        A new array. Components are cut at the array edge (nothing outside the array is counted).

    Raises
    ------
    ValueError
        If ``labels`` is not a 2D integer array, ``connectivity`` is not 4 or 8, or ``value`` or
        ``replace_with`` cannot be stored in ``labels``' dtype.
    """
    arr = check_2d(labels, "labels")
    if isinstance(connectivity, bool) or connectivity not in _STRUCTURES:
        raise ValueError(f"connectivity must be 4 or 8, got {connectivity!r}")
    _check_fits("value", value, arr.dtype)
    _check_fits("replace_with", replace_with, arr.dtype)
    if isinstance(min_cells, bool) or not isinstance(min_cells, (int, np.integer)):
        raise ValueError(f"min_cells must be an integer, got {min_cells!r}")
    out: NDArray[ScalarT] = np.array(arr, order="C")
    if min_cells <= 1:
        return out
    from scipy import ndimage  # deferred: importing scipy.ndimage costs ~1 s of start-up

    is_value = arr == value
    components, count = ndimage.label(is_value, structure=_STRUCTURES[connectivity])
    # Work on the cells of `value` only: usually a small share of the map (walls, noise).
    cells = np.flatnonzero(is_value)
    cell_component = components.reshape(-1)[cells]
    sizes = np.bincount(cell_component, minlength=count + 1)
    out.reshape(-1)[cells[sizes[cell_component] < min_cells]] = replace_with
    return out


def _check_fits(name: str, label: Any, dtype: np.dtype[Any]) -> None:
    if isinstance(label, bool) or not isinstance(label, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {label!r}")
    if dtype.kind == "b":
        low, high = 0, 1
    else:
        info = np.iinfo(dtype)
        low, high = int(info.min), int(info.max)
    if not low <= label <= high:
        raise ValueError(f"{name} must fit in {dtype} ({low}..{high}), got {label}")
