"""Opening image files safely and turning them into normalised channel arrays.

Shared by the map_server reader and the arbitrary-image reader. Pillow does the decoding; this
module adds what Pillow leaves out:

* only regular files are opened (a FIFO would wait for a writer);
* a pixel limit checked before decoding (decompression bombs);
* every chunk of a PNG checked against its CRC before Pillow reads it: Pillow checks no IDAT
  CRC, and damaged deflate data that still inflates gave an image with most pixels wrong; a
  PNG that ends before its IEND chunk is refused as truncated (Pillow's
  ``LOAD_TRUNCATED_IMAGES`` stays False, so other formats cut short are refused too);
* a PNG's header against PNG's rules, before Pillow guesses: IHDR first, a colour type PNG
  has and a bit depth that type allows (:data:`PNG_DEPTHS`), methods PNG defines; a palette
  image (colour type 3) needs its PLTE chunk before its image data (Pillow made up a grey
  palette), of whole entries, at most 256, and no pixel may use an entry past its end;
* binary PGM/PPM samples whose maxval is not 255 (or 65535) are decoded here with numpy, and
  samples above the maxval refused: Pillow clamps them (a map's unknown cells became free), and
  decodes such files with a Python loop per sample;
* one error type for every decoding failure (whatever Pillow raises on a corrupt file), and a
  uniform float view of the channels whatever the image mode.
"""

from __future__ import annotations

import logging
import struct
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import raised_in, regular_file

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


def open_pixels(
    path: Path, max_pixels: int = DEFAULT_MAX_PIXELS, *, pictures_only: bool = False
) -> Channels:
    """Decode ``path`` into :class:`Channels`, refusing bombs, truncation and non-images, and
    with ``pictures_only`` elevation rasters too (:func:`elevation_raster`): their samples are
    heights in metres, which grey levels would scale to ``terrain.height``."""
    from PIL import Image, UnidentifiedImageError

    regular_file(path, "image file")
    try:
        with path.open("rb") as f:
            magic = f.read(len(_PNG_SIGNATURE))
            palette = check_png(path, f) if magic == _PNG_SIGNATURE else None
        why = elevation_raster(path) if pictures_only and magic[:4] in _TIFF_MAGIC else None
        if why is not None:
            raise InputError(
                path,
                f"an elevation raster ({why}), not a picture: its samples are heights, "
                "make terrain of it with `scan2terrain dem2world`",
            )
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
                if img.format == "PPM" and img.tile and img.tile[0][0] == "ppm":
                    return _scaled_pnm(path, img)
                img.load()
                if palette is not None:
                    _check_indices(path, img, palette)
                return _channels(img, path)
    except UnidentifiedImageError:
        raise InputError(path, "not an image file Pillow can read") from None
    except Image.DecompressionBombError as exc:
        raise InputError(path, f"image rejected as a decompression bomb ({exc})") from exc
    except (OSError, SyntaxError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(path, f"cannot decode image (truncated or corrupt?): {exc}") from exc
    except Exception as exc:  # whatever else Pillow's code meets in a corrupt file
        if not raised_in(exc, ("PIL",)):
            raise
        text = " ".join(str(exc).split())[:200]
        raise InputError(
            path, f"cannot decode image (corrupt?): {type(exc).__name__}: {text}"
        ) from exc


#: TIFF tags that georeference a raster (GeoTIFF), by name.
_GEO_TAGS = {
    33550: "ModelPixelScale",
    33922: "ModelTiepoint",
    34264: "ModelTransformation",
    34735: "GeoKeyDirectory",
}
_SAMPLE_KINDS = {2: "signed", 3: "floating-point"}
#: Little- and big-endian TIFF and BigTIFF.
_TIFF_MAGIC = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")


def elevation_raster(path: Path) -> str | None:
    """Why the TIFF ``path`` is an elevation raster (a DEM) rather than a picture, or None.

    Its first page is one when it is one band of grey (not colour, not a palette) and is
    georeferenced (any GeoTIFF tag) or holds signed or floating-point samples (pictures are
    unsigned; DEMs are int16, float32 or float64, which Pillow cannot even open). A colour
    GeoTIFF (an orthophoto) stays a picture. Only the tags are read (tifffile), not the pixels;
    a TIFF whose tags cannot be read is left to the decoder to refuse.
    """
    import tifffile

    # tifffile logs what it cannot parse (GDAL's float32 nodata value): library code never prints.
    log = logging.getLogger("tifffile")
    log.addFilter(_drop)
    try:
        with tifffile.TiffFile(path) as tif:
            tags = {int(t.code): t.value for t in tif.pages[0].tags.values()}
    except Exception as exc:
        # Tags tifffile cannot read: the decoding that follows says what is wrong with the file.
        expected = tifffile.TiffFileError | OSError | ValueError | EOFError | IndexError
        if isinstance(exc, expected) or raised_in(exc, ("tifffile",)):
            return None
        raise
    finally:
        log.removeFilter(_drop)
    if _tag_int(tags.get(277, 1)) != 1 or _tag_int(tags.get(262)) not in (0, 1):
        return None  # colour, palette, or not grey (0 MinIsWhite, 1 MinIsBlack)
    found = [name for code, name in _GEO_TAGS.items() if code in tags]
    if found:
        return "GeoTIFF with " + ", ".join(found) + " tags"
    kind = _SAMPLE_KINDS.get(_tag_int(tags.get(339, 1)) or 1)
    if kind is None:
        return None
    bits = _tag_int(tags.get(258))
    return f"{kind} {bits}-bit samples" if bits else f"{kind} samples"


def _drop(record: logging.LogRecord) -> bool:
    """A logging filter that lets nothing through."""
    return False


def _tag_int(value: object) -> int | None:
    """A TIFF tag's first value as an int, or None (absent, or not a number: a corrupt tag)."""
    if isinstance(value, tuple):
        value = value[0] if value else None
    if not isinstance(value, int | float | str):
        return None
    try:
        return int(value)
    except (TypeError, ValueError, OverflowError):
        return None


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: The longest chunk the PNG specification allows (2^31 - 1 bytes).
_PNG_MAX_CHUNK = (1 << 31) - 1
#: PNG's colour types, and the bit depths each allows (the PNG specification, table 11.1).
PNG_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}
_PNG_COLOURS = {0: "grey", 2: "RGB", 3: "palette", 4: "grey and alpha", 6: "RGBA"}
_PALETTE = 3


