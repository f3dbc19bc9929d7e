"""``fidelity.yaml``, ``fidelity.png`` and ``fidelity_ends.ply``: how a recording replayed in
the written world(s) compares with what the sensor measured
(:class:`~scan2terrain.types.Fidelity`)."""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from scan2terrain.exporters.pointcloud import cloud_bytes
from scan2terrain.types import Cloud, Fidelity, Figures

#: The picture's error classes: upper bounds (metres) and colours; then "hit nothing".
CLASSES: tuple[tuple[float, str, tuple[int, int, int]], ...] = (
    (0.05, "< 5 cm", (26, 152, 80)),
    (0.10, "5-10 cm", (166, 217, 106)),
    (0.20, "10-20 cm", (254, 224, 139)),
    (0.50, "20-50 cm", (244, 109, 67)),
    (np.inf, "> 50 cm", (165, 0, 38)),
)
NOTHING = ("hit nothing", (94, 60, 153))
TRAJECTORY = ("trajectory", (33, 102, 172))
#: The picture's map area is at most this many pixels a side (cells grow to fit).
MAX_SIDE = 900
#: Cells are at least this size (metres).
MIN_CELL = 0.05
#: A smaller map is scaled up by a whole factor to at least this width (pixels).
MIN_WIDTH = 600

_HEADER = """\
# How the recorded beams, replayed in the world(s) written here, compare with the ranges
# the sensor measured (scan2terrain). Each beam with a return is cast from its recorded
# sensor pose along its recorded direction into the world's collision geometry as the
# files say. Metres and shares of the beams (0..1); errors are simulated - recorded, over
# the beams that hit something; nothing: the share that hit no geometry; short / long: the
# shares that hit more than 0.2 m before / beyond the recorded range; inside: the share whose
# first hit faced away from the sensor (it lies inside a solid). tenths: the same
# per tenth of the recording's time. A sample is a fixed hash of each return's place.
"""


#: fidelity_ends.ply's error for a beam that hit nothing (PLY has no inf that every reader takes).
HIT_NOTHING = -1.0


def fidelity_ends_ply(report: Fidelity) -> bytes:
    """Each replayed beam's recorded end point (x, y, z in the world's frame) and its
    ``error``: |simulated - recorded| in metres, :data:`HIT_NOTHING` where the beam hit
    nothing; a binary PLY any point-cloud tool opens (``scan2terrain view`` colours it)."""
    error = np.where(np.isfinite(report.errors), report.errors, HIT_NOTHING).astype(np.float32)
    cloud = Cloud(
        points=report.ends.astype(np.float32).astype(np.float64),  # float32 in the file
        path=Path("fidelity_ends.ply"),
        format="ply",
        records=len(report.ends),
        attributes={"error": error},
    )
    return bytes(cloud_bytes(cloud, ".ply").data)


def figures_doc(f: Figures) -> dict[str, Any]:
    return dataclasses.asdict(f)


def fidelity_yaml(reports: Sequence[Fidelity], *, beams_used: int, sampled: bool) -> bytes:
    """One document for the worlds of a folder (keyed by world file)."""
    import yaml

    first = reports[0]
    doc: dict[str, Any] = {
        "pose_source": first.pose_source,
        "returns": first.returns,
        "beams_used": beams_used,
        "sample": "every return" if not sampled else "a fixed hash sample of the returns",
        "worlds": {
            r.world: {
                **figures_doc(r.overall),
                "tenths": [figures_doc(t) for t in r.tenths],
            }
            for r in reports
        },
    }
    return (_HEADER + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)).encode()


def summary(report: Fidelity) -> str:
    """One line for the command's report."""
    f = report.overall
    if f.beams == 0:
        return "fidelity: no beam with a return to replay"
    median = "n/a" if f.median is None else f"{f.median:.3f} m"
    return (
        f"fidelity ({report.world}): {f.beams:,} recorded beams replayed: "
        f"{_pc(f.within_10cm)} within 10 cm, {_pc(f.within_5cm)} within 5 cm, median error "
        f"{median}, {_pc(f.nothing)} hit nothing, {_pc(f.short)} > 0.2 m short"
    )


def _pc(share: float | None) -> str:
    return "n/a" if share is None else f"{100 * share:.1f}%"


def fidelity_png(report: Fidelity) -> bytes:
    """The map frame seen from above: each cell coloured by the mean |error| of the beams
    ending in it (purple where most hit nothing), the trajectory, and a legend."""
    from PIL import Image, ImageDraw, ImageFont

    ends, errors, path = report.ends[:, :2], report.errors, report.trajectory
    pts = np.vstack([ends, path]) if len(ends) else path
    lo = pts.min(axis=0) - 0.5
    hi = pts.max(axis=0) + 0.5
    cell = max(MIN_CELL, float((hi - lo).max()) / MAX_SIDE)
    w = int(np.ceil((hi[0] - lo[0]) / cell))
    h = int(np.ceil((hi[1] - lo[1]) / cell))
    rgb = np.full((h, w, 3), 255, dtype=np.uint8)
    if len(ends):
        col = np.clip(((ends[:, 0] - lo[0]) / cell).astype(np.intp), 0, w - 1)
        row = np.clip(((ends[:, 1] - lo[1]) / cell).astype(np.intp), 0, h - 1)
        flat = row * w + col
        found = np.isfinite(errors)
        count = np.bincount(flat, minlength=w * h)
        misses = np.bincount(flat, weights=~found, minlength=w * h)
        total = np.bincount(flat[found], weights=errors[found], minlength=w * h)
        hits = count - misses
        mean = np.divide(total, hits, out=np.full(w * h, np.inf), where=hits > 0)
        classes = np.searchsorted([c[0] for c in CLASSES[:-1]], mean, side="left")
        colours = np.array([c[2] for c in CLASSES] + [NOTHING[1]], dtype=np.uint8)
        classes = np.where(misses * 2 > count, len(CLASSES), classes)
        img = colours[classes].reshape(h, w, 3)
        shown = (count > 0).reshape(h, w)
        rgb[shown] = img[shown]
    rgb = rgb[::-1]  # image rows run down, y up
    scale = max(1, -(-MIN_WIDTH // w))  # a small map scaled up by a whole factor
    rgb = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    h, w, cell = h * scale, w * scale, cell / scale
    font = ImageFont.load_default(size=14)
    line_h = 20
    legend_rows = 3
    canvas = Image.new("RGB", (max(w, 560), h + line_h * legend_rows + 10), "white")
    canvas.paste(Image.fromarray(rgb), (0, 0))
    draw = ImageDraw.Draw(canvas)
    if len(path) > 1:
        xy = np.column_stack([(path[:, 0] - lo[0]) / cell, h - (path[:, 1] - lo[1]) / cell])
        draw.line([tuple(p) for p in xy.tolist()], fill=TRAJECTORY[1], width=2)
    top = h + 6
    x = 6
    for label, colour in [(c[1], c[2]) for c in CLASSES] + [NOTHING, TRAJECTORY]:
        draw.rectangle([x, top + 3, x + 12, top + 15], fill=colour)
        draw.text((x + 16, top), label, fill="black", font=font)
        x += 22 + int(draw.textlength(label, font=font)) + 10
        if x > canvas.width - 110:
            x, top = 6, top + line_h
    f = report.overall
    draw.text(
        (6, h + 6 + line_h * 2),
        f"{_pc(f.within_10cm)} of {f.beams:,} beams within 10 cm; 1 px = {cell:.3g} m",
        fill="black",
        font=font,
    )
    buf = io.BytesIO()
    canvas.save(buf, format="PNG", optimize=False)
    return buf.getvalue()
