"""remove_small_components: 6/18/26-connected components of sparse voxel keys, against
hand-made cases and scipy.ndimage.label on small dense grids."""

from __future__ import annotations

import itertools
from typing import Any
from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays
from scipy import ndimage

from scan2terrain.filters import voxels3d
from scan2terrain.filters.voxels3d import remove_small_components

STRUCTURES = {c: ndimage.generate_binary_structure(3, r) for c, r in ((6, 1), (18, 2), (26, 3))}
#: How many coordinates two voxels may differ in and still touch: face 1, edge 2, corner 3.
REACH = {6: 1, 18: 2, 26: 3}
OFFSETS = [o for o in itertools.product((-1, 0, 1), repeat=3) if o != (0, 0, 0)]
I64 = np.iinfo(np.int64)


def reference(dense: np.ndarray, min_voxels: int, connectivity: int) -> np.ndarray:
    """The keep mask of np.argwhere(dense)'s voxels, by scipy.ndimage.label."""
    labels, _ = ndimage.label(dense, structure=STRUCTURES[connectivity])
    sizes = np.bincount(labels.ravel())
    return np.asarray(sizes[labels[dense]] >= min_voxels) | (min_voxels <= 1)


@pytest.mark.parametrize("connectivity", [6, 18, 26])
@pytest.mark.parametrize("offset", OFFSETS)
def test_two_voxels_touch_by_a_face_an_edge_or_a_corner(
    offset: tuple[int, int, int], connectivity: int
) -> None:
    keys = np.array([[5, -3, 7], np.add([5, -3, 7], offset)], dtype=np.int64)
    touching = sum(map(abs, offset)) <= REACH[connectivity]
    assert remove_small_components(keys, 2, connectivity=connectivity).tolist() == [touching] * 2


@pytest.mark.parametrize("connectivity", [6, 18, 26])
def test_voxels_two_apart_do_not_touch(connectivity: int) -> None:
    for offset in itertools.product((-2, 0, 2), repeat=3):
        if offset != (0, 0, 0):
            keys = np.array([[0, 0, 0], offset])
            assert not remove_small_components(keys, 2, connectivity=connectivity).any()


def test_chains_through_edges_and_corners() -> None:
    corners = np.arange(6)[:, None] * np.array([1, 1, 1])  # (0,0,0), (1,1,1), ...: corner to corner
    edges = np.arange(6)[:, None] * np.array([1, -1, 0])  # (0,0,0), (1,-1,0), ...: edge to edge
    for keys, joined in ((corners, {26}), (edges, {18, 26})):
        for connectivity in (6, 18, 26):
            keep = remove_small_components(keys, 6, connectivity=connectivity)
            assert keep.tolist() == [connectivity in joined] * 6


