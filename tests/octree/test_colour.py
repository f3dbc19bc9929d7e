"""VoxelColours: the mean colour of the points of each voxel, keyed as the octree keys them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scan2terrain.octree.colour import GREY, VoxelColours
from scan2terrain.octree.keys import KEY_OFFSET
from scan2terrain.octree.tree import VoxelOctree

RES = 0.1
RED, BLUE = (255, 0, 0), (0, 0, 255)


def key(x: float, y: float, z: float) -> tuple[int, int, int]:
    """The key of a voxel centre (the float32 rule cannot move a centre)."""
    return tuple(int(np.floor(c / RES)) + KEY_OFFSET for c in (x, y, z))  # type: ignore[return-value]


def test_two_colours_in_two_voxels_a_mixed_one_and_an_uncoloured_key() -> None:
    red_pts = np.array([[0.01, 0.02, 0.03], [0.05, 0.05, 0.05], [0.09, 0.01, 0.0]])
    blue_pts = np.array([[1.05, 0.05, 0.05], [1.01, 0.02, 0.08]])
    # the mixed voxel: two red and one green point -> (170, 85, 0), rounded half up
    mixed_pts = np.array([[0.55, 0.55, 0.55]] * 3)
    mixed_rgb = np.array([RED, RED, (0, 255, 0)], dtype=np.uint8)
    points = np.concatenate([red_pts, blue_pts, mixed_pts])
    rgb = np.concatenate([np.tile(RED, (3, 1)), np.tile(BLUE, (2, 1)), mixed_rgb]).astype(np.uint8)
    colours = VoxelColours(RES)
    colours.add(points, rgb)
    assert len(colours) == 3 and colours.points == 8
    keys = np.array(
        [key(0.05, 0.05, 0.05), key(1.05, 0.05, 0.05), key(0.55, 0.55, 0.55), key(3, 3, 3)],
        dtype=np.uint16,
    )
    got = colours.mean(keys)
    assert got.dtype == np.uint8 and got.shape == (4, 3)
    assert got.tolist() == [list(RED), list(BLUE), [170, 85, 0], list(GREY)]


def test_rounding_is_half_up_in_integers() -> None:
    colours = VoxelColours(1.0)
    colours.add(np.array([[0.5, 0.5, 0.5]] * 2), np.array([[0, 1, 2], [1, 2, 2]], dtype=np.uint8))
    # means 0.5, 1.5, 2.0
    assert colours.mean(np.array([[KEY_OFFSET] * 3], dtype=np.uint16)).tolist() == [[1, 2, 2]]


def test_keys_are_the_octrees() -> None:
    """Points on and near cell edges (where float32 rounding moves them across) colour exactly
    the voxels the octree marks occupied from the same points."""
    rng = np.random.default_rng(5)
    edges = rng.integers(-50, 50, size=(2000, 3)) * RES
    points = edges + rng.choice([-1e-9, 0.0, 1e-9, 1e-6], size=(2000, 3))
    rgb = rng.integers(0, 256, size=(2000, 3), dtype=np.uint8)
    tree = VoxelOctree(RES)
    tree.insert_endpoints(points)
    keys, occupied = tree.occupied_and_free()
    keys = keys[occupied].astype(np.int64)
    tree_keys = tree.coord_to_key(points)
    # the float32 rule matters here: plain float64 division puts some points elsewhere
    assert (np.floor(points / RES).astype(np.int64) + KEY_OFFSET != tree_keys).any()
    colours = VoxelColours(RES)
    colours.add(points, rgb)
    assert len(colours) == len(keys)
    # the reference: each voxel's points grouped by the octree's own keys
    packed = (tree_keys[:, 0] << 32) | (tree_keys[:, 1] << 16) | tree_keys[:, 2]
    order = np.argsort(packed, kind="stable")
    uniq, starts, counts = np.unique(packed[order], return_index=True, return_counts=True)
    sums = np.add.reduceat(rgb[order].astype(np.int64), starts, axis=0)
    wanted = (keys[:, 0] << 32) | (keys[:, 1] << 16) | keys[:, 2]
    np.testing.assert_array_equal(np.sort(wanted), uniq)  # the same voxels
    at = np.searchsorted(uniq, wanted)
    expected = (2 * sums[at] + counts[at, None]) // (2 * counts[at, None])
    np.testing.assert_array_equal(colours.mean(keys.astype(np.uint16)), expected)


def test_chunks_and_order_do_not_change_the_result() -> None:
    rng = np.random.default_rng(7)
    points = rng.uniform(-2, 2, size=(5000, 3))
    rgb = rng.integers(0, 256, size=(5000, 3), dtype=np.uint8)
    whole = VoxelColours(RES)
    whole.add(points, rgb)
    chunked = VoxelColours(RES)
    order = rng.permutation(5000)
    for part in np.array_split(order, 37):  # many small runs: merged as they pile up
        chunked.add(points[part], rgb[part])
    keys = np.unique(np.floor(points / RES).astype(np.int64) + KEY_OFFSET, axis=0)
    keys = np.concatenate([keys, [[0, 0, 0], [65535, 65535, 65535]]]).astype(np.uint16)
    np.testing.assert_array_equal(whole.mean(keys), chunked.mean(keys))
    assert len(whole) == len(chunked) == len(keys) - 2 and chunked.points == 5000


def test_non_finite_and_out_of_range_points_are_not_counted() -> None:
    colours = VoxelColours(RES)
    points = np.array([[np.nan, 0, 0], [np.inf, 0, 0], [1e300, 0, 0], [3277.0, 0, 0], [0, 0, 0]])
    colours.add(points, np.full((5, 3), 9, dtype=np.uint8))
    assert colours.points == 1 and len(colours) == 1
    colours.add(points[:2], np.zeros((2, 3), dtype=np.uint8))  # nothing inside: no run
    assert colours.mean(np.array([[KEY_OFFSET] * 3], dtype=np.uint16)).tolist() == [[9, 9, 9]]


def test_empty_and_bad_arguments() -> None:
    colours = VoxelColours(RES)
    assert colours.mean(np.zeros((0, 3), dtype=np.uint16)).shape == (0, 3)
    assert colours.mean(np.array([[1, 2, 3]], dtype=np.uint16)).tolist() == [list(GREY)]
    colours.add(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="points must be"):
        colours.add(np.zeros(3), np.zeros(3, dtype=np.uint8))
    with pytest.raises(ValueError, match="rgb must be"):
        colours.add(np.zeros((2, 3)), np.zeros((1, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="rgb must be uint8"):
        colours.add(np.zeros((2, 3)), np.zeros((2, 3)))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="keys must be"):
        colours.mean(np.zeros(3, dtype=np.uint16))
    with pytest.raises(ValueError, match="resolution"):
        VoxelColours(0.0)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 3), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255)),
        min_size=1,
        max_size=40,
    )
)
def test_a_mean_lies_within_its_points_colours(rows: list[tuple[int, int, int, int]]) -> None:
    """Invariant: each channel's mean is between the smallest and largest value of the voxel's
    points (never a colour outside what was seen)."""
    cells = np.array([r[0] for r in rows])
    rgb = np.array([r[1:] for r in rows], dtype=np.uint8)
    points = np.stack([cells + 0.5, np.full(len(rows), 0.5), np.full(len(rows), 0.5)], axis=1)
    colours = VoxelColours(1.0)
    colours.add(points, rgb)
    for c in np.unique(cells):
        got = colours.mean(np.array([[c + KEY_OFFSET, KEY_OFFSET, KEY_OFFSET]], dtype=np.uint16))
        sel = rgb[cells == c]
        assert (got[0] >= sel.min(axis=0)).all() and (got[0] <= sel.max(axis=0)).all()
