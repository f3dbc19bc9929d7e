"""preview.png: the input beside the filtered grid and their difference, or the input alone;
and whether, and how, the configured filter changes a grid (for the preview and the report).
preview3d.png: the collision geometry of a world as written, seen obliquely, with the spawn
pose."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.exporters.preview import preview_png
from scan2terrain.exporters.render3d import render_png
from scan2terrain.exporters.sdf import is_ground

if TYPE_CHECKING:
    from scan2terrain.readers.world import WorldGeometry


@dataclass(frozen=True)
class Preview:
    """preview.png and what it shows."""

    png: bytes
    label: str


def make_preview(
    before: NDArray[np.generic], after: NDArray[np.generic], cfg: Config, *, occupancy: bool
) -> Preview:
    """Original | filtered | difference when a filter ran; else the input alone (labelled so)."""
    if filtering(cfg, occupancy=occupancy):
        return Preview(
            preview_png(before, after, occupancy=occupancy), "original | filtered | difference"
        )
    return Preview(preview_png(before, None, occupancy=occupancy), "the input; filtering off")


def preview3d(geometry: WorldGeometry, spawn: tuple[float, ...]) -> bytes:
    """preview3d.png of one simulator's world: its collision triangles (read back from the
    files as computed, ``SimWorld.collisions``, so the picture is what the physics gets),
    drawn obliquely with a robot-sized box at the spawn pose (x, y, z, roll, pitch, yaw)."""
    x, y, z, _, _, yaw = spawn
    # Fitted to what stands on the ground: a small room's ground slab is 10 m wider each way.
    standing = [
        geometry.part(k).reshape(-1, 3)
        for k, part in enumerate(geometry.parts)
        if not is_ground(part)
    ]
    fit = np.concatenate(standing) if standing else None
    return render_png(geometry.vertices, geometry.triangles, spawn=(x, y, z, yaw), fit=fit)


def grey8(heights: NDArray[np.float32], lo: float, hi: float) -> NDArray[np.uint8]:
    """Heights as 8-bit grey between ``lo`` (black) and ``hi`` (white), for previews."""
    span = hi - lo if hi > lo else 1.0
    grey: NDArray[np.uint8] = np.clip(np.rint((heights - lo) / span * 255), 0, 255).astype(np.uint8)
    return grey


def filtering(cfg: Config, *, occupancy: bool) -> bool:
    """Whether the configured filter changes anything: a filter kind, or for occupancy grids
    also speckle removal (heights and greys have no speckles)."""
    f = cfg.filter
    return f.enabled and (f.kind != "none" or (occupancy and f.speckle_min_cells > 1))


def filter_text(cfg: Config) -> str:
    f = cfg.filter
    if not filtering(cfg, occupancy=True):
        return "no filter"
    text = f"filter {f.kind}"
    if f.speckle_min_cells > 1:
        text += f", specks under {f.speckle_min_cells} cells removed"
    return text