def test_a_big_component_is_kept_and_specks_dropped() -> None:
    u, v = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
    floor = np.stack([u, v, (u + v) // 7], -1).reshape(-1, 3)  # a stepped floor: 400 voxels
    specks = np.array(
        [[5, 5, 9], [30, 0, 0], [31, 1, 1], [-4, 2, 0], [-4, 3, 0], [-4, 3, 1], [10, 10, 5]]
    )  # one alone, a corner pair, an L of 3, and one 3 above the floor (2 there, at most 3 around)
    keys = np.concatenate([floor, specks])
    keep = remove_small_components(keys, 4)
    assert keep[:400].all()
    assert not keep[400:].any()
    keep3 = remove_small_components(keys, 3)
    assert keep3.tolist() == [True] * 400 + [False] * 3 + [True] * 3 + [False]
    # The steps touch by edges: one component 18-connected, several 6-connected.
    assert remove_small_components(floor, 400, connectivity=18).all()
    assert not remove_small_components(floor, 400, connectivity=6).any()


@pytest.mark.parametrize("box", [(3, 3, 1), (3, 1, 3), (1, 3, 3), (2, 2, 2)])
def test_every_voxel_set_in_a_small_box(box: tuple[int, int, int]) -> None:
    """All 2**8 or 2**9 subsets: every way a diagonal can sit beside face neighbours."""
    cells = np.argwhere(np.ones(box, bool))
    for bits in range(1, 2 ** len(cells)):
        dense = np.zeros(box, bool)
        dense[tuple(cells[[(bits >> i) & 1 == 1 for i in range(len(cells))]].T)] = True
        keys = np.argwhere(dense)
        for connectivity in (6, 18, 26):
            for min_voxels in (2, 3, 5):
                got = remove_small_components(keys, min_voxels, connectivity=connectivity)
                assert np.array_equal(got, reference(dense, min_voxels, connectivity)), keys


@pytest.mark.parametrize("min_voxels", [-3, 0, 1])
def test_min_voxels_of_one_or_less_keeps_all(min_voxels: int) -> None:
    keys = np.array([[0, 0, 0], [9, 9, 9]])
    assert remove_small_components(keys, min_voxels).tolist() == [True, True]


def test_empty_input() -> None:
    for min_voxels in (1, 5):
        keep = remove_small_components(np.zeros((0, 3), np.int64), min_voxels)
        assert keep.shape == (0,)
        assert keep.dtype == np.bool_


def test_negative_huge_and_extreme_coordinates() -> None:
    rng = np.random.default_rng(3)
    dense = rng.random((8, 8, 8)) < 0.3
    keys = np.argwhere(dense)
    expect = reference(dense, 4, 26)
    for shift in ([-1000, -1, -(2**40)], [2**50, -(2**55), 3], [I64.max - 8, I64.min, 0]):
        assert np.array_equal(remove_small_components(keys + shift, 4), expect)
    # The whole int64 range: neighbours across the ends are not invented, real ones are found.
    extremes = np.array([[I64.max, 0, 0], [I64.max - 1, 0, 1], [I64.min, 0, 0], [0, I64.min, 5]])
    assert remove_small_components(extremes, 2).tolist() == [True, True, False, False]


def test_keys_millions_apart_keep_their_own_components() -> None:
    rng = np.random.default_rng(4)
    dense = rng.random((6, 6, 6)) < 0.35
    keys = np.argwhere(dense)
    expect = reference(dense, 3, 26)
    far = [[0, 0, 0], [7_000_000, -9_000_000, 0], [0, 5_000_000, 8_000_000], [3, -3, 10**12]]
    keys_far = np.concatenate([keys + shift for shift in far])
    assert np.array_equal(remove_small_components(keys_far, 3), np.tile(expect, len(far)))


def test_the_mask_follows_the_input_order() -> None:
    rng = np.random.default_rng(5)
    keys = np.argwhere(rng.random((10, 10, 10)) < 0.2) - 5
    keep = remove_small_components(keys, 3)
    perm = rng.permutation(len(keys))
    assert np.array_equal(remove_small_components(keys[perm], 3), keep[perm])
    assert 0 < keep.sum() < len(keep)  # the case drops some voxels and keeps others


@pytest.mark.parametrize("dtype", [np.int8, np.int32, np.uint16, np.uint64])
def test_integer_dtypes(dtype: type[np.integer[Any]]) -> None:
    keys = np.array([[0, 0, 0], [1, 0, 0], [5, 5, 5]], dtype=dtype)
    assert remove_small_components(keys, 2).tolist() == [True, True, False]


@settings(max_examples=150, deadline=None)
@given(
    dense=arrays(np.bool_, array_shapes(min_dims=3, max_dims=3, min_side=1, max_side=7)),
    connectivity=st.sampled_from([6, 18, 26]),
    min_voxels=st.integers(0, 9),
    shift=st.tuples(*[st.integers(-(2**40), 2**40)] * 3),
    gap=st.integers(0, 3),
    ranked=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_matches_scipy_ndimage_label(
    *,
    dense: np.ndarray,
    connectivity: int,
    min_voxels: int,
    shift: tuple[int, int, int],
    gap: int,
    ranked: bool,
    seed: int,
) -> None:
    """Any voxel set in a small box, shifted, shuffled, optionally split by an empty slab whose
    far side is moved 2**45 away (an axis spanning more than 2 N values is compressed), and
    optionally through the ranked-column path (forced)."""
    axis = gap % 3
    if gap and dense.shape[axis] > 1:
        cut = dense.shape[axis] // 2  # an empty slab before index `cut`: nothing touches across
        dense = np.insert(dense, cut, False, axis=axis)
        keys = np.argwhere(dense)
        keys[keys[:, axis] > cut, axis] += 2**45
    else:
        keys = np.argwhere(dense)
    expect = reference(dense, min_voxels, connectivity)
    perm = np.random.default_rng(seed).permutation(len(keys))
    limit = 0 if ranked else voxels3d._MAX_LINEAR_CODE
    with mock.patch.object(voxels3d, "_MAX_LINEAR_CODE", limit):
        got = remove_small_components(keys[perm] + shift, min_voxels, connectivity=connectivity)
    assert np.array_equal(got, expect[perm])


@pytest.mark.parametrize(
    ("keys", "kwargs", "name"),
    [
        (np.zeros((3, 2), np.int64), {}, "keys"),
        (np.zeros(3, np.int64), {}, "keys"),
        (np.zeros((2, 3)), {}, "keys"),  # float
        (np.array([[1, 2, 3], [1, 2, 3]]), {}, "keys"),  # a voxel twice
        (np.array([[2**63, 0, 0]], np.uint64), {}, "keys"),
        (np.zeros((1, 3), np.int64), {"min_voxels": 2.5}, "min_voxels"),
        (np.zeros((1, 3), np.int64), {"min_voxels": True}, "min_voxels"),
        (np.zeros((1, 3), np.int64), {"connectivity": 8}, "connectivity"),
        (np.zeros((1, 3), np.int64), {"connectivity": True}, "connectivity"),
    ],
)
def test_bad_arguments_name_the_parameter(
    keys: np.ndarray, kwargs: dict[str, Any], name: str
) -> None:
    options = {"min_voxels": 2, **kwargs}
    with pytest.raises(ValueError, match=name):
        remove_small_components(keys, **options)
