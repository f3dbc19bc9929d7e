"""Where a Gazebo world's files are (:class:`Store`), and a heightmap image decoded from its
bytes (:func:`heightmap_image`), for :mod:`.world`.

A world's files are looked up in a mapping of bytes first (paths relative to the world's folder:
a world folder before it is written), then on disk, each read only when it is a regular file of
at most :data:`MAX_FILE_BYTES`. ``model://NAME/rest`` is looked for under ``models/`` beside the
world, then each model path, then each folder of :data:`RESOURCE_PATH_VARIABLES`.
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path, PurePosixPath

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import raised_in, regular_file
from scan2terrain.readers._pixels import DEFAULT_MAX_PIXELS, _channels, check_png

#: Largest file read (a world, model, mesh or image file).
MAX_FILE_BYTES = 1 << 30
#: Environment variables listing model folders, in the order they are searched.
RESOURCE_PATH_VARIABLES = ("GZ_SIM_RESOURCE_PATH", "IGN_GAZEBO_RESOURCE_PATH", "GAZEBO_MODEL_PATH")


class Store:
    """Where a world's files are: ``files`` first (keys relative to the world's folder), then
    the disk; and where ``model://`` looks."""

    def __init__(
        self, world: Path, files: Mapping[str, bytes] | None, model_paths: Sequence[Path]
    ) -> None:
        self.root = world.parent
        self.files: dict[str, bytes] | None = None
        self.folders: set[str] = set()
        if files is not None:
            self.files = {
                str(PurePosixPath(os.path.normpath(k)).as_posix()): v for k, v in files.items()
            }
            for key in self.files:
                parts = PurePosixPath(key).parts
                self.folders.update("/".join(parts[:i]) for i in range(1, len(parts)))
        env = [
            Path(p)
            for var in RESOURCE_PATH_VARIABLES
            for p in os.environ.get(var, "").split(os.pathsep)
            if p
        ]
        self.search = [self.root / "models", *map(Path, model_paths), *env]

    def _key(self, path: Path) -> str | None:
        if self.files is None:
            return None
        rel = os.path.relpath(path, self.root)
        if rel == os.pardir or rel.startswith(os.pardir + os.sep):
            return None
        return Path(rel).as_posix()

    def is_file(self, path: Path) -> bool:
        key = self._key(path)
        if key is not None and self.files is not None and key in self.files:
            return True
        try:
            return path.is_file()
        except (OSError, ValueError):
            return False

    def is_dir(self, path: Path) -> bool:
        key = self._key(path)
        if key is not None and key in self.folders:
            return True
        try:
            return path.is_dir()
        except (OSError, ValueError):
            return False

    def read(self, path: Path, what: str) -> bytes:
        key = self._key(path)
        if key is not None and self.files is not None and key in self.files:
            return self.files[key]
        size = regular_file(path, what)
        if size > MAX_FILE_BYTES:
            raise InputError(path, f"the {what} has {size:,} bytes, over {MAX_FILE_BYTES:,}")
        try:
            return path.read_bytes()
        except OSError as exc:
            raise InputError(path, f"cannot read the {what} ({exc.strerror or exc})") from exc

    def resolve(self, uri: str, source: Path, where: str) -> Path:
        """The path a URI names, from the file ``source`` (``where`` says which element, for
        messages)."""
        if uri.startswith("model://"):
            rest = uri[len("model://") :].lstrip("/")
            if not rest:
                raise InputError(source, f"{where}: {uri!r} names no model")
            for folder in self.search:
                candidate = folder / rest
                if self.is_file(candidate) or self.is_dir(candidate):
                    return candidate
            shown = ", ".join(str(f) for f in self.search[:4])
            more = f" and {len(self.search) - 4} more" if len(self.search) > 4 else ""
            raise InputError(
                source,
                f"{where}: {uri!r} is found nowhere (looked for {rest!r} in {shown}{more}); "
                f"pass its folder as a model path or add it to {RESOURCE_PATH_VARIABLES[0]}",
            )
        if "://" in uri:
            scheme = uri.partition("://")[0]
            if scheme != "file":
                raise InputError(
                    source,
                    f"{where}: {uri!r}: only model://, file:// and relative paths are read "
                    "(nothing is downloaded)",
                )
            uri = uri[len("file://") :]
        path = Path(uri)
        if not path.is_absolute():
            path = source.parent / path
        return Path(os.path.normpath(path))


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def heightmap_image(
    data: bytes, path: Path
) -> tuple[NDArray[np.integer], NDArray[np.integer], int]:
    """A heightmap image's first channel (H, W), every colour channel (H, W, C) and full scale
    (255 or 65535), decoded by Pillow with the checks of :mod:`._pixels` (PNG chunk CRCs, the
    pixel limit). A palette image gives its indices, as FreeImage gives them to Gazebo; a 16-bit
    colour PNG is refused (Pillow would read 8 of its bits, Gazebo reads 16)."""
    from PIL import Image, UnidentifiedImageError

    if data[:8] == _PNG_SIGNATURE:
        check_png(path, io.BytesIO(data[8:]))
        if len(data) > 25 and data[24] == 16 and data[25] in (2, 4, 6):
            raise InputError(
                path,
                "a 16-bit colour PNG: only 16-bit greyscale is read (Pillow keeps 8 bits of "
                "colour); save the heightmap as 16-bit greyscale",
            )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data))
            with img:
                w, h = img.size
                if w * h > DEFAULT_MAX_PIXELS:
                    raise InputError(
                        path, f"image has {w}x{h} pixels, over the limit of {DEFAULT_MAX_PIXELS}"
                    )
                if w == 0 or h == 0:
                    raise InputError(path, "image is empty")
                img.load()
                if img.mode == "P":
                    indices = np.asarray(img, dtype=np.uint8)
                    return indices, indices[..., None], 255
                channels = _channels(img, path)
    except UnidentifiedImageError:
        raise InputError(path, "not an image file Pillow can read") from None
    except Image.DecompressionBombError as exc:
        raise InputError(path, f"image rejected as a decompression bomb ({exc})") from exc
    except (OSError, SyntaxError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(path, f"cannot decode image (truncated or corrupt?): {exc}") from exc
    except Exception as exc:
        if not raised_in(exc, ("PIL",)):
            raise
        text = " ".join(str(exc).split())[:200]
        raise InputError(path, f"cannot decode image: {type(exc).__name__}: {text}") from exc
    colour = channels.colour
    return colour[:, :, 0], colour, channels.max_value
