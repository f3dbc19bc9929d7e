"""The replay stage: recorded beams cast into known triangles give the analytic ranges, a
world moved or turned scores worse, and the sample of beams is one fixed set however the
recording was read."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.replay.beams import BeamRecorder
from scan2terrain.replay.cast import fidelity, figures, simulated_ranges
from scan2terrain.types import Scan

#: The room's inside: x in [-3, 3], y in [-2, 2], z in [0, 2.5] (walls are the box's faces).
LO = np.array([-3.0, -2.0, 0.0])
HI = np.array([3.0, 2.0, 2.5])


def box_mesh(
    lo: NDArray[np.float64], hi: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """A box's 8 corners and 12 triangles."""
    corners = np.array(
        [[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])]
    )
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return corners, np.array(tris, dtype=np.int32)


def room_range(origin: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Analytic distance from inside the box to its faces along unit directions ``d``."""
    with np.errstate(divide="ignore"):
        t_hi = np.where(d > 0, (HI - origin) / d, np.inf)
        t_lo = np.where(d < 0, (LO - origin) / d, np.inf)
    out: NDArray[np.float64] = np.minimum(t_hi, t_lo).min(axis=1)
    return out


def recorded_scans(
    n: int = 40, beams: int = 720, seed: int = 3, *, flat: bool = False
) -> list[Scan]:
    """Scans from poses inside the room, beams in every direction (``flat``: within 10 degrees
    of the horizontal, at the walls), ranges analytic."""
    rng = np.random.default_rng(seed)
    scans = []
    for i in range(n):
        origin = np.array([rng.uniform(-2.5, 2.5), rng.uniform(-1.5, 1.5), rng.uniform(0.2, 2.0)])
        d = rng.normal(size=(beams, 3))
        if flat:
            d[:, 2] = np.hypot(d[:, 0], d[:, 1]) * np.tan(np.radians(rng.uniform(-10, 10, beams)))
        d /= np.linalg.norm(d, axis=1)[:, None]
        pts = origin + d * room_range(origin, d)[:, None]
        stamp = 1_000_000_000 + i * 100_000_000
        scans.append(Scan(pts, origin, -1.0, stamp, "/points", 0.0, np.eye(3)))
    return scans


def record(scans: list[Scan], budget: int = 1_000_000) -> BeamRecorder:
    rec = BeamRecorder(budget)
    for s in scans:
        rec.add(s)
    return rec


def test_box_room_replays_to_the_tenth_of_a_millimetre() -> None:
    v, t = box_mesh(LO, HI)
    beams = record(recorded_scans()).beams()
    sim, back = simulated_ranges(v, t, beams)
    assert not back.any()
    rec = np.linalg.norm(beams.vectors.astype(np.float64), axis=1)
    assert np.abs(sim - rec).max() < 1e-3
    f = fidelity(v, t, beams, world="room", pose_source="given")
    assert f.overall.beams == len(beams.scan) == 40 * 720
    assert f.overall.within_5cm == 1.0 and f.overall.nothing == 0.0
    assert f.overall.median is not None and f.overall.median < 1e-4
    assert [x.beams for x in f.tenths] == [4 * 720] * 10


def test_far_from_the_origin_keeps_the_millimetres() -> None:
    """A world 300 km from its origin (UTM-like): float32 alone would be off by 3 cm."""
    shift = np.array([512_345.0, 4_201_234.0, 120.0])
    v, t = box_mesh(LO + shift, HI + shift)
    scans = [
        dataclasses.replace(s, points=s.points + shift, origin=s.origin + shift)
        for s in recorded_scans(5)
    ]
    beams = record(scans).beams()
    sim, back = simulated_ranges(v, t, beams)
    assert not back.any()
    rec = np.linalg.norm(beams.vectors.astype(np.float64), axis=1)
    assert np.abs(sim - rec).max() < 1e-3


def turned(v: NDArray[np.float64], degrees: float) -> NDArray[np.float64]:
    a = math.radians(degrees)
    r = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    out: NDArray[np.float64] = v @ r.T
    return out


@pytest.mark.parametrize("how", ["shifted 0.2 m", "turned 2 degrees"])
def test_a_moved_world_scores_clearly_worse(how: str) -> None:
    v, t = box_mesh(LO, HI)
    beams = record(recorded_scans(flat=True)).beams()
    exact = fidelity(v, t, beams, world="room", pose_source="given").overall
    v = v + np.array([0.2, 0.0, 0.0]) if how.startswith("shifted") else turned(v, 2.0)
    moved = fidelity(v, t, beams, world="room", pose_source="given").overall
    assert exact.within_5cm == 1.0 and exact.p95 is not None and exact.p95 < 1e-3
    assert moved.within_5cm is not None and moved.within_5cm < 0.85
    assert moved.p95 is not None and moved.p95 > 0.05


def test_missing_geometry_and_phantoms_are_counted() -> None:
    rec = np.array([1.0, 2.0, 3.0, 4.0])
    sim = np.array([1.01, np.inf, 2.5, 4.5])  # within, nothing, 0.5 short, 0.5 long
    f = figures(rec, sim)
    assert (f.within_5cm, f.nothing, f.short, f.long) == (0.25, 0.25, 0.25, 0.25)
    assert f.median == 0.5 and f.signed_median == 0.01  # of 0.01, -0.5, +0.5
    assert f.inside == 0.0
    inside = figures(np.array([2.0, 3.0]), np.array([0.5, 3.0]), np.array([True, False]))
    assert inside.inside == 0.5 and inside.short == 0.5


def test_sample_is_fixed_and_the_same_from_parts() -> None:
    """Past the budget the same beams are kept whether the recording was read whole or in
    parts merged in any order."""
    scans = recorded_scans(60, 500)
    whole = record(scans, budget=4000)
    assert whole.level > 0 and 2000 < len(whole.beams().scan) <= 4000
    parts = [record(scans[i::3][::-1], budget=4000) for i in range(3)]  # any split, any order
    merged = parts[2]
    merged.merge(parts[0])
    merged.merge(parts[1])
    a, b = whole.beams(), merged.beams()
    for name in ("origins", "rotations", "stamps_ns", "scan", "vectors"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.returns == b.returns == 60 * 500
    again = record(scans, budget=4000).beams()
    assert np.array_equal(again.vectors, a.vectors)


def test_a_sensor_inside_a_solid_is_seen() -> None:
    """The room's faces face into it (a cavity); turned out, the room is a solid box the
    sensor sits in, and every first hit is the back of a face."""
    v, t = box_mesh(LO, HI)
    beams = record(recorded_scans(4)).beams()
    assert fidelity(v, t, beams, world="room", pose_source="given").overall.inside == 0.0
    solid = fidelity(v, t[:, ::-1], beams, world="room", pose_source="given").overall
    assert solid.inside == 1.0
