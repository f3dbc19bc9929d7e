"""Caps of polygons with many holes (speckled grids): tiled, so the work grows with the polygon
(earcut alone was quadratic in the holes), and correct where earcut's output was beyond repair.

The speckle maps here have 55-75 % wall cells: from about 60 % the walls percolate (4-connected)
into one polygon holding every free speck as a hole, which is what breaks earcut. The seeds
below are ones whose caps earcut got wrong ("cannot be triangulated along its own edges"): about
one map in twenty of 100-260 cells a side did."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from scan2terrain.cli import main
from scan2terrain.geometry import _cap_tiles, caps
from scan2terrain.geometry._cap_repair import twice_areas
from scan2terrain.geometry.contacts import SharedPoints
from scan2terrain.geometry.mesh import extrude, is_watertight
from scan2terrain.geometry.outlines import Polygon, flatten, trace
from scan2terrain.geometry.simplify import simplify
from scan2terrain.types import Pose2D
from tests.conftest import write_map
from tests.geometry.shapes import check_solid

#: Seeds of :func:`speckle_map` whose caps earcut triangulated wrongly.
EARCUT_FAILED = (19, 48, 62)


def speckle_map(seed: int) -> NDArray[np.bool_]:
    """A square map of 100-260 cells a side, 55-75 % of them walls at random."""
    rng = np.random.default_rng(seed)
    size = int(rng.integers(100, 261))
    fill = float(rng.uniform(0.55, 0.75))
    walls: NDArray[np.bool_] = np.random.default_rng(seed + 10000).random((size, size)) < fill
    return walls


def check_caps(polys: list[Polygon]) -> NDArray[np.int64]:
    """The caps of the polygons, checked: every triangle counter-clockwise with area, their
    areas adding up to the polygons', and their boundary edges exactly the outline edges."""
    rings = flatten(polys)
    xy = rings.xy
    nxt = rings.next_vertex()
    prv = np.empty(len(xy), dtype=np.int64)
    prv[nxt] = np.arange(len(xy))
    shared = SharedPoints(xy, nxt, prv)
    tri = caps._caps(xy, rings.start, rings.owner, shared)
    area2 = twice_areas(xy, tri)
    assert (area2 > 0).all()
    assert np.isclose(area2.sum() / 2, sum(p.area() for p in polys), rtol=1e-12)
    # The outline edges as the mesh's walls take them: from the sector vertex of their start.
    a = np.arange(len(xy))
    a[shared.members] = shared.sector_of_edges()
    outline = {(int(u), int(v)) for u, v in zip(a, nxt, strict=True)}
    edges = {(int(u), int(v)) for t in tri.tolist() for u, v in zip(t, t[1:] + t[:1], strict=True)}
    assert len(edges) == 3 * len(tri)  # no edge twice
    assert {(u, v) for u, v in edges if (v, u) not in edges} == outline
    return tri


@pytest.mark.parametrize("seed", EARCUT_FAILED)
def test_speckle_maps_earcut_got_wrong(seed: int) -> None:
    polys = trace(speckle_map(seed), 0.05, Pose2D(1.0, -2.0, 0.0))
    assert max(len(p.holes) for p in polys) > _cap_tiles.MANY_HOLES
    check_caps(polys)
    check_solid(extrude(polys, 2.0), polys, 2.0, 0.0)


@pytest.mark.slow
def test_rotated_and_simplified_speckle() -> None:
    polys = trace(speckle_map(EARCUT_FAILED[0]), 0.05, Pose2D(3.0, 1.0, 0.7))
    check_caps(polys)
    straight = simplify(polys, 0.05, resolution=0.05, origin=Pose2D(3.0, 1.0, 0.7))
    check_caps(straight)


@pytest.mark.slow
def test_many_holes_are_tiled(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 600 x 600 speckle map's polygon (about 30,000 holes, 200,000 points) reaches earcut
    only in tiles of about ``TILE_POINTS`` points: the work of each earcut call is bounded,
    and the calls add up to the polygon (earcut's hole bridging costs holes x points per
    call: the whole polygon in one call took minutes at 800 x 800)."""
    import mapbox_earcut

    sizes: list[int] = []
    real = mapbox_earcut.triangulate_float64

    def counted(points: NDArray[np.float64], ends: NDArray[np.uint32]) -> NDArray[np.uint32]:
        sizes.append(len(points))
        out: NDArray[np.uint32] = real(points, ends)
        return out

    monkeypatch.setattr(mapbox_earcut, "triangulate_float64", counted)
    walls = np.random.default_rng(3).random((600, 600)) < 0.63
    polys = trace(walls, 0.05, Pose2D(0.0, 0.0, 0.0))
    points = max(sum(len(r) for r in p.rings()) for p in polys)
    assert points > 200_000
    mesh = extrude(polys, 2.0)
    assert is_watertight(mesh)
    assert max(sizes) <= 8 * _cap_tiles.TILE_POINTS
    assert sum(sizes) <= 2 * sum(sum(len(r) for r in p.rings()) for p in polys)


def test_tiled_caps_are_the_same_every_run() -> None:
    polys = trace(speckle_map(EARCUT_FAILED[1]), 0.05, Pose2D(0.0, 0.0, 0.0))
    first = extrude(polys, 2.0)
    again = extrude(polys, 2.0)
    assert np.array_equal(first.faces, again.faces)
    assert np.array_equal(first.vertices, again.vertices)


def test_speckle_map_to_world(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The whole command on a speckled map_server map, unfiltered: exit 0, a closed mesh."""
    import trimesh

    walls = speckle_map(EARCUT_FAILED[0])
    pixels = np.where(np.flipud(walls), 0, 254).astype(np.uint8)
    yaml_path = write_map(tmp_path / "m", pixels, name="m.pgm", resolution=0.05)
    out = tmp_path / "w"
    code = main(["map2world", str(yaml_path), "-o", str(out), "--no-filter"])
    assert code == 0, capsys.readouterr().err
    stls = sorted(out.glob("models/*/meshes/walls.stl"))
    assert stls  # one per simulator
    for stl in stls:
        mesh = trimesh.load(stl, force="mesh")
        assert isinstance(mesh, trimesh.Trimesh)
        assert mesh.is_watertight and mesh.is_winding_consistent
        # The wall cells' volume, less the slivers that the vertices at diagonal contacts
        # (thousands here) take off as they move 1 % of a cell into their own material.
        assert np.isclose(mesh.volume, walls.sum() * 0.05 * 0.05 * 2.0, rtol=1e-2)


def test_edge_keys_stay_distinct_where_packed_keys_overflowed() -> None:
    """(polygon * n + a) * n + b passed int64 at a few hundred thousand polygons of a 3000^2
    map; the keys now number the (polygon, from point) pairs first."""
    from scan2terrain.geometry._cap_repair import _edge_keys

    n = 5_000_000  # points
    owner = np.array([400_000, 400_000, 400_001, 7], dtype=np.int64)
    a = np.array([4_999_999, 4_999_999, 4_999_999, 3], dtype=np.int64)
    b = np.array([1, 2, 1, 4_999_998], dtype=np.int64)
    assert ((owner * n + a) * n + b < 0).any()  # the old keys wrapped round
    (keys, again) = _edge_keys(n, (owner, a, b), (owner[::-1], a[::-1], b[::-1]))
    assert len(np.unique(keys)) == 4 and (keys >= 0).all()
    assert np.array_equal(again, keys[::-1])  # the same edge, the same key in another group
