"""What a bag path names, and the files rosbags is given for it (:func:`_source`).

For :func:`scan2terrain.readers.bag.open_bag`: the format sniffed from the first bytes, ROS1 and
rosbag2 layouts told apart, zstd bags decompressed under a cap, suffixes fixed by symlinks in
locked temporary folders. Choices:

* **What can be opened.** A ROS1 ``.bag`` file; several ``.bag`` files of one split recording
  (a list of paths, or a folder of ``.bag`` files); a rosbag2 folder (``metadata.yaml``
  plus ``.db3``/``.mcap``, also with ``compression_mode: FILE`` zstd, which rosbags decompresses
  itself); a standalone ``.db3`` or ``.mcap`` file without ``metadata.yaml``; a standalone
  zstd-compressed ``.mcap.zstd``/``.db3.zstd`` file, decompressed here into a temporary folder
  (with the ``zstd`` module rosbags itself depends on, so no extra dependency). The format is
  sniffed from the first bytes, not the suffix, so errors can say what a file really is; a bag
  with the wrong suffix is opened through a temporary symlink because rosbags dispatches on
  the suffix.
* **Only regular files are opened** (:func:`~scan2terrain.readers._files.regular_file`): a named
  pipe given as a bag, or as the storage file of a rosbag2 folder, waited for a writer forever.
* **Decompression is capped.** A whole-file zstd bag (standalone, or each file of a rosbag2
  folder with ``compression_mode: FILE``, which rosbags would decompress without a limit) is
  decompressed here, streamed, to at most :data:`MAX_ZSTD_RATIO` times its size (at least
  :data:`MIN_ZSTD_BUDGET`): a 49 KB file inflated to 1.6 GB. A frame that states its size is
  refused before anything is written.
* **Temporary folders** (``.s2t-bag-*.part`` in the system's temporary folder) are held under
  an exclusive ``flock`` while they live, and removed when the bag is closed; those of killed
  runs, which nobody holds, are removed by the next bag read (the rule and the code of
  :mod:`scan2terrain.exporters.output`'s output folders).
"""

from __future__ import annotations

import codecs
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from functools import cache
from pathlib import Path, PurePath
from typing import Any

from scan2terrain.errors import InputError
from scan2terrain.fileio import TMP_PREFIX, locked, sweep, try_lock
from scan2terrain.readers._files import regular_file

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

_MAGIC_ROS1 = b"#ROSBAG V2.0"
_MAGIC_ROSRECORD = b"#ROSRECORD"
_MAGIC_SQLITE = b"SQLite format 3\x00"
_MAGIC_MCAP = b"\x89MCAP0\r\n"
_MAGIC_ZSTD = b"\x28\xb5\x2f\xfd"
_STORAGE_SUFFIX = {"sqlite3": ".db3", "mcap": ".mcap"}
_STORAGE_NAMES = (".db3", ".mcap", ".db3.zstd", ".mcap.zstd")
#: A zstd bag is decompressed to at most this many times its size (and at least
#: :data:`MIN_ZSTD_BUDGET` bytes). Recordings compress 2 to 10 times; the nav2 fixture, mostly
#: an empty costmap, 120 times. A trusted file beyond it can be decompressed with ``zstd -d``.
MAX_ZSTD_RATIO = 200
MIN_ZSTD_BUDGET = 64 << 20
#: A rosbag2 ``metadata.yaml`` lists topics and files: kilobytes.
MAX_METADATA_BYTES = 16 << 20
_LEGACY_HINT = (
    "this is the pre-2010 '#ROSRECORD V1.2' bag format, which only ROS1's own rosbag reads; "
    "convert it in ROS1 with 'rosbag reindex old.bag' (rewrites it as V2.0, keeping "
    "old.orig.bag) or 'rosbag fix old.bag new.bag'"
)


# --- finding out what a path is -------------------------------------------------------------------


