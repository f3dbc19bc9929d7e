"""Shared test fixtures: paths to the real sample files, and small image writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "fixtures"
MAPS = {
    "willow": FIXTURES / "maps/map_willow_garage_005/willow-full-0.05.yaml",
    "tb3": FIXTURES / "maps/map_tb3_world_mapsaver/map.yaml",
    "levine": FIXTURES / "maps/map_levine_thinwalls/levine.yaml",
    "warehouse": FIXTURES / "maps/map_nav2_warehouse_003/warehouse.yaml",
}
IMAGES = {
    "bowl_rgb": FIXTURES / "images/heightmap_png_bowl/heightmap_bowl.png",
    "winding_valley": FIXTURES / "images/heightmap_png_winding_valley/heightmap.png",
}


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
