"""The config's rules live in its types (config.Must in Annotated fields) and are checked in
one loop; values are converted by their declared types (typing.get_origin/get_args); derived
values are properties."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Annotated, Any, get_args, get_origin, get_type_hints

import pytest

from scan2terrain.config import Config, Must, load_config
from scan2terrain.errors import ConfigError

#: Numeric fields whose only rules are across fields (Config.validate) or none by design.
FREE_NUMBERS = {
    "octree.max_range",  # any: < 0 is unlimited, as OctoMap
    "octree.z_min",  # any height; z_min <= z_max is checked across fields
    "octree.z_max",
    "scans.start",  # seconds from the start or UNIX seconds; start <= end across fields
    "scans.end",
    "scans.map_message",  # an index from either end; past the end is the bag's to refuse
}


def _fields(target: Any, prefix: str = "") -> list[tuple[str, Any]]:
    out = []
    for f in dataclasses.fields(target):
        value = getattr(target, f.name)
        if dataclasses.is_dataclass(value):
            out += _fields(value, f"{prefix}{f.name}.")
        else:
            hint = get_type_hints(type(target), include_extras=True)[f.name]
            out.append((f"{prefix}{f.name}", hint))
    return out


def _unannotated(hint: Any) -> tuple[Any, tuple[Any, ...]]:
    if get_origin(hint) is Annotated:
        base, *rules = get_args(hint)
        return base, tuple(rules)
    return hint, ()


def _numeric(hint: Any) -> bool:
    kinds = get_args(hint) if get_args(hint) and get_origin(hint) is not list else (hint,)
    return any(
        k in (int, float) or (get_origin(k) is list and get_args(k)[0] in (int, float))
        for k in kinds
    )


def test_every_number_carries_its_bounds() -> None:
    missing = []
    for key, hint in _fields(Config()):
        base, rules = _unannotated(hint)
        if _numeric(base) and not rules and key not in FREE_NUMBERS:
            missing.append(key)
    assert not missing, f"numeric fields without a Must rule: {missing}"
    assert all(isinstance(r, Must) for _, h in _fields(Config()) for r in _unannotated(h)[1])


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("filter.size", 4, "filter.size = 4 is invalid: must be odd, 3..99"),
        ("terrain.height", 0.0, "terrain.height = 0.0 is invalid: must be in (0, 100000] metres"),
        ("stream.tile_cells", 300, "must be a power of two up to 16384"),
        ("world.model_name", "a b", "letters, digits, '_' and '-' only"),
        ("scans.local_origin", [1.0, 2.0], "auto, none or [x, y, z] within 1e+09 of 0"),
        ("octree.hit", 1.0, "octree.hit = 1.0 is invalid: must be in (0, 1)"),
        ("scans.las_classes", [2, 256], "LAS classification codes, 0..255"),
        ("max_memory", 0, "max_memory = 0 is invalid: must be > 0 (MiB)"),
        ("canvas.offset_x", -(1 << 21), "within +-1048576 cells"),
    ],
)
def test_a_value_outside_its_field_s_rule_is_refused_in_the_rule_s_words(
    key: str, value: object, said: str
) -> None:
    with pytest.raises(ConfigError, match=re.escape(said)):
        load_config(None, {key: value})


def test_none_passes_the_rules_of_a_field_that_may_be_none() -> None:
    cfg = load_config(None, {})
    assert cfg.world.voxel_size is None and cfg.world.sampling is None
    assert load_config(None, {"world.sampling": 2}).world.sampling == 2


@pytest.mark.parametrize(
    ("key", "value", "got"),
    [
        ("terrain.height", 3, 3.0),
        ("terrain.upsample", 2.0, 2),
        ("terrain.bit_depth", 16, 16),
        ("scans.local_origin", "none", "none"),
        ("scans.local_origin", [1, 2, 3], [1.0, 2.0, 3.0]),
        ("scans.las_classes", [2.0, 6], [2, 6]),
        ("scans.topics", ["/a", "/b"], ["/a", "/b"]),
        ("image.origin", [1, 2], [1.0, 2.0]),
        ("scans.fixed_frame", 7, "7"),
    ],
)
def test_values_are_converted_by_the_declared_type(key: str, value: object, got: object) -> None:
    section, name = key.split(".")
    out = getattr(getattr(load_config(None, {key: value}), section), name)
    assert out == got and type(out) is type(got)


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("terrain.upsample", 1.5, "'terrain.upsample' has the wrong type (1.5; expected int)"),
        ("terrain.upsample", True, "'terrain.upsample' has the wrong type (True; expected int)"),
        ("output.preview", "yes", "'output.preview' has the wrong type ('yes'; expected bool)"),
        ("scans.las_classes", "2", "'scans.las_classes' has the wrong type"),
        ("scans.las_classes", [2.5], "'scans.las_classes' has the wrong type"),
        ("image.origin", [1, "x"], "'image.origin' has the wrong type"),
        ("image.origin", 5, "'image.origin' has the wrong type (5; expected list[float] | null)"),
        (
            "scans.local_origin",
            [1, 2, "a"],
            "'scans.local_origin' has the wrong type ([1, 2, 'a']; expected 'auto' | 'none' |"
            " list[float])",
        ),
        ("scans.fixed_frame", ["map"], "'scans.fixed_frame' has the wrong type"),
        ("terrain.height", math.inf, "'terrain.height' = inf is invalid: must be a finite"),
    ],
)
def test_a_value_of_the_wrong_type_is_refused(key: str, value: object, said: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(None, {key: value})
    assert f"command line: {said}" in str(info.value)


def test_empty_is_refused_where_the_type_has_no_none(tmp_path: Path) -> None:
    empty = tmp_path / "empty.yaml"
    empty.write_text("terrain:\n  height: null\n")
    with pytest.raises(ConfigError, match=re.escape(f"{empty}: 'terrain.height' may not be")):
        load_config(empty)
    empty.write_text("world:\n  voxel_size: null\n")
    assert load_config(empty).world.voxel_size is None


def test_derived_values_are_properties() -> None:
    cfg = Config()
    assert cfg.octree.z_band == (-math.inf, math.inf)
    assert load_config(None, {"octree.z_min": 0.1}).octree.z_band == (0.1, math.inf)
    assert not cfg.stream.active and not cfg.stream.distributed
    assert load_config(None, {"stream.enabled": True}).stream.active
    dask = load_config(None, {"stream.workers": 2}).stream
    assert dask.active and dask.distributed and not dask.enabled
    assert "active" not in Config().to_dict()["stream"]  # not written to scan2terrain.yaml
