"""faces_at_hits: each wall face toward observed free space half a cell into the wall, where
the wall stays a cell thick."""

from __future__ import annotations

import numpy as np

from scan2terrain.geometry.faces import faces_at_hits

# Rows of a grid: W wall, . free, ? unknown.


def grid(*rows: str) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([list(r) for r in rows])
    return a == "W", a == "."


def test_a_wall_seen_from_one_side_keeps_its_back_half() -> None:
    walls, free = grid("..W?")
    fine = faces_at_hits(walls, free)
    assert fine.shape == (2, 8)
    assert fine[0].tolist() == [False] * 5 + [True] + [False] * 2  # the half toward '?' stays
    assert (fine[0] == fine[1]).all()


def test_a_thin_wall_seen_from_both_sides_and_a_post_stay_whole() -> None:
    walls, free = grid("..W..")
    assert faces_at_hits(walls, free)[0].tolist() == [False] * 4 + [True, True] + [False] * 4
    walls, free = grid("...", ".W.", "...")
    assert faces_at_hits(walls, free).sum() == 4


def test_a_thick_wall_loses_half_a_cell_on_each_observed_side() -> None:
    walls, free = grid(".WWW.")
    row = faces_at_hits(walls, free)[0].tolist()
    assert row == [False] * 3 + [True] * 4 + [False] * 3


def test_a_room_corner_moves_both_faces() -> None:
    walls, free = grid("WWWW", "W...", "W...")
    fine = faces_at_hits(walls, free)
    # Row 0 (the lowest y) is the wall along x: its half toward row 1 (free) goes, but only
    # above free cells; column 0 likewise.
    assert fine[0, :].all() and not fine[1, 2:].any()
    assert fine[:, 0].all() and not fine[2:, 1].any()
    assert fine[1, 1]  # the corner's inner quarter has no free cell beside it, only diagonally


def test_grids_made_of_maps_are_not_changed_where_nothing_is_free() -> None:
    walls, free = grid("WW??", "WW??")
    fine = faces_at_hits(walls, free)
    assert fine.sum() == 4 * walls.sum()
