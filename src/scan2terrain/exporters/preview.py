"""The paper's Fig. 7 as one PNG: original | filtered | difference, side by side."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters.mapserver import trinary_shades
from scan2terrain.grids.occupancy import to_rank

#: Panels wider or taller than this are decimated (every k-th cell) to keep previews small.
MAX_PANEL = 2048
#: Previews narrower than this are scaled up by a whole factor (each cell a k x k block of
#: pixels), as long as a panel stays within MAX_PANEL: a 20 x 20 map was a 76 x 20 pixel PNG.
MIN_WIDTH = 600
GAP = 8
#: Palette entries for the difference marks; the faded panel only uses 128..255.
RED, BLUE = 1, 2


def preview_png(before: NDArray[Any], after: NDArray[Any] | None, *, occupancy: bool) -> bytes:
    """Before and after in grid order (row 0 lowest y), same shape, as a three-panel PNG
    (``after`` None: ``before`` alone, one panel).

    Occupancy grids are drawn in map_saver shades; grey images as they are (scaled to 8 bits).
    The difference panel is the "after" image faded, with cells that changed in colour: red where
    the value went up (e.g. became occupied), blue where it went down. The image is a palette PNG
    (grey levels, then the two marks), a third the size of RGB and quicker to write.
    """
    from PIL import Image

    if after is None:
        return _one_panel(before, occupancy)
    if before.shape != after.shape:
        raise ValueError("before and after must have the same shape")
    step = max(1, -(-max(before.shape) // MAX_PANEL))
    b, a = np.flipud(before)[::step, ::step], np.flipud(after)[::step, ::step]
    # Panels use 3..255, so palette entries RED and BLUE mean only the marks.
    grey_b, grey_a = np.maximum(_grey(b, occupancy), 3), np.maximum(_grey(a, occupancy), 3)
    if occupancy:  # unknown (-1) sits between free and occupied, not below free
        b, a = to_rank(b), to_rank(a)
    diff = 128 + grey_a // 2
    diff[a > b] = RED
    diff[a < b] = BLUE
    h, w = b.shape
    canvas = np.full((h, 3 * w + 2 * GAP), 255, dtype=np.uint8)
    canvas[:, :w] = grey_b
    canvas[:, w + GAP : 2 * w + GAP] = grey_a
    canvas[:, 2 * w + 2 * GAP :] = diff
    canvas = _scaled_up(canvas, (h, w))
    palette = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    palette[RED], palette[BLUE] = (220, 30, 30), (30, 80, 230)
    img = Image.frombuffer(
        "P", (canvas.shape[1], canvas.shape[0]), canvas.tobytes(), "raw", "P", 0, 1
    )
    img.putpalette(palette.ravel().tolist())
    buf = io.BytesIO()
    img.save(buf, format="PNG", compress_level=1)  # a preview: speed first
    return buf.getvalue()


def _one_panel(before: NDArray[Any], occupancy: bool) -> bytes:
    from PIL import Image

    step = max(1, -(-max(before.shape) // MAX_PANEL))
    grey = _grey(np.flipud(before)[::step, ::step], occupancy)
    grey = np.ascontiguousarray(_scaled_up(grey, grey.shape))
    buf = io.BytesIO()
    Image.fromarray(grey, mode="L").save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def _scaled_up(image: NDArray[np.uint8], panel: tuple[int, ...]) -> NDArray[np.uint8]:
    """``image`` with each pixel a k x k block: the smallest whole k that makes it
    :data:`MIN_WIDTH` wide, but no more than keeps a ``panel`` (rows, cols) within
    :data:`MAX_PANEL`; 1 for an image that is wide enough."""
    k = min(-(-MIN_WIDTH // image.shape[1]), MAX_PANEL // max(panel))
    if k <= 1:
        return image
    return np.repeat(np.repeat(image, k, axis=0), k, axis=1)


def _grey(a: NDArray[Any], occupancy: bool) -> NDArray[np.uint8]:
    if occupancy:
        return trinary_shades(a.astype(np.int8))
    top = max(int(a.max(initial=0)), 1)
    return (a.astype(np.float64) * (255.0 / top) if top > 255 else a).astype(np.uint8)
