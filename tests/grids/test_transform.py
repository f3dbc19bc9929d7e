"""Grid transforms keep every cell where it was in the map frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scan2terrain.grids import axis_align, canvas, invert_occupancy, to_trinary, upsample
from scan2terrain.types import Pose2D


def centres(shape: tuple[int, int], origin: Pose2D, res: float) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.indices(shape, dtype=np.float64)
    return origin.transform((cols + 0.5) * res, (rows + 0.5) * res)


def test_canvas_crop_and_extend_keep_georeference() -> None:
    data = np.arange(12, dtype=np.int16).reshape(3, 4)
    origin = Pose2D(1.0, -2.0, 0.3)
    out, o2 = canvas(data, origin, 0.5, width=6, height=2, offset_x=1, offset_y=-1, fill=-7)
    assert out.shape == (2, 6)
    np.testing.assert_array_equal(out[:, 0], [-7, -7])
    np.testing.assert_array_equal(out[:, 1:5], data[1:3])
    x0, y0 = centres(data.shape, origin, 0.5)
    x1, y1 = centres(out.shape, o2, 0.5)
    # Cell (1, 0) of the input is cell (0, 1) of the output.
    assert (x1[0, 1], y1[0, 1]) == pytest.approx((x0[1, 0], y0[1, 0]))


@pytest.mark.parametrize("quarter", [1, 2, 3, -1])
def test_axis_align_quarter_turns_are_exact(quarter: int) -> None:
    rng = np.random.default_rng(quarter + 5)
    data = rng.integers(-1, 101, (5, 7)).astype(np.int8)
    origin = Pose2D(3.0, -1.0, quarter * math.pi / 2)
    out, o2 = axis_align(data, origin, 0.25, fill=-1)
    assert o2.yaw == 0.0
    assert sorted(out.ravel().tolist()) == sorted(data.ravel().tolist())
    x0, y0 = centres(data.shape, origin, 0.25)
    x1, y1 = centres(out.shape, o2, 0.25)
    # Every input cell centre is an output cell centre holding the same value.
    col = np.rint((x0 - o2.x) / 0.25 - 0.5).astype(int)
    row = np.rint((y0 - o2.y) / 0.25 - 0.5).astype(int)
    np.testing.assert_array_equal(out[row, col], data)
    np.testing.assert_allclose(x1[row, col], x0, atol=1e-9)
    np.testing.assert_allclose(y1[row, col], y0, atol=1e-9)


def test_axis_align_ninety_degrees_orientation() -> None:
    # A wall along the map's local +u axis (bottom row) must point along world +y after 90 deg.
    data = np.zeros((3, 4), dtype=np.int8)
    data[0, :] = 100
    out, o2 = axis_align(data, Pose2D(0.0, 0.0, math.pi / 2), 1.0)
    assert out.shape == (4, 3)
    np.testing.assert_array_equal(out[:, 2], [100] * 4)  # the column nearest x = 0
    assert (o2.x, o2.y) == pytest.approx((-3.0, 0.0))


@settings(max_examples=40, deadline=None)
@given(yaw=st.floats(-math.pi, math.pi), seed=st.integers(0, 1000))
def test_axis_align_any_yaw_takes_values_from_under_each_centre(yaw: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    data = rng.integers(0, 50, (6, 9)).astype(np.int16)
    origin = Pose2D(0.7, -0.4, yaw)
    out, o2 = axis_align(data, origin, 0.5, fill=-1)
    x, y = centres(out.shape, o2, 0.5)
    c, s = math.cos(-yaw), math.sin(-yaw)
    u = c * (x - origin.x) - s * (y - origin.y)
    v = s * (x - origin.x) + c * (y - origin.y)
    col, row = np.floor(u / 0.5).astype(int), np.floor(v / 0.5).astype(int)
    inside = (col >= 0) & (col < 9) & (row >= 0) & (row < 6)
    np.testing.assert_array_equal(out[inside], data[row[inside], col[inside]])
    assert (out[~inside] == -1).all()


def test_upsample() -> None:
    out, res = upsample(np.array([[1, 2]], dtype=np.uint8), 0.1, 3)
    assert res == pytest.approx(0.1 / 3) and out.shape == (3, 6)
    np.testing.assert_array_equal(out[:, :3], 1)


def test_to_trinary_and_invert() -> None:
    data = np.array([-1, 0, 1, 50, 99, 100], dtype=np.int8)
    np.testing.assert_array_equal(to_trinary(data), [-1, 0, -1, -1, -1, 100])
    np.testing.assert_array_equal(
        to_trinary(data, occupied_above=65, free_below=19.6), [-1, 0, 0, -1, 100, 100]
    )
    np.testing.assert_array_equal(invert_occupancy(data), [-1, 100, 99, 50, 1, 0])
