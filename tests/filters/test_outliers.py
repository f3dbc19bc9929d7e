"""statistical_outliers: Open3D's neighbour search, the statistics of PCL and Open3D, kept
points as a mask; against a brute-force reference, on a plane with outliers, and where Open3D's
own remove_statistical_outlier drops points it should keep."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import open3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from scan2terrain.filters.outliers import _mean_neighbour_distance, statistical_outliers


def reference(points: np.ndarray, neighbours: int, std_ratio: float) -> tuple[np.ndarray, float]:
    """Brute force: (mean distance to the k nearest others, threshold) by all-pairs distances."""
    distances = np.linalg.norm(points[:, None] - points[None], axis=-1)
    nearest = np.sort(distances, axis=1)[:, 1 : neighbours + 1]  # column 0: the point itself
    mean = nearest.mean(axis=1)
    return mean, float(mean.mean() + std_ratio * mean.std(ddof=1))


def plane_with_outliers(seed: int) -> tuple[np.ndarray, int]:
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(40) * 0.05, np.arange(40) * 0.05)
    plane = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    plane += rng.normal(0, 0.005, plane.shape)
    far = rng.uniform(-1, 1, (25, 3)) * [10, 10, 3] + [1, 1, 4]  # 1 to 7 m above the plane
    points = np.concatenate([plane, far])
    return points, len(plane)


@pytest.fixture
def open3d_threads() -> Iterator[None]:
    saved = open3d.utility.get_max_threads()
    yield
    open3d.utility.set_max_threads(saved)


def test_a_plane_is_kept_and_far_points_removed() -> None:
    points, n_plane = plane_with_outliers(0)
    keep = statistical_outliers(points)
    assert keep[:n_plane].all()
    assert not keep[n_plane:].any()
    # The order of the points does not matter: the mask follows them.
    perm = np.random.default_rng(1).permutation(len(points))
    assert np.array_equal(statistical_outliers(points[perm]), keep[perm])


def test_the_ratio_sets_how_far_is_too_far() -> None:
    rng = np.random.default_rng(2)
    points = rng.normal(0, 1, (500, 3))  # a blob: mean distances grow smoothly outwards
    dropped = [int((~statistical_outliers(points, std_ratio=r)).sum()) for r in (0.5, 1, 2, 3)]
    assert dropped == sorted(dropped, reverse=True)
    assert dropped[0] > 50
    mean, threshold = reference(points, 20, 1.0)
    assert np.array_equal(statistical_outliers(points, std_ratio=1.0), mean <= threshold)


@pytest.mark.parametrize(("std_ratio", "kept"), [(1.95, True), (1.85, False)])
def test_the_deviation_is_the_sample_one(std_ratio: float, kept: bool) -> None:
    """Pairs 100 m apart, 1 m or (the last) 3 m wide: mean distances 1 x 8 and 3 x 2, mean 1.4,
    std 0.843 (N - 1; 0.8 over N): 3 is under 1.4 + 1.95 std only with N - 1."""
    starts = np.arange(5)[:, None] * [100.0, 0, 0]
    widths = np.array([1.0, 1, 1, 1, 3])[:, None] * [1, 0, 0]
    points = np.concatenate([starts, starts + widths])
    keep = statistical_outliers(points, neighbours=1, std_ratio=std_ratio)
    assert keep.tolist() == [True] * 4 + [kept] + [True] * 4 + [kept]


def test_results_are_the_same_run_to_run_and_for_any_thread_count(open3d_threads: None) -> None:
    points, _ = plane_with_outliers(3)
    points = np.concatenate([points, np.random.default_rng(4).uniform(0, 2, (60_000, 3))])
    runs = []
    for threads in (1, 2, 4, 1):
        open3d.utility.set_max_threads(threads)
        runs.append((_mean_neighbour_distance(points, 20), statistical_outliers(points)))
    for distances, keep in runs[1:]:
        assert distances.tobytes() == runs[0][0].tobytes()  # bit for bit
        assert np.array_equal(keep, runs[0][1])


@pytest.mark.parametrize("n", [0, 1, 2, 20])
def test_no_more_points_than_neighbours_keeps_all(n: int) -> None:
    points = np.random.default_rng(n).uniform(0, 1, (n, 3))
    points[-1:] += 1000  # one far away: too few points to call it an outlier
    keep = statistical_outliers(points, neighbours=20)
    assert keep.shape == (n,)
    assert keep.dtype == np.bool_
    assert keep.all()


def test_one_more_point_than_neighbours_is_judged() -> None:
    points = np.random.default_rng(5).uniform(0, 1, (21, 3))
    points[-1] += 1000
    assert statistical_outliers(points, neighbours=20).tolist() == [True] * 20 + [False]


def test_what_open3d_would_drop_is_kept() -> None:
    """Open3D 0.20's remove_statistical_outlier drops these; the statistics do not."""
    # 30 copies of one point in a sparse cloud: their mean distance is 0, the smallest there is.
    rng = np.random.default_rng(6)
    cloud = np.concatenate([np.full((30, 3), 0.5), rng.uniform(0, 1, (200, 3))])
    assert statistical_outliers(cloud, neighbours=20)[:30].all()
    # A regular lattice with 2 neighbours: every mean distance is 1, none is above the rest.
    lattice = np.argwhere(np.ones((5, 5, 1), bool)).astype(np.float64)
    assert statistical_outliers(lattice, neighbours=2).all()
    # Two points with 1 neighbour each.
    assert statistical_outliers(np.array([[0.0, 0, 0], [1, 0, 0]]), neighbours=1).all()


