"""Opening image files safely and turning them into normalised channel arrays.

Shared by the map_server reader and the arbitrary-image reader. Pillow does the decoding; this
module
adds a pixel limit checked before decoding (decompression bombs), one error type for every decoding
failure, and a uniform float view of the channels whatever the image mode.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

#: Default refusal limit: 2^28 pixels (16384 x 16384), 256 MiB as 8-bit grey.
DEFAULT_MAX_PIXELS = 1 << 28


@dataclass(frozen=True)
class Channels:
    """An image's samples, top row first, as stored (no scaling).

    colour : uint8 or uint16 array (H, W, C), C = 1 for grey images, 3 for colour.
    alpha : array (H, W) of the same dtype, or None when the image has no alpha channel.
    max_value : 255 or 65535, the full-scale sample value.
    """

    colour: NDArray[np.uint8] | NDArray[np.uint16]
    alpha: NDArray[np.uint8] | NDArray[np.uint16] | None
    max_value: int

    def mean_colour(self) -> NDArray[np.float64]:
        """Mean of R, G and B in [0, 1], shape (H, W) (a grey sample counts three times)."""
        mean: NDArray[np.float64] = self.colour.mean(axis=2, dtype=np.float64)
        return mean / self.max_value


def open_pixels(path: Path, max_pixels: int = DEFAULT_MAX_PIXELS) -> Channels:
    """Decode ``path`` into :class:`Channels`, refusing bombs, truncation and non-images."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise InputError(path, "image file not found")
    try:
        with warnings.catch_warnings():
            # We apply our own pixel limit below, before decoding.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(path)
            with img:
                w, h = img.size
                if w * h > max_pixels:
                    raise InputError(
                        path,
                        f"image has {w}x{h} = {w * h} pixels, over the limit of {max_pixels} "
                        "(raise it with --max-pixels if the file is trusted)",
                    )
                if w == 0 or h == 0:
                    raise InputError(path, "image is empty")
                img.load()
                return _channels(img, path)
    except UnidentifiedImageError:
        raise InputError(path, "not an image file Pillow can read") from None
    except Image.DecompressionBombError as exc:
        raise InputError(path, f"image rejected as a decompression bomb ({exc})") from None
    except (OSError, SyntaxError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(path, f"cannot decode image (truncated or corrupt?): {exc}") from None


def _channels(img: object, path: Path) -> Channels:
    from PIL import Image

    assert isinstance(img, Image.Image)
    mode = img.mode
    if mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
        # 16-bit greyscale PNG/TIFF. Pillow widens some of them to 32-bit "I".
        wide = np.asarray(img)
        if wide.size and (int(wide.max()) > 65535 or int(wide.min()) < 0):
            raise InputError(path, f"samples outside 16 bits (mode {mode}) are not supported")
        return Channels(wide.astype(np.uint16)[..., None], None, 65535)
    if mode == "F":
        raise InputError(path, "floating-point images are elevation rasters, not maps or pictures")
    if mode == "P":
        img = img.convert("RGBA" if "transparency" in img.info else "RGB")
    elif mode == "PA":
        img = img.convert("RGBA")
    elif mode not in ("L", "LA", "RGB", "RGBA"):
        img = img.convert("RGB")
    arr = np.asarray(img, dtype=np.uint8)
    if arr.ndim == 2:  # L
        return Channels(arr[..., None], None, 255)
    if arr.shape[2] in (2, 4):  # LA, RGBA
        return Channels(arr[..., :-1], arr[..., -1], 255)
    return Channels(arr, None, 255)
