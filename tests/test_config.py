"""Config files: every example loads, bad values are refused with the key named."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from scan2terrain.config import Config, load_config
from scan2terrain.errors import ConfigError
from tests.fixtures import ROOT

CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))


def set_by_hand(path: Path) -> Config:
    """``Config()`` with every value the file sets put in by ``dataclasses.replace``, section by
    section (YAML lists as tuples): what loading the file must give, found without the loader."""
    data = yaml.safe_load(path.read_text())
    fields = {
        name: dataclasses.replace(
            getattr(Config(), name),
            **{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()},
        )
        if isinstance(values, dict)
        else values  # a top-level value (max_pixels)
        for name, values in data.items()
    }
    return dataclasses.replace(Config(), **fields)


def test_the_example_configs_are_there() -> None:
    assert [p.name for p in CONFIGS] == ["default.yaml", "indoor_gz.yaml", "paper.yaml"]


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_example_configs_load_to_the_values_they_set(path: Path) -> None:
    """Each key the file sets has the file's value, every other key keeps its default."""
    cfg = load_config(path)
    assert cfg == set_by_hand(path)
    if path.name != "default.yaml":
        assert cfg != Config()  # the example changes something


def test_paper_config_is_the_papers_tool() -> None:
    cfg = load_config(ROOT / "configs/paper.yaml")
    assert (cfg.filter.kind, cfg.terrain.height, cfg.terrain.unknown) == ("paper", 1.0, "obstacle")
    assert cfg.world.simulator == "classic"
    assert cfg.filter.size == Config().filter.size == 3  # not set by the file


def test_default_yaml_is_the_defaults() -> None:
    assert load_config(ROOT / "configs/default.yaml") == Config()


def test_overrides_win_over_file(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("terrain:\n  height: 3.0\n  unknown: obstacle\n")
    cfg = load_config(tmp_path / "c.yaml", {"terrain.height": 1.5, "filter.kind": None})
    assert cfg.terrain.height == 1.5 and cfg.terrain.unknown == "obstacle"
    assert cfg.filter.kind == "thin_wall"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("terrain:\n  height: -1\n", "terrain.height"),
        ("terrain:\n  height: tall\n", "'terrain.height' has the wrong type"),
        ("filter:\n  kind: gaussian\n", "filter.kind"),
        ("filter:\n  size: 4\n", "filter.size"),
        ("world:\n  simulator: webots\n", "world.simulator"),
        ("world:\n  model_name: 'a b'\n", "world.model_name"),
        ("dem:\n  max_elevation: 0\n", "dem.max_elevation = 0.0 is invalid: must be > 0"),
        ("dem:\n  max_elevation: .nan\n", "'dem.max_elevation' = nan is invalid"),
        ("dem:\n  max_elevation: 1.0e+10\n", "dem.max_elevation = 10000000000.0 is invalid"),
        ("nonsense: 1\n", "unknown config key 'nonsense'"),
        ("terrain: 3\n", "'terrain' must be a mapping"),
        ("- a\n- b\n", "config must be a mapping"),
        ("terrain: [\n", "malformed config YAML"),
    ],
)
def test_bad_config(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "c.yaml")


def test_max_elevation_default_is_the_readers_limit() -> None:
    from scan2terrain.readers._limits import MAX_ELEVATION_M

    assert Config().dem.max_elevation == MAX_ELEVATION_M
