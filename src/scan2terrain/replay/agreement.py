"""How well a recording's beams agree with a map of its own hits, for one set of poses: the
measure the pose correction is judged by (``--correct auto`` keeps corrected poses only when
they agree better than the recorded ones).

The recording is cut into :data:`PARTS` spans of time. Beams of each span are marched through a
2D grid of the hits of the *other* spans (a beam always agrees with its own end point, so it is
left out), and a beam agrees when the first occupied cell it meets lies within
:data:`WITHIN` of its recorded range. Wrong poses place a revisited wall twice: beams stop on
the wrong copy, short or long. Beams that meet nothing of the other spans (places seen once)
are not counted. It is the fidelity replay's question asked of the recording alone, in the
plane, before any world is built.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

PARTS = 5
WITHIN = 0.1  #: metres
#: Beams marched at most (a fixed sample: every n-th beam of every scan).
SAMPLE = 200_000


def agreement(
    poses: NDArray[np.float64], scans: list[NDArray[np.float64]], resolution: float
) -> tuple[float, int]:
    """(share of the counted beams within WITHIN, beams counted) for scans (points (N, 2) in
    each scan's own frame) at ``poses`` (K, 3: x, y, yaw)."""
    from scan2terrain.replay._march_kernels import first_hits

    k = len(poses)
    sizes = np.array([len(s) for s in scans])
    if k < PARTS or sizes.sum() == 0:
        return 0.0, 0
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    owner = np.repeat(np.arange(k), sizes)
    local = np.concatenate(scans)
    ends = np.stack(
        [
            c[owner] * local[:, 0] - s[owner] * local[:, 1] + poses[owner, 0],
            s[owner] * local[:, 0] + c[owner] * local[:, 1] + poses[owner, 1],
        ],
        axis=1,
    )
    part = (owner * PARTS) // k
    lo = np.minimum(ends.min(axis=0), poses[:, :2].min(axis=0)) - 1.0
    hi = np.maximum(ends.max(axis=0), poses[:, :2].max(axis=0)) + 1.0
    shape = np.ceil((hi - lo) / resolution).astype(np.int64) + 1
    cells = np.floor((ends - lo) / resolution).astype(np.int64)
    every = max(1, len(ends) // SAMPLE)
    pick = np.arange(0, len(ends), every)
    agree = counted = 0
    for p in range(PARTS):
        others = part != p
        grid = np.zeros((int(shape[1]), int(shape[0])), bool)
        grid[cells[others, 1], cells[others, 0]] = True
        mine = pick[part[pick] == p]
        if len(mine) == 0:
            continue
        o = (poses[owner[mine], :2] - lo) / resolution
        v = (ends[mine] - poses[owner[mine], :2]) / resolution
        rng = np.hypot(v[:, 0], v[:, 1])
        ok = rng > 0
        o, v, rng = o[ok], v[ok], rng[ok]
        margin = 1.0 / resolution
        hit = first_hits(grid, o[:, 0], o[:, 1], v[:, 0] / rng, v[:, 1] / rng, rng + margin, 0.5)
        met = hit >= 0
        counted += int(met.sum())
        agree += int(np.sum(np.abs(hit[met] - rng[met]) * resolution <= WITHIN))
    return (agree / counted if counted else 0.0), counted
