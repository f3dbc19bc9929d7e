"""Small 3D components of occupied voxels left out (--min-voxels), against scipy.ndimage."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from scan2terrain.filters.voxels3d import remove_small_components

STRUCTURES = {
    6: ndimage.generate_binary_structure(3, 1),
    18: ndimage.generate_binary_structure(3, 2),
    26: np.ones((3, 3, 3)),
}


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([6, 18, 26]), st.integers(0, 6))
def test_matches_a_dense_labelling(seed: int, connectivity: int, min_voxels: int) -> None:
    rng = np.random.default_rng(seed)
    dense = rng.random((6, 7, 5)) < 0.25
    keys = np.argwhere(dense) - 1000  # negative coordinates too
    labels, _ = ndimage.label(dense, structure=STRUCTURES[connectivity])
    size = np.bincount(labels.ravel())
    expect = size[labels[dense]] >= min_voxels if min_voxels > 1 else np.ones(len(keys), bool)
    got = remove_small_components(keys, min_voxels, connectivity=connectivity)
    assert np.array_equal(got, expect)


def test_contacts_and_far_apart_keys() -> None:
    keys = np.array([[0, 0, 0], [1, 1, 1], [2**40, 0, 0]])  # a corner contact; one far away
    assert remove_small_components(keys, 2).tolist() == [True, True, False]
    assert remove_small_components(keys, 2, connectivity=18).tolist() == [False] * 3
    assert remove_small_components(np.zeros((0, 3), np.int64), 5).shape == (0,)


@pytest.mark.parametrize(
    ("keys", "kw"), [(np.zeros((2, 2)), {}), (np.zeros((1, 3)), {"connectivity": 8})]
)
def test_bad_arguments(keys: np.ndarray, kw: dict[str, int]) -> None:
    with pytest.raises(ValueError):
        remove_small_components(keys, 3, **kw)
