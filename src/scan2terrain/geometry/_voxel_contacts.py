"""Where voxels touch only along an edge or at a corner: the sheets of surface around a lattice
vertex (one vertex copy each) and the diagonal edges (one midpoint per voxel), so the voxel
mesh stays 2-manifold (for :mod:`scan2terrain.geometry.voxel_mesh`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry._voxel_lattice import _Lattice


@dataclass
class Diagonals:
    """Unit lattice segments where two occupied voxels touch only along that edge (the other two
    voxels around it empty): each gets one midpoint per voxel, so the two solids' faces use
    different edges there. Coordinates doubled (the midpoint is odd along its line)."""

    line: NDArray[np.int64]  #: (D, 4) axis, a, b (doubled), quadrant of the voxel
    along: NDArray[np.int64]  #: doubled coordinate of the midpoint along the line (odd)
    xyz: NDArray[np.float64]  #: (D, 3) position, lattice units, hair move included


def _diagonals(grid: _Lattice, hair: float) -> Diagonals:
    lines, along, xyz = [], [], []
    vox = grid.vox
    for t in range(3):
        a, b = [x for x in range(3) if x != t]
        for sb in (1, -1):
            ea = np.zeros(3, np.int64)
            eb = np.zeros(3, np.int64)
            ea[a], eb[b] = 1, sb
            hit = grid.occupied(vox + ea + eb) & ~grid.occupied(vox + ea) & ~grid.occupied(vox + eb)
            va = vox[hit]
            line_a = va[:, a] + 1
            line_b = va[:, b] + (1 if sb > 0 else 0)
            for voxel in (va, va + ea + eb):  # the two voxels touching along the segment
                qa = voxel[:, a] - (line_a - 1)
                qb = voxel[:, b] - (line_b - 1)
                lines.append(
                    np.column_stack([np.full(len(va), t), 2 * line_a, 2 * line_b, qa + 2 * qb])
                )
                along.append(2 * va[:, t] + 1)
                toward = np.zeros((len(va), 3))
                toward[:, a] = voxel[:, a] + 0.5 - line_a
                toward[:, b] = voxel[:, b] + 0.5 - line_b
                point = np.zeros((len(va), 3))
                point[:, t] = va[:, t] + 0.5
                point[:, a] = line_a
                point[:, b] = line_b
                xyz.append(point + toward / np.sqrt(0.5) * hair)
    if not lines:  # pragma: no cover - the loops always run
        return Diagonals(np.zeros((0, 4), np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    return Diagonals(np.concatenate(lines), np.concatenate(along), np.concatenate(xyz))


@lru_cache(maxsize=1)
def sheet_tables() -> tuple[NDArray[np.int8], NDArray[np.int8], NDArray[np.float64]]:
    """For each of the 256 occupancy patterns of the 8 voxels around a lattice vertex (bit
    ``x + 2y + 4z`` of voxel ``(x, y, z)``, 0 or 1 per axis, the vertex at their shared corner):
    the sheet of each surface face, indexed [pattern, occupied voxel, empty voxel]; the number of
    sheets; and each sheet's unit direction (toward its occupied voxels, away from its empty
    ones) for the hair move."""
    sheet = np.full((256, 8, 8), -1, np.int8)
    count = np.zeros(256, np.int8)
    direction = np.zeros((256, 4, 3))
    centre = np.array([[(i >> b & 1) - 0.5 for b in range(3)] for i in range(8)])
    pairs = [(a, a ^ (1 << bit)) for a in range(8) for bit in range(3) if not a & (1 << bit)]
    for pattern in range(256):
        occ = [bool(pattern >> i & 1) for i in range(8)]
        faces = [(a, b) if occ[a] else (b, a) for a, b in pairs if occ[a] != occ[b]]
        parent = list(range(len(faces)))

        find = _Finder(parent)

        # Around each half-edge from the vertex (axis t, side s) are the voxels with bit t = s.
        for t in range(3):
            for s in (0, 1):
                around = [i for i, f in enumerate(faces) if _on_half_edge(f, t, s)]
                if len(around) == 2:
                    parent[find(around[0])] = find(around[1])
                elif len(around) == 4:
                    by_voxel: dict[int, list[int]] = {}
                    for i in around:
                        by_voxel.setdefault(faces[i][0], []).append(i)
                    for group in by_voxel.values():
                        parent[find(group[0])] = find(group[1])
        roots = sorted({find(i) for i in range(len(faces))})
        assert len(roots) <= 4, pattern  # at most 4 (a checkerboard of the 8 voxels)
        count[pattern] = len(roots)
        for i, (o, e) in enumerate(faces):
            sheet[pattern, o, e] = roots.index(find(i))
        for si, root in enumerate(roots):
            members = [faces[i] for i in range(len(faces)) if find(i) == root]
            solid = centre[[o for o, _ in members]].mean(0)
            toward = solid - centre[[e for _, e in members]].mean(0)
            norm = np.linalg.norm(toward)
            direction[pattern, si] = toward / norm if norm > 0 else 0.0
    return sheet, count, direction


class _Finder:
    """Union-find's find over ``parent`` (path halving)."""

    def __init__(self, parent: list[int]) -> None:
        self.parent = parent

    def __call__(self, i: int) -> int:
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i


def _on_half_edge(face: tuple[int, int], t: int, s: int) -> bool:
    """Whether the face between voxels ``face`` touches the half-edge along axis ``t`` on side
    ``s``: both voxels have bit t = s (the face is then parallel to that axis)."""
    a, b = face
    return bool((a >> t & 1) == s and (b >> t & 1) == s)
