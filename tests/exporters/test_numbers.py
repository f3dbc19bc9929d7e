"""Numbers as text: each value's shortest repr, whatever repeats."""

from __future__ import annotations

import numpy as np

from scan2terrain.exporters._numbers import float_texts, joined_ints


def test_float_texts_are_each_values_repr_in_order() -> None:
    rng = np.random.default_rng(7)
    grid = np.round(rng.uniform(-50, 50, (500, 3)) / 0.05) * 0.05 + 0.025  # repeats
    odd = np.array([[0.0, -0.0, 1e-300], [1e16, -1e-5, 0.1 + 0.2], [np.inf, -np.inf, 5e-324]])
    values = np.concatenate([grid, odd, rng.normal(size=(200, 3))])
    assert float_texts(values) == [repr(x) for x in values.reshape(-1).tolist()]
    assert float_texts(odd)[:2] == ["0.0", "-0.0"]  # the sign of zero is kept


def test_float_texts_of_float32_read_back_to_the_same_float32() -> None:
    values = np.random.default_rng(3).normal(size=(100, 3)).astype(np.float32)
    texts = float_texts(values)
    assert texts == [repr(x) for x in values.reshape(-1).tolist()]
    assert np.array_equal(np.array([float(t) for t in texts], dtype=np.float32), values.ravel())


def test_float_texts_of_nothing() -> None:
    assert float_texts(np.zeros((0, 3))) == []


def test_joined_ints_are_the_numbers_one_space_apart() -> None:
    values = np.array([[0, 7, -3], [123456789012, 1, 2]], dtype=np.int64)
    assert joined_ints(values) == "0 7 -3 123456789012 1 2"
    assert joined_ints(np.zeros(0, dtype=np.int64)) == ""
