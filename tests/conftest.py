"""Shared pytest fixtures (the real maps, parametrised) and a small map writer. The paths to the
real sample files are in :mod:`tests.fixtures`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.fixtures import MAPS


@pytest.fixture(params=sorted(MAPS), ids=sorted(MAPS))
def real_map(request: pytest.FixtureRequest) -> Path:
    return MAPS[request.param]


def write_map(
    folder: Path,
    pixels: np.ndarray,
    *,
    name: str = "m.png",
    resolution: float = 0.1,
    origin: str = "[0.0, 0.0, 0.0]",
    extra: str = "",
    occ: float = 0.65,
    free: float = 0.196,
) -> Path:
    """Write a map_server map (image from ``pixels``, top row first) and return the YAML path."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(folder / name)
    yaml_path = folder / "m.yaml"
    yaml_path.write_text(
        f"image: {name}\nresolution: {resolution}\norigin: {origin}\nnegate: 0\n"
        f"occupied_thresh: {occ}\nfree_thresh: {free}\n{extra}"
    )
    return yaml_path
