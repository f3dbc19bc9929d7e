"""Numbers as text for the text formats (OBJ, COLLADA, XYZ/CSV): Python's shortest repr, which
reads back to the same float64."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def float_texts(values: NDArray[np.floating]) -> list[str]:
    """``repr`` of each value as a float64, in C order. Each distinct value is formatted once:
    a mesh's or a voxel grid's coordinates repeat (grid lines, a few heights; normals more so),
    and formatting is most of the cost. Distinct means a distinct bit pattern, so ``-0.0`` keeps
    its sign."""
    flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    bits, index = np.unique(flat.view(np.int64), return_inverse=True)
    texts = np.array([repr(x) for x in bits.view(np.float64).tolist()], dtype=object)
    out: list[str] = texts[index.reshape(-1)].tolist()
    return out


def joined_ints(values: NDArray[np.integer]) -> str:
    """The integers in C order, separated by single spaces (one %-format: C code, about twice
    as fast as joining their ``str``)."""
    flat = np.asarray(values).reshape(-1).tolist()
    return ("%d " * len(flat) % tuple(flat))[:-1]
