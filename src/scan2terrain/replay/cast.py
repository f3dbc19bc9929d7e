"""Recorded beams cast into a world's collision geometry (Intel Embree, through embreex: the
binding trimesh uses; it releases the GIL, so the rays are cast in chunks on every core), and
the simulated ranges compared with the recorded ones.

Geometry and rays are moved by one reference point (the sensor's first position, rounded to
the metre) before they become float32, Embree's number type, so a world far from its origin
keeps its millimetres.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import Beams, Fidelity, Figures

#: A simulated range this much shorter or longer than the recorded one is phantom or missing
#: geometry (metres).
FAR = 0.2
#: The recording is scored in this many equal parts of its time (of its scans for a scan file).
PARTS = 10
#: Rays cast by one call (a thread's share at a time).
CHUNK = 1 << 18

Floats = NDArray[np.float64]


def simulated_ranges(
    vertices: Floats,
    triangles: NDArray[np.int32],
    beams: Beams,
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[Floats, NDArray[np.bool_]]:
    """Each beam's range in the world whose frame is the fixed frame less ``offset``: the
    distance from its scan's origin along its recorded direction to the first triangle it
    meets (+inf: none); and whether that triangle faced away from the sensor (the beam
    started inside a solid, every solid the tool writes being closed with its faces out)."""
    from embreex.mesh_construction import TriangleMesh
    from embreex.rtcore_scene import EmbreeScene

    n = len(beams.scan)
    if n == 0 or len(triangles) == 0:
        return np.full(n, np.inf), np.zeros(n, dtype=bool)
    ref = np.round(beams.origins[0]) - np.asarray(offset, dtype=np.float64)
    scene = EmbreeScene()
    TriangleMesh(
        scene,
        np.ascontiguousarray(vertices - ref, dtype=np.float32),
        np.ascontiguousarray(triangles, dtype=np.int32),
    )
    local = beams.origins - np.asarray(offset) - ref
    origins = np.ascontiguousarray(local[beams.scan], dtype=np.float32)
    vec = beams.vectors.astype(np.float64)
    recorded = np.sqrt(np.einsum("ij,ij->i", vec, vec))
    directions = np.ascontiguousarray(vec / recorded[:, None], dtype=np.float32)

    def cast(start: int) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        part = slice(start, start + CHUNK)
        hit = scene.run(origins[part], directions[part], output=1)
        found = hit["primID"] >= 0
        back = found & (np.einsum("ij,ij->i", hit["Ng"], directions[part]) > 0)
        return np.where(found, hit["tfar"], np.inf), back

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        parts = list(pool.map(cast, range(0, n, CHUNK)))
    ranges = np.concatenate([p[0] for p in parts]).astype(np.float64)
    return ranges, np.concatenate([p[1] for p in parts])


def recorded_ranges(beams: Beams) -> Floats:
    vec = beams.vectors.astype(np.float64)
    out: Floats = np.sqrt(np.einsum("ij,ij->i", vec, vec))
    return out


def figures(recorded: Floats, simulated: Floats, back: NDArray[np.bool_] | None = None) -> Figures:
    """The comparison of one set of beams (see :class:`~scan2terrain.types.Figures`);
    ``back``: the beams whose first hit faced away from the sensor."""
    n = len(recorded)
    if n == 0:
        return Figures(0, None, None, None, None, None, None, None, None, None)
    found = np.isfinite(simulated)
    signed = simulated[found] - recorded[found]
    err = np.abs(signed)

    def share(mask_count: int) -> float:
        return round(mask_count / n, 6)

    def metres(value: float) -> float:
        return round(float(value), 4) + 0.0

    some = len(err) > 0
    return Figures(
        beams=n,
        median=metres(np.median(err)) if some else None,
        p95=metres(np.percentile(err, 95)) if some else None,
        signed_median=metres(np.median(signed)) if some else None,
        within_5cm=share(int((err <= 0.05).sum())),
        within_10cm=share(int((err <= 0.10).sum())),
        nothing=share(int((~found).sum())),
        short=share(int((signed < -FAR).sum())),
        long=share(int((signed > FAR).sum())),
        inside=share(0 if back is None else int(back.sum())),
    )


def fidelity(
    vertices: Floats,
    triangles: NDArray[np.int32],
    beams: Beams,
    *,
    world: str,
    pose_source: str,
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Fidelity:
    """The replay of ``beams`` in one world's triangles (world = fixed frame - ``offset``):
    figures over all beams and per tenth of the recording."""
    simulated, back = simulated_ranges(vertices, triangles, beams, offset)
    recorded = recorded_ranges(beams)
    part = _parts(beams)
    tenths = tuple(
        figures(recorded[part == k], simulated[part == k], back[part == k]) for k in range(PARTS)
    )
    ends = beams.origins[beams.scan] + beams.vectors
    return Fidelity(
        world=world,
        pose_source=pose_source,
        returns=beams.returns,
        overall=figures(recorded, simulated, back),
        tenths=tenths,
        ends=ends,
        errors=np.abs(simulated - recorded),
        trajectory=beams.origins[:, :2].copy(),
    )


def _parts(beams: Beams) -> NDArray[np.intp]:
    """Each beam's tenth of the recording: by its scan's stamp, or by its scan's place when
    the stamps do not span a time (scan files)."""
    stamps = beams.stamps_ns
    count = len(stamps)
    if count and stamps.max() > stamps.min():
        t = (stamps - stamps.min()) / float(stamps.max() - stamps.min())
    else:
        t = np.arange(count) / max(count, 1)
    per_scan = np.minimum((t * PARTS).astype(np.intp), PARTS - 1)
    out: NDArray[np.intp] = per_scan[beams.scan]
    return out
