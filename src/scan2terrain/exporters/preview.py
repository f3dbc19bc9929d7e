"""The paper's Fig. 7 as one PNG: original | filtered | difference, side by side."""

from __future__ import annotations

import io

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters.mapserver import trinary_shades

#: Panels wider or taller than this are decimated (every k-th cell) to keep previews small.
MAX_PANEL = 2048
GAP = 8


def preview_png(before: NDArray[np.integer], after: NDArray[np.integer], *, occupancy: bool) -> bytes:
    """Before and after in grid order (row 0 lowest y), same shape, as a three-panel RGB PNG.

    Occupancy grids are drawn in map_saver shades; grey images as they are (scaled to 8 bits).
    The difference panel is the "after" image faded, with cells that changed in colour: red where
    the value went up (e.g. became occupied), blue where it went down.
    """
    from PIL import Image

    if before.shape != after.shape:
        raise ValueError("before and after must have the same shape")
    step = max(1, -(-max(before.shape) // MAX_PANEL))
    b, a = np.flipud(before)[::step, ::step], np.flipud(after)[::step, ::step]
    grey_b, grey_a = (_grey(b, occupancy), _grey(a, occupancy))
    diff = np.repeat((128 + grey_a // 2)[..., None], 3, axis=2)
    up, down = a > b, a < b
    if occupancy:  # unknown (-1) sits between free and occupied, not below free
        rank_b, rank_a = _rank(b), _rank(a)
        up, down = rank_a > rank_b, rank_a < rank_b
    diff[up] = (220, 30, 30)
    diff[down] = (30, 80, 230)
    h, w = b.shape
    canvas = np.full((h, 3 * w + 2 * GAP, 3), 255, dtype=np.uint8)
    canvas[:, :w] = grey_b[..., None]
    canvas[:, w + GAP : 2 * w + GAP] = grey_a[..., None]
    canvas[:, 2 * w + 2 * GAP :] = diff
    buf = io.BytesIO()
    Image.fromarray(canvas).save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def _grey(a: NDArray[np.integer], occupancy: bool) -> NDArray[np.uint8]:
    if occupancy:
        return trinary_shades(a.astype(np.int8))
    top = max(int(a.max(initial=0)), 1)
    return (a.astype(np.float64) * (255.0 / top) if top > 255 else a).astype(np.uint8)


def _rank(a: NDArray[np.integer]) -> NDArray[np.int8]:
    """free 0 < unknown 1 < occupied 2."""
    return np.where(a < 0, 1, np.where(a > 0, 2, 0)).astype(np.int8)
