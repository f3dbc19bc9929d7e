"""A trajectory as a TUM file: one pose a line, ``t x y z qx qy qz qw``, what ``--trajectory``
(:func:`scan2terrain.readers.tracks.read_tum`) reads back exactly."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters._numbers import float_texts

#: Poses formatted at a time (bounds the temporary Python strings).
_BLOCK = 65536
_NS = 1_000_000_000


def tum_bytes(
    times_ns: NDArray[np.int64],
    translations: NDArray[np.float64],
    quaternions_xyzw: NDArray[np.float64],
    *,
    comment: str = "",
) -> bytes:
    """TUM lines for poses (K,), (K, 3), (K, 4), after a ``# comment`` line when given.

    Times are written as decimal seconds with all nine digits of the nanoseconds (read back to
    the nanosecond, not through a float); positions and quaternions as the shortest text that
    reads back to the same float64.
    """
    t = np.asarray(times_ns, dtype=np.int64).reshape(-1)
    values = np.hstack([np.asarray(translations), np.asarray(quaternions_xyzw)])
    if values.shape != (t.size, 7):
        raise ValueError(f"{t.size} times need (K, 3) translations and (K, 4) quaternions")
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    line = "%s%d.%09d %s %s %s %s %s %s %s\n"
    blocks = [head.encode("utf-8")]
    for start in range(0, t.size, _BLOCK):
        part = t[start : start + _BLOCK]
        seconds, nanos = np.divmod(np.abs(part), _NS)
        rows = np.empty((part.size, 10), dtype=object)
        rows[:, 0] = np.where(part < 0, "-", "")
        rows[:, 1] = seconds.tolist()
        rows[:, 2] = nanos.tolist()
        texts = float_texts(values[start : start + _BLOCK])
        rows[:, 3:] = np.array(texts, dtype=object).reshape(-1, 7)
        blocks.append(((line * part.size) % tuple(rows.ravel().tolist())).encode("ascii"))
    return b"".join(blocks)
