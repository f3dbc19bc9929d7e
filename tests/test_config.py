"""Config files: every example loads, bad values are refused with the key named."""

from __future__ import annotations

from pathlib import Path

import pytest

from scan2terrain.config import Config, load_config
from scan2terrain.errors import ConfigError
from tests.fixtures import ROOT


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.yaml")), ids=lambda p: p.name)
def test_example_configs_load(path: Path) -> None:
    load_config(path)


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