@pytest.mark.parametrize("std_ratio", [0.25, 2.0])
def test_a_lattice_is_not_cut_by_rounding(std_ratio: float) -> None:
    # 0.1 m apart: the mean distances are 0.1 up to 1e-16, which a std of 1e-16 would cut.
    for origin in ([3.7, 1.3, 0.0], [512_345.6, 5_412_345.7, 310.2]):  # and in UTM
        lattice = np.argwhere(np.ones((7, 7, 1), bool)) * 0.1 + origin
        assert statistical_outliers(lattice, neighbours=2, std_ratio=std_ratio).all()
    # ... while a corner moved 1 mm out is an outlier among 48 points at 0.1 m from theirs.
    lattice[0, :2] -= 0.001
    keep = statistical_outliers(lattice, neighbours=2, std_ratio=std_ratio)
    assert keep.tolist() == [False] + [True] * 48


@settings(max_examples=60, deadline=None)
@given(
    points=st.integers(2, 40).flatmap(
        lambda n: arrays(np.float64, (n, 3), elements=st.integers(-4, 4).map(lambda i: i / 2))
    ),
    neighbours=st.integers(1, 6),
    std_ratio=st.floats(0.25, 3.0),
)
def test_matches_a_brute_force_reference(
    points: np.ndarray, neighbours: int, std_ratio: float
) -> None:
    """Small clouds on a half-metre lattice: duplicates and ties are common."""
    keep = statistical_outliers(points, neighbours=neighbours, std_ratio=std_ratio)
    if len(points) <= neighbours:
        assert keep.all()
        return
    mean, threshold = reference(points, neighbours, std_ratio)
    assert np.allclose(_mean_neighbour_distance(points, neighbours), mean, rtol=1e-12, atol=0)
    clear = np.abs(mean - threshold) > 1e-9 * (1 + abs(threshold))  # not on the threshold
    assert np.array_equal(keep[clear], (mean <= threshold)[clear])


def test_input_dtypes() -> None:
    points, _ = plane_with_outliers(7)
    expect = statistical_outliers(points)
    assert np.array_equal(statistical_outliers(points.astype(np.float32)), expect)
    grid = np.argwhere(np.ones((6, 6, 6), bool)).astype(np.int32)  # integers are accepted
    assert statistical_outliers(grid, neighbours=6).shape == (216,)


@pytest.mark.parametrize(
    ("points", "kwargs", "name"),
    [
        (np.zeros((4, 2)), {}, "points"),
        (np.zeros(12), {}, "points"),
        (np.array([["a", "b", "c"]]), {}, "points"),
        (np.array([[0.0, np.nan, 0.0]] * 30), {}, "points"),
        (np.array([[0.0, np.inf, 0.0]]), {}, "points"),
        (np.zeros((4, 3)), {"neighbours": 0}, "neighbours"),
        (np.zeros((4, 3)), {"neighbours": 2.0}, "neighbours"),
        (np.zeros((4, 3)), {"neighbours": True}, "neighbours"),
        (np.zeros((4, 3)), {"std_ratio": 0.0}, "std_ratio"),
        (np.zeros((4, 3)), {"std_ratio": -1.0}, "std_ratio"),
        (np.zeros((4, 3)), {"std_ratio": float("nan")}, "std_ratio"),
        (np.zeros((4, 3)), {"std_ratio": float("inf")}, "std_ratio"),
        (np.zeros((4, 3)), {"std_ratio": "2"}, "std_ratio"),
    ],
)
def test_bad_arguments_name_the_parameter(
    points: np.ndarray, kwargs: dict[str, Any], name: str
) -> None:
    with pytest.raises(ValueError, match=name):
        statistical_outliers(points, **kwargs)
