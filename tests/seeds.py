"""Small good inputs that the fuzz (tests/test_mutations.py) and the hostile-input tests
(tests/readers/) damage: random points, a PLY with a list property, a .bt octree, the synthetic
room's recording, and a TIFF's tag table."""

from __future__ import annotations

import struct
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np


def points(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform((-4, -3, 0), (4, 3, 2), size=(n, 3))


def ply_list(fmt: str) -> Callable[[], bytes]:
    """A PLY whose vertex rows vary in length (a list property): the Open3D (RPly) path."""

    def data() -> bytes:
        pts = points(150)
        head = (
            f"ply\nformat {fmt} 1.0\nelement vertex {len(pts)}\nproperty float x\n"
            "property float y\nproperty float z\nproperty list uchar float extra\nend_header\n"
        )
        if fmt == "ascii":
            rows = "".join(
                f"{x:.4f} {y:.4f} {z:.4f} {k % 3}{' 1.5' * (k % 3)}\n"
                for k, (x, y, z) in enumerate(pts)
            )
            return (head + rows).encode()
        body = bytearray()
        for k, p in enumerate(pts):  # a loop over a test file's 150 points
            body += struct.pack("<3fB", *p, k % 3) + struct.pack(f"<{k % 3}f", *[1.5] * (k % 3))
        return head.encode() + bytes(body)

    return data


def tiff_entries(data: bytes) -> dict[int, int]:
    """Tag code -> offset of its 12-byte entry in a little-endian TIFF's first IFD."""
    assert data[:4] == b"II*\x00"
    ifd = struct.unpack_from("<I", data, 4)[0]
    n = struct.unpack_from("<H", data, ifd)[0]
    return {struct.unpack_from("<H", data, ifd + 2 + 12 * i)[0]: ifd + 2 + 12 * i for i in range(n)}


def bt_file(folder: Path) -> tuple[Path, Path]:
    from scan2terrain.octree.bt import bt_bytes

    rng = np.random.default_rng(3)
    keys = np.unique(rng.integers(32768 - 20, 32768 + 20, size=(600, 3)), axis=0)
    occupied = rng.random(len(keys)) < 0.4
    path = folder / "tree.bt"
    path.write_bytes(bt_bytes(resolution=0.1, keys=keys.astype(np.uint16), occupied=occupied))
    return path, path


@cache
def room(variant: str) -> Any:
    from tests.bagmaker import synthetic_room

    return synthetic_room(variant, n_scans=6, beams=90, rings=4, azimuths=60)  # type: ignore[arg-type]