def _sniff(path: Path) -> str:
    """The format of a file from its first bytes: ros1, rosrecord, sqlite3, mcap, zstd, ..."""
    with path.open("rb") as f:
        head = f.read(256)
    if not head:
        return "empty"
    for kind, magic in (
        ("ros1", _MAGIC_ROS1),
        ("rosrecord", _MAGIC_ROSRECORD),
        ("sqlite3", _MAGIC_SQLITE),
        ("mcap", _MAGIC_MCAP),
        ("zstd", _MAGIC_ZSTD),
    ):
        if head.startswith(magic):
            return kind
    if head.startswith(b"#ROSBAG"):
        return "ros1-other"
    printable = all(b >= 0x20 or b in b"\t\n\r\f" for b in head)
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
    except UnicodeDecodeError:
        return "unknown"
    return "text" if printable else "unknown"


def _not_a_bag(path: Path, kind: str) -> InputError:
    if kind == "empty":
        return InputError(path, "the file is empty, not a bag")
    if kind == "rosrecord":
        return InputError(path, _LEGACY_HINT)
    if kind == "ros1-other":
        return InputError(path, "unsupported ROS1 bag version (only '#ROSBAG V2.0' is read)")
    if kind == "text":
        hint = (
            "; for a rosbag2 recording pass the folder that holds metadata.yaml"
            if path.suffix in {".yaml", ".yml"}
            else ""
        )
        return InputError(path, f"this is a text file, not a ROS bag{hint}")
    return InputError(
        path,
        "not a ROS bag (expected a ROS1 .bag, a rosbag2 folder, or a .db3 / .mcap file)",
    )


@dataclass(frozen=True)
class Source:
    """What to hand to AnyReader, and which path to name in messages."""

    paths: tuple[Path, ...]  # as given by the user (named in errors)
    read: tuple[Path, ...]  # what rosbags opens (staged copies or symlinks where needed)


def _temp_folder(stack: ExitStack) -> Path:
    """A new folder in the system's temporary folder, removed when ``stack`` closes.

    It holds an exclusive flock while it lives, so the next bag read can tell the folder of a
    killed run from a live one's and remove it (:func:`scan2terrain.fileio.sweep`,
    under a short lock on the temporary folder, as for output folders).
    """
    # Lazy: the output module is a later stage's, shared here as fileio shares it.

    parent = Path(tempfile.gettempdir())
    try:
        with locked(parent):
            sweep(parent)
            folder = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}bag-", suffix=".part", dir=parent))
            lock = try_lock(folder)
    except OSError as exc:
        raise InputError(
            None, f"cannot make a temporary folder in {parent} ({exc.strerror or exc})"
        ) from exc
    if lock is not None:
        stack.callback(os.close, lock)
    stack.callback(shutil.rmtree, folder, ignore_errors=True)  # first, then the lock goes
    return folder


def _stage(path: Path, kind: str, stack: ExitStack) -> Path:
    """A path rosbags will accept for a file of this kind (it dispatches on the suffix)."""
    want = ".bag" if kind == "ros1" else _STORAGE_SUFFIX[kind]
    if path.suffix == want:
        return path
    link = _temp_folder(stack) / (path.stem + want)
    link.symlink_to(path.resolve())
    return link


def _too_big(limit: int, size: int) -> str:
    return (
        f"more than {limit:,} bytes, {MAX_ZSTD_RATIO} times its {size:,} (at least "
        f"{MIN_ZSTD_BUDGET:,}: MAX_ZSTD_RATIO in scan2terrain.readers._bag_source): a zstd bomb? "
        "If the file is trusted, decompress it with 'zstd -d' and give the result"
    )