def _check_ihdr(path: Path, data: bytes) -> int:
    """The colour type of a PNG whose IHDR chunk holds ``data``, checked against PNG's rules."""
    bad = "cannot decode image: the PNG's header breaks the format's rules"
    if len(data) != 13:
        raise InputError(path, f"{bad}: an IHDR chunk of {len(data)} bytes, not 13")
    fields: tuple[int, ...] = struct.unpack(">IIBBBBB", data)
    depth, colour, compression, filtering, interlace = fields[2:]
    if colour not in PNG_DEPTHS:
        raise InputError(
            path,
            f"{bad}: colour type {colour} is none of PNG's ({', '.join(map(str, PNG_DEPTHS))})",
        )
    allowed = PNG_DEPTHS[colour]
    if depth not in allowed:
        raise InputError(
            path,
            f"{bad}: bit depth {depth} with colour type {colour} ({_PNG_COLOURS[colour]}), "
            f"which allows {', '.join(map(str, allowed))}",
        )
    for name, value, most in (("compression", compression, 0), ("filter", filtering, 0),
                              ("interlace", interlace, 1)):  # fmt: skip
        if value > most:
            raise InputError(path, f"{bad}: {name} method {value}, which PNG does not define")
    return colour


def check_png(path: Path, f: BinaryIO) -> int | None:
    """Every chunk of the PNG ``f`` (just past its signature) whole and matching its CRC, up to
    IEND, read 1 MiB at a time (zlib.crc32: about a millisecond a megabyte); its header and
    palette against PNG's rules. Returns the number of palette entries of a palette image, or
    None for the other colour types."""
    truncated = "cannot decode image: truncated PNG"
    corrupt = "cannot decode image: corrupt PNG"
    rules = "cannot decode image: the PNG breaks the format's rules"
    colour: int | None = None
    entries: int | None = None
    pos = len(_PNG_SIGNATURE)
    while True:
        head = f.read(8)
        if len(head) < 8:
            raise InputError(path, f"{truncated}: it has no IEND chunk")
        length, kind = struct.unpack(">I4s", head)
        name = kind.decode("ascii") if kind.isalpha() else f"0x{kind.hex()}"
        if length > _PNG_MAX_CHUNK:
            raise InputError(path, f"{corrupt}: a chunk length of {length} at byte {pos}")
        crc = zlib.crc32(kind)
        left = length
        kept = b""
        while left:
            data = f.read(min(left, 1 << 20))
            if not data:
                break
            crc = zlib.crc32(data, crc)
            if left == length and kind in (b"IHDR", b"PLTE"):
                kept = data
            left -= len(data)
        stored = f.read(4)
        if left or len(stored) < 4:
            have = 8 + length - left + len(stored)
            raise InputError(
                path,
                f"{truncated}: its {name} chunk at byte {pos} needs {length + 12} bytes, the file "
                f"ends {have} bytes into it",
            )
        if struct.unpack(">I", stored)[0] != crc:
            raise InputError(path, f"{corrupt}: its {name} chunk at byte {pos} fails its CRC check")
        if colour is None:
            if kind != b"IHDR":
                raise InputError(path, f"{rules}: its first chunk is {name}, not IHDR")
            colour = _check_ihdr(path, kept)
        elif kind == b"PLTE" and colour == _PALETTE:
            if entries is not None:
                raise InputError(path, f"{rules}: a second PLTE chunk at byte {pos}")
            if not (0 < length <= 3 * 256 and length % 3 == 0):
                raise InputError(
                    path,
                    f"{rules}: a PLTE chunk of {length} bytes at byte {pos}; a palette is 1 to "
                    "256 entries of 3 bytes",
                )
            entries = length // 3
        elif kind == b"IDAT" and colour == _PALETTE and entries is None:
            raise InputError(
                path,
                f"{rules}: colour type 3 (palette) without a PLTE chunk before its image data "
                "(a palette image needs its palette)",
            )
        if kind == b"IEND":
            return entries
        pos += length + 12


