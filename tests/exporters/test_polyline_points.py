"""Polyline points as written for gz-common (``sdf.gz_polyline_points``), without Gazebo.

gz-common 4's polyline triangulation needs sums of coordinates to be exact and the points in
general position (see the function's docstring); tests/test_geometry_worlds.py and
tests/test_gazebo_harness.py check the worlds with gz-common itself.
"""

from __future__ import annotations

import itertools
import math
import re
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.exporters import sdf
from scan2terrain.geometry import outlines
from scan2terrain.types import Pose2D
from tests.conftest import write_map


def _staircase(origin: Pose2D, resolution: float) -> list[outlines.Polygon]:
    """A diagonal wall (cells touching at corners) and a block with two holes, one touching
    the block's notched corner at a point: rows and diagonals full of collinear lattice points."""
    occ = np.zeros((12, 16), dtype=bool)
    for k in range(8):
        occ[k, k : k + 2] = True
    occ[2:9, 10:16] = True
    occ[2, 10] = False  # a notch at the corner...
    occ[3, 11] = False  # ...and a hole touching it diagonally
    occ[5:7, 12:14] = False
    return outlines.trace(occ, resolution, origin)


@pytest.mark.parametrize(
    "origin",
    [Pose2D(0.0, 0.0, 0.0), Pose2D(-51.224998, 12.5, 0.0), Pose2D(431250.3, 4.1e6, 0.7)],
)
def test_points_are_on_a_binary_grid_and_barely_move(origin: Pose2D) -> None:
    polygons = [p.rings() for p in _staircase(origin, 0.05)]
    moved = sdf.gz_polyline_points(polygons)
    assert [[r.shape for r in p] for p in moved] == [[r.shape for r in p] for p in polygons]
    before = np.concatenate([r for p in polygons for r in p])
    after = np.concatenate([r for p in moved for r in p])
    exponent = math.frexp(max(float(np.abs(before).max()), 1.0))[1]
    quantum = math.ldexp(1.0, exponent - 50)
    steps = after / quantum
    assert np.array_equal(steps, np.rint(steps))  # multiples of the quantum
    assert np.abs(steps).max() <= 2.0**50 + sdf.POLYLINE_NUDGE
    assert np.abs(after - before).max() <= (sdf.POLYLINE_NUDGE + 0.5) * quantum
    assert np.abs(after - before).max() < 1e-12 * np.abs(before).max()
    # Equal points move equally (in every ring and polygon), distinct ones stay distinct.
    _, first = np.unique(before, axis=0, return_inverse=True)
    _, second = np.unique(after, axis=0, return_inverse=True)
    pairs = np.unique(np.stack([first.ravel(), second.ravel()], axis=1), axis=0)
    assert len(pairs) == first.max() + 1 == second.max() + 1
    # Sums of three coordinates, and a centroid at a vertex's height, are exact.
    rng = np.random.default_rng(3)
    values = after.ravel()
    for a, b, c in values[rng.integers(0, len(values), (200, 3))].tolist():
        assert Fraction(a) + Fraction(b) + Fraction(c) == Fraction(a + b + c)
        assert Fraction(a + b) - Fraction(min(a, b)) == Fraction(max(a, b))
    # The same input gives the same points.
    again = sdf.gz_polyline_points(polygons)
    assert [np.concatenate(p).tolist() for p in again] == [
        np.concatenate(p).tolist() for p in moved
    ]


def test_lattice_points_end_in_general_position() -> None:
    """No three points of a geometry exactly collinear any more (GTS' point location and
    constraint insertion fail on exactly collinear points)."""
    polygons = [p.rings() for p in _staircase(Pose2D(0.0, 0.0, 0.0), 0.25)]
    before = np.unique(np.concatenate([r for p in polygons for r in p]), axis=0)
    after = np.unique(
        np.concatenate([r for p in sdf.gz_polyline_points(polygons) for r in p]), axis=0
    )

    def collinear(points: np.ndarray) -> int:
        exact = [(Fraction(x), Fraction(y)) for x, y in points.tolist()]
        return sum(
            (b[0] - a[0]) * (c[1] - a[1]) == (b[1] - a[1]) * (c[0] - a[0])
            for a, b, c in itertools.combinations(exact, 3)
        )

    assert collinear(before) > 100
    assert collinear(after) == 0


def test_model_sdf_holds_exactly_those_points() -> None:
    polygons = [p.rings() for p in _staircase(Pose2D(-10.0, -10.0, 0.0), 0.05)]
    ground = sdf.Ground((0.0, 0.0), (1.0, 1.0))
    placement = sdf.walls_placement("gz", "m", "polylines", ground, 2.0)
    text = sdf.polylines_model_sdf(placement, ground, polygons, comment="c").decode()
    written = [float(v) for v in re.findall(r"<point>(\S+) \S+</point>", text)]
    written_y = [float(v) for v in re.findall(r"<point>\S+ (\S+)</point>", text)]
    moved = sdf.gz_polyline_points(polygons)
    # Collision and visual: the same points, each read back to exactly the same double.
    expected = np.concatenate([np.concatenate(p) for p in moved for _ in range(2)])
    assert written == expected[:, 0].tolist() and written_y == expected[:, 1].tolist()
    assert text == sdf.polylines_model_sdf(placement, ground, polygons, comment="c").decode()


def test_no_polygons_and_bad_points() -> None:
    assert sdf.gz_polyline_points([]) == []
    with pytest.raises(ValueError, match="finite"):
        sdf.gz_polyline_points([[np.array([[0.0, 0.0], [1.0, np.nan], [0.0, 1.0]])]])


def test_polylines_refuse_cells_gz_common_would_merge(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pixels = np.full((10, 10), 254, dtype=np.uint8)
    pixels[3:6, 2:8] = 0
    yaml_path = write_map(tmp_path / "m", pixels, resolution=0.0005)
    out = tmp_path / "w"
    argv = ["map2world", str(yaml_path), "-o", str(out), "--geometry", "polylines"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "polylines needs cells of at least 0.001 m" in err
    assert not out.exists()
    assert main([*argv[:-1], "boxes"]) == 0
