"""The filter registry is the one list of filters: config, CLI and the grid steps read it."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from scan2terrain.cli import build_parser
from scan2terrain.config import FILTERS, FilterKind, load_config
from scan2terrain.errors import ConfigError
from scan2terrain.filters.registry import FILTERS as REGISTRY
from scan2terrain.filters.registry import run_filter


def test_config_and_cli_choices_come_from_the_registry() -> None:
    assert ("none", *REGISTRY) == FILTERS
    group = build_parser()._subparsers
    assert group is not None
    sub = group._group_actions[0]
    assert isinstance(sub, argparse._SubParsersAction)
    for name, parser in sub.choices.items():
        for action in parser._actions:
            if action.dest == "filter.kind":
                assert tuple(action.choices) == FILTERS, name


@pytest.mark.parametrize("kind", sorted(REGISTRY))
@pytest.mark.parametrize("dtype", [np.int8, np.uint8, np.uint16])
def test_every_filter_keeps_shape_and_dtype(kind: FilterKind, dtype: type[np.integer]) -> None:
    rng = np.random.default_rng(7)
    a = rng.integers(0, 3, size=(9, 11)).astype(dtype)
    out = run_filter(a, kind, 3, "majority" if dtype == np.int8 else "median")
    assert out.shape == a.shape and out.dtype == a.dtype
    # A lone speck on a uniform floor is removed by every filter.
    floor = np.zeros((7, 7), dtype)
    floor[3, 3] = 2
    assert not run_filter(floor, kind, 3, "median").any()


def test_none_returns_the_input_and_unknown_kinds_are_refused() -> None:
    a = np.arange(9, dtype=np.uint8).reshape(3, 3)
    assert run_filter(a, "none", 3, "median") is a
    with pytest.raises(ConfigError, match=r"filter\.kind = 'gaussian'.*one of"):
        load_config(overrides={"filter.kind": "gaussian"})
