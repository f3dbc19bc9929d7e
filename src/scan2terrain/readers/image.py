"""Any picture (PNG, JPG, TIFF, BMP, PGM; grey, RGB, RGBA, palette, 16-bit) as a grey image."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.readers._pixels import DEFAULT_MAX_PIXELS, open_pixels

#: ITU-R BT.601 luma weights, the ones Pillow's convert("L") uses.
LUMA = np.array([0.299, 0.587, 0.114])


@dataclass(frozen=True)
class GreyImage:
    """A grey image, top row first.

    values : uint8 or uint16 array (H, W); ``max_value`` (255 or 65535) is white.
    """

    path: Path
    values: NDArray[Any]
    max_value: int


def read_grey_image(path: Path, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> GreyImage:
    """Read ``path`` and reduce it to luminance (not just its first channel).

    Colour images become ``0.299 R + 0.587 G + 0.114 B`` rounded to the stored depth; grey images
    are kept as they are, 16-bit included. An alpha channel is ignored: a transparent pixel keeps
    the height of its colour. An elevation raster (a GeoTIFF, or one band of signed or
    floating-point samples) is refused with a pointer to dem2world: its heights are metres.
    """
    path = Path(path)
    ch = open_pixels(path, max_pixels, pictures_only=True)
    dtype = np.uint16 if ch.max_value == 65535 else np.uint8
    if ch.colour.shape[2] == 1:
        values = np.ascontiguousarray(ch.colour[..., 0])
    else:
        luma = ch.colour @ LUMA
        values = np.clip(np.rint(luma), 0, ch.max_value).astype(dtype)
    return GreyImage(path, values, ch.max_value)
