"""Uncompressed LAS read without laspy: the header from its bytes, the point records straight
from the file into numpy, ``step`` records at a time (then scaled by ``_las_kernels.py``).

For a local file whose header is regular (:func:`plain_header`): LAS 1.0-1.4, an uncompressed
point format 0-10, a record at least that format's size, VLRs that end where the points begin,
no extra-bytes description and no EVLRs. Anything else (and every LAZ) is read by laspy, which
reads or refuses it as before. The same numbers as laspy's: laspy reads these fields at these
offsets (laspy/header.py), X, Y, Z are the int32 at bytes 0, 4 and 8 of every point format and
the classification is bits 0-4 of byte 15 (formats 0-5) or byte 16 (6-10).

Records are read with ``readinto`` into one buffer per chunk, not memory-mapped: a file cut
short while mapped would end the process with SIGBUS, where a short read is an InputError.
``check_las_layout`` has checked the header's counts against the file's size before this runs.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from io import BufferedIOBase
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

#: laspy's header sizes by minor version (what it reads before the VLRs; fewer is refused).
_HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
#: Bytes of a point record of each point format (LAS 1.4 R15, Table 7 and on).
FORMAT_SIZE = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
_VLR_HEADER = 54
_EXTRA_BYTES = (b"LASF_Spec", 4)


@dataclass(frozen=True)
class PlainLas:
    """What reading an uncompressed LAS file's points needs, from its header."""

    version: str
    point_format: int
    start: int  #: byte of the first point record
    record: int  #: bytes of a record
    count: int  #: point records (LAS 1.4: the 64-bit count, as laspy takes it)
    scales: NDArray[np.float64]
    offsets: NDArray[np.float64]
    mins: tuple[float, float, float]
    maxs: tuple[float, float, float]

    def records_dtype(self) -> np.dtype[np.void]:
        """X, Y, Z (int32) and the classification byte of a record, at their offsets."""
        return np.dtype(
            {
                "names": ["X", "Y", "Z", "class"],
                "formats": ["<i4", "<i4", "<i4", "u1"],
                "offsets": [0, 4, 8, 15 if self.point_format <= 5 else 16],
                "itemsize": self.record,
            }
        )

    def classes(self, records: NDArray[np.void]) -> NDArray[np.uint8]:
        """The classification code of every record, as laspy's ``classification``."""
        raw: NDArray[np.uint8] = records["class"]
        codes: NDArray[np.uint8] = raw & np.uint8(0x1F) if self.point_format <= 5 else raw.copy()
        return codes


def plain_header(f: BinaryIO) -> PlainLas | None:
    """The header of an uncompressed LAS file whose header is regular (module doc), or None (read
    it with laspy)."""
    f.seek(0)
    head = f.read(375)
    if len(head) < 227 or not head.startswith(b"LASF"):
        return None
    major, minor = head[24], head[25]
    header_size, start, n_vlrs, fmt_id, record, count = struct.unpack_from("<HIIBHI", head, 94)
    if major != 1 or minor not in _HEADER_SIZE or header_size < _HEADER_SIZE[minor]:
        return None
    if fmt_id & 0xC0 or fmt_id not in FORMAT_SIZE or record < FORMAT_SIZE[fmt_id]:
        return None  # compressed, unknown, or records too short for their format
    if minor >= 4:
        n_evlrs, count = struct.unpack_from("<IQ", head, 243)
        if n_evlrs:
            return None
    pos = header_size
    for _ in range(n_vlrs):  # a loop over the header's few VLRs (their count is checked)
        f.seek(pos)
        raw = f.read(_VLR_HEADER)
        if len(raw) < _VLR_HEADER or pos + _VLR_HEADER > start:
            return None
        user, record_id, length = struct.unpack_from("<16sHH", raw, 2)
        if (user.split(b"\0")[0], record_id) == _EXTRA_BYTES:
            return None
        pos += _VLR_HEADER + length
    if pos > start:
        return None
    bounds = struct.unpack_from("<6d", head, 179)  # max X, min X, max Y, min Y, max Z, min Z
    return PlainLas(
        version=f"{major}.{minor}",
        point_format=fmt_id,
        start=start,
        record=record,
        count=count,
        scales=np.array(struct.unpack_from("<3d", head, 131)),
        offsets=np.array(struct.unpack_from("<3d", head, 155)),
        mins=(bounds[1], bounds[3], bounds[5]),
        maxs=(bounds[0], bounds[2], bounds[4]),
    )


def read_records(
    f: BufferedIOBase, las: PlainLas, where: Path | str, first: int, stop: int, step: int
) -> Iterator[NDArray[np.void]]:
    """Records ``[first, stop)`` of the file, ``step`` at a time (a new array each: the caller
    may keep one while the next is read). InputError if the file ends before them."""
    dtype = las.records_dtype()
    f.seek(las.start + first * las.record)
    at = first
    while at < stop:
        m = min(step, stop - at)
        buf = np.empty(m * las.record, dtype=np.uint8)
        got = f.readinto(buf.data)
        if got != buf.nbytes:
            raise InputError(
                where,
                f"truncated LAS file: expected points {first}..{stop}, it ends within point "
                f"{at + (got or 0) // las.record}",
            )
        yield buf.view(dtype)
        at += m
