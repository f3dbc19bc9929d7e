"""preview3d.png (issue 30): an oblique, shaded picture of every kind of world's collision
geometry with the spawn pose, drawn by exporters/render3d.py; not blank, at least 800 px wide,
the same bytes on a rerun, skipped by --no-preview."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scan2terrain.cli import main
from scan2terrain.exporters import render3d
from scan2terrain.readers.world import read_world
from tests.fixtures import SFBAY, TB3_MAP

RED = np.array(render3d.SPAWN_RGB)
SKY = np.array(render3d.SKY)


def _voxel_cloud(tmp: Path) -> Path:
    """A room 6 x 4 m: floor, four walls 2.5 m high, a table; points 5 cm apart."""
    step = 0.05
    u = np.arange(0, 6, step)
    v = np.arange(0, 4, step)
    h = np.arange(0, 2.5, step)
    parts = [
        np.stack(np.meshgrid(u, v, [0.0], indexing="ij"), -1),
        np.stack(np.meshgrid(u, [0.0, 4.0], h, indexing="ij"), -1),
        np.stack(np.meshgrid([0.0, 6.0], v, h, indexing="ij"), -1),
        np.stack(
            np.meshgrid(np.arange(2, 3, step), np.arange(1, 2, step), [0.75], indexing="ij"), -1
        ),
    ]
    cloud = tmp / "room.xyz"
    np.savetxt(cloud, np.concatenate([p.reshape(-1, 3) for p in parts]), fmt="%.3f")
    return cloud


KINDS = {
    "walls_mesh": lambda tmp: ["map2world", str(TB3_MAP)],
    "walls_boxes": lambda tmp: ["map2world", str(TB3_MAP), "--geometry", "boxes"],
    "walls_polylines": lambda tmp: ["map2world", str(TB3_MAP), "--geometry", "polylines"],
    "map_heightmap": lambda tmp: ["map2world", str(TB3_MAP), "--geometry", "heightmap"],
    "terrain": lambda tmp: ["dem2world", str(SFBAY)],
    "voxels": lambda tmp: [
        "cloud2world", str(_voxel_cloud(tmp)), "--geometry", "voxels", "--resolution", "0.1"
    ],
}  # fmt: skip


def _rgb(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


def _build(tmp: Path, kind: str, name: str, *extra: str) -> Path:
    out = tmp / name
    assert main([*KINDS[kind](tmp), "-o", str(out), "-q", *extra]) == 0
    return out


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_kind_of_world_has_a_readable_picture(tmp_path: Path, kind: str) -> None:
    first = _build(tmp_path, kind, "a")
    again = _build(tmp_path, kind, "b")
    picture = first / "preview3d.png"
    assert picture.read_bytes() == (again / "preview3d.png").read_bytes()
    rgb = _rgb(picture)
    width = rgb.shape[1]
    assert width >= 800
    drawn = np.any(rgb != SKY, axis=-1)
    assert drawn.mean() > 0.2  # the world, not a speck in the sky
    colours = np.unique(rgb[drawn].reshape(-1, 3), axis=0)
    assert len(colours) >= 4  # the ground, faces lit differently, the spawn: not a silhouette
    # The spawn marker is there: a ring and an arrow in the spawn's red.
    assert np.all(rgb == RED, axis=-1).sum() > 50


def test_no_preview_skips_it(tmp_path: Path) -> None:
    out = _build(tmp_path, "walls_mesh", "w", "--no-preview")
    assert not (out / "preview3d.png").exists()
    assert not (out / "preview.png").exists()


def test_classic_only_world_is_drawn_from_its_own_geometry(tmp_path: Path) -> None:
    out = _build(tmp_path, "walls_mesh", "w", "--simulator", "classic")
    assert _rgb(out / "preview3d.png").shape[1] >= 800


def test_the_picture_is_the_world_as_written(tmp_path: Path) -> None:
    """Drawn again from the files on disk, it is the same picture: what the physics gets."""
    from scan2terrain.exporters.sdf import is_ground

    out = _build(tmp_path, "walls_boxes", "w")
    geometry = read_world(out / "world_gz.sdf", simulator="gz")
    import yaml

    x, y, z, _, _, yaw = yaml.safe_load((out / "spawn.yaml").read_text())["gz"]["pose"]
    standing = [
        geometry.part(k).reshape(-1, 3)
        for k, part in enumerate(geometry.parts)
        if not is_ground(part)
    ]
    png = render3d.render_png(
        geometry.vertices, geometry.triangles, spawn=(x, y, z, yaw), fit=np.concatenate(standing)
    )
    assert np.array_equal(
        _rgb(out / "preview3d.png"), np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    )


@pytest.mark.parametrize("kind", ["walls_mesh", "terrain", "voxels"])
def test_culling_back_faces_hides_nothing_seen(tmp_path: Path, kind: str) -> None:
    """Our solids wind outward and our heightmaps upward: the faces culled are hidden ones, so
    the picture barely changes (silhouette pixels of edge-on walls may go to either face)."""
    out = _build(tmp_path, kind, "w", "--no-preview")
    geometry = read_world(out / "world_gz.sdf", simulator="gz")
    culled, full = (
        np.asarray(
            Image.open(
                io.BytesIO(render3d.render_png(geometry.vertices, geometry.triangles, cull=c))
            ).convert("RGB")
        )
        for c in (True, False)
    )
    differ = np.any(culled != full, axis=-1)
    assert differ.mean() < 0.03
    # Nothing large went missing: no sky in the culled picture where the full one has a
    # surface, beyond a pixel's width of silhouette.
    holes = np.all(culled == SKY, axis=-1) & ~np.all(full == SKY, axis=-1)
    assert holes.mean() < 0.01


def _cube(side: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    corners = (
        np.array([[(i & 1) - 0.5, ((i >> 1) & 1) - 0.5, ((i >> 2) & 1) - 0.5] for i in range(8)])
        * side
    )
    faces = np.array(
        [
            (0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
            (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5),
        ]
    )  # fmt: skip
    return corners, faces


def test_a_cube_fills_the_middle_and_leaves_the_corners_sky() -> None:
    corners, faces = _cube()
    rgb = np.asarray(Image.open(io.BytesIO(render3d.render_png(corners, faces))).convert("RGB"))
    h, w, _ = rgb.shape
    assert (w, h) == (render3d.WIDTH, render3d.HEIGHT)
    assert not np.array_equal(rgb[h // 2, w // 2], SKY)
    for r, c in ((0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1)):
        assert np.array_equal(rgb[r, c], SKY)
    # The top face is level: one colour; the sides are coloured by height, band by band.
    drawn = np.any(rgb != SKY, axis=-1)
    rows = np.flatnonzero(drawn.any(axis=1))
    top_row = rgb[rows[0] + 3][drawn[rows[0] + 3]]
    assert len(np.unique(top_row, axis=0)) == 1
    assert len(np.unique(rgb[drawn], axis=0)) >= render3d._BANDS
    # The cube is fitted: it spans the picture's height but for the margin.
    rows = np.flatnonzero(np.any(rgb != SKY, axis=(1, 2)))
    assert rows[0] <= render3d.MARGIN + 1 and rows[-1] >= h - render3d.MARGIN - 2


def test_a_wall_thinner_than_a_pixel_is_a_line_not_dashes() -> None:
    """A 1 cm wall 40 m long: narrower than a pixel everywhere, still drawn along its length."""
    corners, faces = _cube(1.0)
    wall = corners * (40.0, 0.01, 2.0)
    rgb = np.asarray(Image.open(io.BytesIO(render3d.render_png(wall, faces))).convert("RGB"))
    drawn = np.any(rgb != SKY, axis=-1)
    cols = np.flatnonzero(drawn.any(axis=0))
    assert np.all(np.diff(cols) == 1)  # no gap from one end to the other


def test_the_spawn_is_marked_where_it_stands() -> None:
    corners, faces = _cube(10.0)
    spawn = (3.0, -2.0, 5.0, 0.7)  # on the cube's top
    rgb = np.asarray(
        Image.open(io.BytesIO(render3d.render_png(corners, faces, spawn=spawn))).convert("RGB")
    )
    red = np.argwhere(np.all(rgb == RED, axis=-1))
    # Where the spawn point projects, by the renderer's own camera and fit.
    right, up, _ = render3d.camera_axes()
    points = np.concatenate([corners, render3d._robot_box(spawn)[0]])
    sx, sy = points @ right, points @ up
    scale = 1 / max(
        np.ptp(sx) / (render3d.WIDTH - 2 * render3d.MARGIN),
        np.ptp(sy) / (render3d.HEIGHT - 2 * render3d.MARGIN),
    )
    p = np.array(spawn[:3])
    col = (p @ right - (sx.min() + sx.max()) / 2) * scale + render3d.WIDTH / 2
    row = render3d.HEIGHT / 2 - (p @ up - (sy.min() + sy.max()) / 2) * scale
    near = np.hypot(red[:, 0] - row, red[:, 1] - col)
    assert (near < 12).sum() > 20  # the ring and the box around the point