def _inflate(path: Path, out: Path) -> None:
    """Decompress the zstd file ``path`` into ``out``, streamed, refusing (before writing
    anything, when its first frame states its size) more than the budget."""
    size = path.stat().st_size
    limit = max(MIN_ZSTD_BUDGET, MAX_ZSTD_RATIO * size)
    try:
        with path.open("rb") as raw:
            try:
                declared = zstd.get_frame_info(raw.read(18)).decompressed_size
            except zstd.ZstdError:  # no frame header: decompression says what is wrong
                declared = None
            if declared is not None and declared > limit:
                raise InputError(
                    path, f"its zstd frame holds {declared:,} bytes, {_too_big(limit, size)}"
                )
            raw.seek(0)
            total = 0
            with zstd.open(raw, "rb") as src, out.open("wb") as dst:
                while chunk := src.read(1 << 20):
                    total += len(chunk)
                    if total > limit:
                        raise InputError(path, f"decompresses to {_too_big(limit, size)}")
                    dst.write(chunk)
    except (OSError, zstd.ZstdError, EOFError) as exc:
        raise InputError(path, f"cannot decompress this zstd file ({exc})") from exc
    except InputError:
        out.unlink(missing_ok=True)  # now: the folder goes only when the bag is closed
        raise


def _decompress(path: Path, stack: ExitStack) -> Path:
    """Decompress a whole-file zstd bag (``.mcap.zstd``) into a temporary file."""
    out = _temp_folder(stack) / "bag"
    _inflate(path, out)
    kind = _sniff(out)
    if kind not in _STORAGE_SUFFIX:
        raise InputError(path, "a zstd file that does not hold a .mcap or .db3 bag")
    return out.rename(out.with_suffix(_STORAGE_SUFFIX[kind]))


#: What rosbags reads of ``rosbag2_bagfile_information`` without a default.
_METADATA_KEYS = (
    "version",
    "storage_identifier",
    "relative_file_paths",
    "duration",
    "starting_time",
    "message_count",
    "topics_with_message_count",
)


