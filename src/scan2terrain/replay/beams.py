"""The recorded beams of posed scans, kept for the replay: every beam with a return (a hit
within the scan's range), or a deterministic sample of them past :data:`BEAM_BUDGET`.

The sample is a hash of each return's identity: its scan's stamp and topic, and its place in
the scan. A return is kept while its 64-bit hash has its top ``level`` bits zero, and
``level`` rises by one (halving what is kept) whenever more than the budget are held, so the
kept set is the one of the lowest level that fits the budget. Recorders of parts of a recording
(streamed pieces, read in any order) merge into the same set, and :meth:`BeamRecorder.beams`
orders scans by stamp and topic: the same beams, in the same order, whichever path read them.
"""

from __future__ import annotations

import zlib

import numpy as np
from numpy.typing import NDArray

from scan2terrain.readers.points import hits_of
from scan2terrain.types import Beams, Scan

#: Beams replayed at most (about 28 MB held; a share's sampling error is then below 0.1%).
BEAM_BUDGET = 1_000_000

_U64 = np.uint64


def beam_hash(index: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """SplitMix64's finaliser of each value: a fixed, well-mixed 64-bit hash."""
    with np.errstate(over="ignore"):
        z = index + _U64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> _U64(27))) * _U64(0x94D049BB133111EB)
        out: NDArray[np.uint64] = z ^ (z >> _U64(31))
    return out


class BeamRecorder:
    """Collects the beams of posed scans as they stream past (:meth:`add`), and the sensor
    pose of every scan (the trajectory actually used), into :class:`~scan2terrain.types.Beams`."""

    def __init__(self, budget: int = BEAM_BUDGET, *, beams: bool = True) -> None:
        self.budget = budget
        #: False: the scans' poses only (no replay to make: the trajectory alone)
        self.keeps_beams = beams
        self.level = 0
        self.returns = 0  #: beams with a return seen so far
        #: kept beams, per scan with any: (scan's place, vectors, place in the scan, hashes)
        self._parts: list[
            tuple[int, NDArray[np.float32], NDArray[np.uint32], NDArray[np.uint64]]
        ] = []
        self._held = 0
        self._origins: list[NDArray[np.float64]] = []
        self._rotations: list[NDArray[np.float64]] = []
        self._stamps: list[int] = []
        self._topics: list[str] = []

    @property
    def scans(self) -> int:
        return len(self._stamps)

    def add(self, scan: Scan, hits: NDArray[np.float64] | None = None) -> None:
        """One posed scan (``hits``: its returns, when the caller has them already)."""
        index = len(self._stamps)
        rotation = np.eye(3) if scan.rotation is None else np.asarray(scan.rotation)
        self._origins.append(np.asarray(scan.origin, dtype=np.float64))
        self._rotations.append(rotation)
        self._stamps.append(scan.stamp_ns)
        self._topics.append(scan.topic)
        if not self.keeps_beams:
            return
        if hits is None:
            hits = hits_of(scan)
        n = len(hits)
        if n == 0:
            return
        self.returns += n
        key = (scan.stamp_ns ^ (zlib.crc32(scan.topic.encode()) << 32)) & 0xFFFFFFFFFFFFFFFF
        base = beam_hash(np.array([key], dtype=np.uint64))[0]
        with np.errstate(over="ignore"):
            h = beam_hash(base + np.arange(n, dtype=np.uint64))
        if self.level == 0:  # every return kept: no copies by index
            place = np.arange(n, dtype=np.uint32)
            rows = hits
        else:
            place = np.flatnonzero(self._kept(h)).astype(np.uint32)
            if len(place) == 0:
                return
            rows, h = hits[place], h[place]
        vectors = (rows - scan.origin).astype(np.float32)  # less the origin in float64 first
        if not vectors.any(axis=1).all():  # a return at the sensor itself has no direction
            good = vectors.any(axis=1)
            vectors, place, h = vectors[good], place[good], h[good]
        self._parts.append((index, vectors, place, h))
        self._held += len(place)
        self._fit()

    def merge(self, other: BeamRecorder) -> None:
        """Add another recorder's scans (another part of the same recording) after ours."""
        offset = len(self._stamps)
        self._origins += other._origins
        self._rotations += other._rotations
        self._stamps += other._stamps
        self._topics += other._topics
        self.returns += other.returns
        self.level = max(self.level, other.level)
        self._parts += [(i + offset, v, p, h) for i, v, p, h in other._parts]
        self._parts = self._filtered(self._parts)
        self._held = sum(len(p[2]) for p in self._parts)
        self._fit()

    def _fit(self) -> None:
        while self._held > self.budget:
            self.level += 1
            self._parts = self._filtered(self._parts)
            self._held = sum(len(p[2]) for p in self._parts)

    def _filtered(
        self,
        parts: list[tuple[int, NDArray[np.float32], NDArray[np.uint32], NDArray[np.uint64]]],
    ) -> list[tuple[int, NDArray[np.float32], NDArray[np.uint32], NDArray[np.uint64]]]:
        out = []
        for i, v, p, h in parts:
            k = self._kept(h)
            if k.all():
                out.append((i, v, p, h))
            elif k.any():
                out.append((i, v[k], p[k], h[k]))
        return out

    def _kept(self, h: NDArray[np.uint64]) -> NDArray[np.bool_]:
        if self.level == 0:
            return np.ones(len(h), dtype=bool)
        out: NDArray[np.bool_] = (h >> _U64(64 - self.level)) == 0
        return out

    def beams(self) -> Beams:
        """What was recorded: every scan's pose in the order of stamps (then topics), and the
        kept beams, by scan and place in it."""
        count = len(self._stamps)
        stamps = np.array(self._stamps, dtype=np.int64)
        topic = np.unique(np.array(self._topics, dtype=str), return_inverse=True)[1]
        order = np.lexsort((topic.reshape(-1), stamps)) if count else np.zeros(0, np.intp)
        rank = np.empty(count, dtype=np.int32)
        rank[order] = np.arange(count, dtype=np.int32)
        parts = sorted(self._parts, key=lambda p: int(rank[p[0]]))
        if parts:
            vectors = np.concatenate([p[1] for p in parts])
            scan = np.concatenate([np.full(len(p[2]), rank[p[0]], np.int32) for p in parts])
        else:
            vectors, scan = np.zeros((0, 3), np.float32), np.zeros(0, np.int32)
        return Beams(
            origins=np.array(self._origins, dtype=np.float64).reshape(count, 3)[order],
            rotations=np.array(self._rotations, dtype=np.float64).reshape(count, 3, 3)[order],
            stamps_ns=stamps[order],
            scan=scan,
            vectors=vectors,
            returns=self.returns,
        )