def _check_indices(path: Path, img: Any, entries: int) -> None:
    """No pixel of the palette image ``img`` (decoded) uses an entry past its ``entries``."""
    if img.mode not in ("P", "PA"):
        return
    top = int(img.getextrema()[1] if img.mode == "P" else img.getextrema()[0][1])
    if top >= entries:
        raise InputError(
            path,
            "cannot decode image: the PNG breaks the format's rules: its pixels use palette "
            f"index {top} past its {entries} palette entries",
        )


def _scaled_pnm(path: Path, img: Any) -> Channels:
    """A binary PGM/PPM whose maxval is neither 255 nor (PGM) 65535, decoded with numpy: its
    samples scaled to 255 (or 65535 when maxval > 255 in a PGM) as Pillow scales them, with
    Python's rounding, after refusing samples above the maxval (Pillow clamps them)."""
    offset, args = img.tile[0][2], img.tile[0][3]
    maxval = int(args[-1])
    bands = 3 if img.mode == "RGB" else 1
    out_max = 65535 if img.mode == "I" else 255
    dtype = np.dtype(">u1" if maxval < 256 else ">u2")
    w, h = img.size
    need = w * h * bands * dtype.itemsize
    with path.open("rb") as f:
        f.seek(offset)
        raw = f.read(need)
    if len(raw) < need:
        raise InputError(
            path,
            f"truncated: {w}x{h} pixels need {need} bytes after the header, the file has "
            f"{len(raw)}",
        )
    samples = np.frombuffer(raw, dtype=dtype).reshape(h, w, bands)
    top = int(samples.max())
    if top > maxval:
        kind = "PGM" if bands == 1 else "PPM"
        raise InputError(
            path, f"samples up to {top} exceed the {kind}'s maxval {maxval} (corrupt file)"
        )
    # Pillow: round(value / maxval * out_max), in double precision, rounding half to even.
    scaled = np.rint(samples / maxval * out_max)
    colour = scaled.astype(np.uint16 if out_max == 65535 else np.uint8)
    return Channels(colour, None, out_max)


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
