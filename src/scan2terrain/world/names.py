"""Model names: readable (the input's stem) and unique per content (a digest of the terrain or walls
and the options that shaped them), because Gazebo Classic caches terrain by model name."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np

from scan2terrain.config import Config
from scan2terrain.exporters.heightmap import Heightmap
from scan2terrain.exporters.tiles import Terrain


def model_name_for(source: Path, hm: Heightmap, cfg: Config) -> str:
    """A readable, unique, deterministic name: input stem + digest of the terrain itself.

    Gazebo Classic caches terrain by model name (~/.gazebo/paging/<name>); a new terrain must never
    reuse the name of an old one. The digest covers what the cache holds, the pixels and their
    scale and placement, not unrelated options, and not the PNG bytes (they depend on zlib).
    """
    geometry = repr((hm.resolution, hm.centre, hm.z_min, hm.z_range, cfg.world.sampling))
    return unique_name(source, hm.pixels.tobytes() + geometry.encode(), cfg)


def terrain_name(source: Path, terrain: Terrain, cfg: Config) -> str:
    """:func:`model_name_for` one heightmap; for tiles, the prefix of every tile's model name
    (``<prefix>_<row>_<col>``), from a digest of the heights and of everything that turns them
    into pixels and places them (the tiles' pixels follow from those)."""
    if isinstance(terrain, Heightmap):
        return model_name_for(source, terrain, cfg)
    t = terrain
    scale = (t.resolution, t.origin, t.z_min, t.z_range, t.max_side, t.bit_depth, t.pad_height)
    geometry = repr((*scale, t.grid_shape, cfg.world.sampling))
    heights = hashlib.sha256(np.ascontiguousarray(t.heights).data).digest()
    return unique_name(source, heights + geometry.encode(), cfg)


def unique_name(source: Path, content: bytes, cfg: Config) -> str:
    """``world.model_name``, else input stem + the first 8 hex digits of sha256(content)."""
    if cfg.world.model_name:
        return cfg.world.model_name
    stem = re.sub(r"[^A-Za-z0-9]+", "_", source.stem).strip("_").lower() or "terrain"
    return f"{stem}_{hashlib.sha256(content).hexdigest()[:8]}"