def _metadata(meta: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a rosbag2 folder's ``metadata.yaml`` (``meta``),
    with ``relative_file_paths`` as plain names. Read here first, so that what is wrong with it
    is said of it: UTF-8 text, YAML with keys once each (as rosbags' ruamel has them), a
    mapping with the keys rosbags reads."""
    import yaml

    try:
        text = meta.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            meta, f"byte {exc.start} is not UTF-8 text: not a rosbag2 metadata.yaml"
        ) from None
    except OSError as exc:
        raise InputError(meta, f"cannot read it ({exc.strerror or exc})") from exc
    try:
        doc = yaml.load(text, Loader=_unique_key_loader())
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow
        line = text.count("\n", 0, exc.position) + 1
        column = exc.position - (text.rfind("\n", 0, exc.position) + 1) + 1
        raise InputError(
            meta,
            f"malformed YAML at line {line}, column {column} (character #x{exc.character:04x} "
            "is not allowed)",
        ) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None)
        detail = f" ({' '.join(str(problem).split())[:120]})" if problem else ""
        raise InputError(meta, f"malformed YAML{where}{detail}") from None
    except (RecursionError, ValueError):  # nested too deeply; an integer of 5000 digits
        raise InputError(meta, "malformed YAML (nested too deeply, or a huge number)") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise InputError(meta, "not rosbag2 metadata: no 'rosbag2_bagfile_information' mapping")
    missing = [k for k in _METADATA_KEYS if k not in info]
    if missing:
        raise InputError(meta, f"rosbag2_bagfile_information has no {missing[0]!r}")
    paths = info["relative_file_paths"]
    if not isinstance(paths, list) or not all(isinstance(x, str) and x for x in paths):
        raise InputError(meta, "its relative_file_paths is not a list of file names")
    return {**info, "relative_file_paths": [PurePath(x).name for x in paths]}


@cache
def _unique_key_loader() -> type[Any]:
    import yaml

    class Loader(yaml.SafeLoader):
        """PyYAML's safe loader refusing a key twice in one mapping, as ruamel (rosbags) does."""

        def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
            seen: set[Any] = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                try:
                    twice = key in seen
                    seen.add(key)
                except TypeError:  # an unhashable key: PyYAML says so below
                    continue
                if twice:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"found duplicate key {key!r}", key_node.start_mark
                    )
            return super().construct_mapping(node, deep=deep)

    return Loader


def _unpack_file_mode(folder: Path, info: dict[str, Any], stack: ExitStack) -> Path | None:
    """For a rosbag2 folder compressed file by file (``compression_mode: FILE``, zstd): a copy
    with its files decompressed here (capped) and a metadata.yaml that says so, for rosbags to
    read instead of decompressing them itself without a limit; None for any other folder."""
    import yaml

    names: list[str] = info["relative_file_paths"]
    mode = str(info.get("compression_mode") or "").lower()
    if mode != "file" or info.get("compression_format") != "zstd" or not names:
        return None
    if not all((folder / name).is_file() for name in names):
        return None  # rosbags names the missing ones
    staged = _temp_folder(stack) / folder.name
    staged.mkdir()
    unpacked = [PurePath(name).stem for name in names]  # rosbags' own names for them
    for name, out in zip(names, unpacked, strict=True):
        _inflate(folder / name, staged / out)
    plain = {**info, "compression_mode": "", "compression_format": ""}
    plain["relative_file_paths"] = unpacked
    (staged / "metadata.yaml").write_text(
        yaml.safe_dump({"rosbag2_bagfile_information": plain}), encoding="utf-8"
    )
    return staged


def _rosbag2(path: Path, stack: ExitStack) -> Source:
    """A rosbag2 folder: its metadata.yaml and storage files must be regular files."""
    meta = path / "metadata.yaml"
    if regular_file(meta, "bag") > MAX_METADATA_BYTES:
        raise InputError(
            meta, f"larger than {MAX_METADATA_BYTES:,} bytes: not a rosbag2 metadata file"
        )
    info = _metadata(meta)
    listed = set(info["relative_file_paths"])
    for entry in sorted(path.iterdir()):
        if entry.name.endswith(_STORAGE_NAMES) or entry.name in listed:
            regular_file(entry, "bag")
    staged = _unpack_file_mode(path, info, stack)
    if staged is not None:
        return Source((path,), (staged,))
    if path.suffix == ".bag":  # rosbags reads every *.bag path as a ROS1 file
        link = _temp_folder(stack) / path.stem
        link.symlink_to(path.resolve(), target_is_directory=True)
        return Source((path,), (link,))
    return Source((path,), (path,))


def _source(given: Path | str | Sequence[Path | str], stack: ExitStack) -> Source:
    items = [Path(given)] if isinstance(given, (str, os.PathLike)) else [Path(p) for p in given]
    if not items:
        raise InputError(None, "no bag given")
    for p in items:
        if not p.is_dir():  # a file, or nothing: refused before it is opened unless regular
            regular_file(p, "bag", missing="bag not found")
    if len(items) > 1:  # a split ROS1 recording
        staged = []
        for p in items:
            if p.is_dir() or (kind := _sniff(p)) != "ros1":
                raise InputError(
                    p,
                    "several paths are read as one split ROS1 recording: "
                    "each must be a ROS1 .bag file",
                )
            staged.append(_stage(p, kind, stack))
        return Source(tuple(items), tuple(staged))

    path = items[0]
    if path.is_file() and path.name == "metadata.yaml":
        path = path.parent
    if path.is_dir():
        meta = path / "metadata.yaml"
        if meta.exists() or meta.is_symlink():
            return _rosbag2(path, stack)
        bags = sorted(p for p in path.iterdir() if p.suffix == ".bag" and p.is_file())
        if bags:
            return _source(bags, stack) if len(bags) > 1 else _source(bags[0], stack)
        storage = sorted(
            p for p in path.iterdir() if p.is_file() and p.name.endswith(_STORAGE_NAMES)
        )
        if len(storage) == 1:
            return Source((path,), _source(storage[0], stack).read)
        raise InputError(
            path,
            "no bag in this folder (expected metadata.yaml, .bag files, or one .db3/.mcap file)",
        )
    kind = _sniff(path)
    if kind == "zstd":
        return Source((path,), (_decompress(path, stack),))
    if kind in {"ros1", *_STORAGE_SUFFIX}:
        return Source((path,), (_stage(path, kind, stack),))
    raise _not_a_bag(path, kind)
