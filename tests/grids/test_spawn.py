"""The spawn spot: level, room for a 1 x 1 m robot, free where known, nearest the preference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scan2terrain.grids.spawn import FOOTPRINT, LEVEL_SLOPE, Around, find_spawn
from scan2terrain.types import Pose2D

R = 0.05


def cell_of(x: float, y: float, origin: Pose2D) -> tuple[int, int]:
    return math.floor((y - origin.y) / R), math.floor((x - origin.x) / R)


def footprint_clear(blocked: np.ndarray, x: float, y: float, origin: Pose2D) -> bool:
    """No blocked cell overlaps the FOOTPRINT square centred on (x, y)."""
    rows, cols = np.indices(blocked.shape)
    cx = origin.x + (cols + 0.5) * R
    cy = origin.y + (rows + 0.5) * R
    near = (np.abs(cx - x) < FOOTPRINT / 2 + R / 2) & (np.abs(cy - y) < FOOTPRINT / 2 + R / 2)
    return not bool((blocked & near).any())


def test_origin_in_the_open_is_kept() -> None:
    origin = Pose2D(-5.0, -5.0)
    h = np.zeros((200, 200))
    s = find_spawn(h, R, origin)
    assert (s.x, s.y, s.z, s.yaw) == pytest.approx((0.025, 0.025, 0.0, 0.0))
    assert "map origin" in s.why


def test_a_wall_at_the_origin_moves_the_spot_to_the_nearest_room() -> None:
    origin = Pose2D(-5.0, -5.0)
    h = np.zeros((200, 200))
    h[90:110, :] = 2.0  # a 1 m thick wall across the map through the origin
    ground = h == 0
    s = find_spawn(h, R, origin, ground=ground)
    assert footprint_clear(~ground, s.x, s.y, origin)
    assert s.z == 0.0
    # Nearest: just clear of the wall's face (0.5 m from the origin) by half the footprint.
    assert abs(s.y) == pytest.approx(0.5 + FOOTPRINT / 2 + R / 2, abs=R)


def test_known_free_space_is_preferred_to_unknown_floor() -> None:
    origin = Pose2D(-5.0, -5.0)
    h = np.zeros((200, 200))
    free = np.zeros(h.shape, dtype=bool)
    free[150:190, 150:190] = True  # known free only far from the origin
    s = find_spawn(h, R, origin, free=free)
    r, c = cell_of(s.x, s.y, origin)
    assert free[r, c] and footprint_clear(~free, s.x, s.y, origin)
    assert "free" in s.why


def test_preferred_point_and_yaw_are_used() -> None:
    origin = Pose2D(0.0, 0.0)
    h = np.zeros((200, 200))
    s = find_spawn(h, R, origin, preferred=(3.0, 4.0), yaw=1.25, why="from the recorded start")
    assert (s.x, s.y, s.yaw) == pytest.approx((3.025, 4.025, 1.25))
    assert s.why.startswith("from the recorded start")


def test_origin_off_the_map_uses_its_centre() -> None:
    origin = Pose2D(100.0, 50.0)
    s = find_spawn(np.zeros((100, 60)), R, origin)
    assert (s.x, s.y) == pytest.approx((101.525, 52.525))
    assert "centre" in s.why


def test_slopes_are_avoided_and_z_is_the_highest_ground_under_the_footprint() -> None:
    """Terrain: a 20 degree ramp around the origin and a flat terrace at 3 m beside it."""
    origin = Pose2D(-5.0, -5.0)
    _, cols = np.indices((200, 200))
    x = origin.x + (cols + 0.5) * R
    h = np.clip(np.tan(np.radians(20)) * (x + 5.0), 0, 3.0)  # flat at 3 m from x = 3.24
    s = find_spawn(h, R, origin)
    r, c = cell_of(s.x, s.y, origin)
    half = round(FOOTPRINT / 2 / R)  # the cells that overlap the footprint square
    under = h[r - half : r + half + 1, c - half : c + half + 1]
    run = (2 * half + 1) * R
    assert under.max() - under.min() <= LEVEL_SLOPE * run + 1e-9  # level: rise over run
    assert s.x > 3.24 and s.z == pytest.approx(3.0)  # on the terrace, not the ramp


def test_rotated_grid() -> None:
    """A grid turned 90 degrees: the spot is found in map coordinates all the same."""
    origin = Pose2D(5.0, -5.0, math.pi / 2)
    h = np.zeros((200, 200))
    s = find_spawn(h, R, origin)
    assert (s.x, s.y) == pytest.approx((-0.025, 0.025), abs=1e-9)


def test_no_level_room_anywhere_gives_the_flattest_spot() -> None:
    h = np.random.default_rng(3).uniform(0, 1, (60, 60))
    s = find_spawn(h, R, Pose2D(-1.5, -1.5))
    assert "flattest" in s.why and math.isfinite(s.z)


def test_tiny_grid_and_bad_input() -> None:
    s = find_spawn(np.zeros((2, 3)), R, Pose2D(0, 0))
    assert math.isfinite(s.x) and s.z == 0.0
    with pytest.raises(ValueError, match="non-empty 2D"):
        find_spawn(np.zeros((0, 3)), R, Pose2D(0, 0))


def test_coarse_cells_take_the_surface_under_the_footprint() -> None:
    """A 30 m DEM: z is the bilinear ground under the 1.5 m footprint, not the highest sample
    of the neighbouring cells 30 m away."""
    r = 30.0
    _, cols = np.indices((9, 9))
    h = cols * 0.5  # rises 0.5 m a cell: 1 degree, level enough
    s = find_spawn(h.astype(np.float64), r, Pose2D(-135.0, -135.0))
    # At the centre cell (col 4, x = 0), the footprint reaches 0.75 m = 0.025 cells east.
    assert (s.x, s.y) == pytest.approx((0.0, 0.0))
    assert s.z == pytest.approx(4 * 0.5 + 0.5 * 0.75 / r)


@pytest.mark.parametrize("resolution", [1e-12, 1e-300, 1e-4])
def test_absurdly_fine_cells_do_not_overflow_the_windows(resolution: float) -> None:
    """The footprint in cells is clamped to the grid (a .bt at 1e-12 m made scipy's filters
    raise MemoryError / OverflowError)."""
    heights = np.zeros((6, 7))
    spawn = find_spawn(heights, resolution, Pose2D(0.0, 0.0, 0.0))
    assert math.isfinite(spawn.x) and math.isfinite(spawn.y) and spawn.z == 0.0


@pytest.mark.parametrize("seed", range(20))
def test_square_filter_equals_scipy(seed: int) -> None:
    """The spawn search's running min/max (no scipy import) equals scipy.ndimage's filters."""
    from scipy import ndimage

    from scan2terrain.grids.spawn import square_filter

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(int(rng.integers(1, 60)), int(rng.integers(1, 60)))).astype(np.float32)
    for half in (0, 1, 2, 7, 15, 40):
        size = 2 * half + 1
        assert np.array_equal(
            square_filter(a, half, np.maximum), ndimage.maximum_filter(a, size, mode="nearest")
        )
        assert np.array_equal(
            square_filter(a, half, np.minimum), ndimage.minimum_filter(a, size, mode="nearest")
        )
        u = (rng.random(a.shape) < 0.8).astype(np.uint8)
        assert np.array_equal(square_filter(u, half, np.minimum), ndimage.minimum_filter(u, size))


# --- issue 25 item 4: never on an obstacle when ground has room; the ground around the grid --


def test_heightmap_samples_keep_the_square_off_the_slope_up_to_a_wall() -> None:
    """At 0.1 m the 1.5 m square reaches 7.5 cells each way. Walls worlds: the cells under it
    are 7 each way, and a wall cell 8 away only touches its edge. A heightmap: Gazebo raises
    the ground from the last floor sample to the wall sample, so the square would end half way
    up that slope (1 m on a 2 m wall): samples 8 away must be floor too."""
    r = 0.1
    origin = Pose2D(-5.0, -5.0)
    h = np.zeros((100, 100))
    h[:, 58:] = 2.0  # a wall from x = 0.8 m (sample 58 at x = 0.85)
    ground = h == 0
    cells = find_spawn(h, r, origin, ground=ground, preferred=(0.5, 0.0))
    samples = find_spawn(h, r, origin, ground=ground, preferred=(0.5, 0.0), samples=True)
    assert cells.x == pytest.approx(0.05)  # column 50: cells 43..57 under the square
    assert samples.x == pytest.approx(-0.05)  # column 49: samples 41..57, 58 out of reach
    # The surface Gazebo builds (linear between samples) under the square: flat at 0.
    from scan2terrain.grids.spawn import ground_under

    for s, rise in ((cells, 1.0), (samples, 0.0)):
        col = (s.x - origin.x) / r - 0.5
        row = (s.y - origin.y) / r - 0.5
        assert ground_under(h, row, col, FOOTPRINT / 2 / r) == pytest.approx(rise)


@pytest.mark.parametrize("samples", [False, True])
def test_a_grid_all_obstacle_spawns_on_the_ground_around_it(samples: bool) -> None:
    """A lamppost's grid: 4 x 4 cells of 0.1 m, all of them wall. The world's slab reaches
    10 m beyond: the spot is the nearest level spot there, off the post, on the ground."""
    r = 0.1
    origin = Pose2D(-0.2, -0.2)
    h = np.full((4, 4), 2.0)
    ground = np.zeros(h.shape, dtype=bool)
    s = find_spawn(
        h, r, origin, ground=ground, free=~ground, samples=samples, around=Around((100,) * 4, 0.0)
    )
    assert s.ground and s.z == 0.0
    assert "beyond its edge" in s.why
    half = FOOTPRINT / 2 + (r / 2 if samples else 0.0)
    # Off the post by the square's half side (and a sample's reach for a heightmap), nearest.
    gap = max(abs(s.x) - 0.2, abs(s.y) - 0.2)
    assert half - 1e-9 <= gap <= half + r + 1e-9
    assert min(abs(s.x), abs(s.y)) <= r  # straight out from the post's side


def test_ground_around_counts_only_where_the_grid_leaves_off() -> None:
    """A free room on the grid is still preferred to the ground around it."""
    origin = Pose2D(-5.0, -5.0)
    h = np.zeros((200, 200))
    h[:, :60] = 2.0  # walls over the west side, the origin in the room to the east
    s = find_spawn(h, R, origin, ground=h == 0, free=h == 0, around=Around((400,) * 4, 0.0))
    assert (s.x, s.y) == pytest.approx((0.025, 0.025)) and "free" in s.why


@pytest.mark.parametrize("samples", [False, True])
def test_no_ground_with_room_says_so_and_why(samples: bool) -> None:
    """No ground around and none on the grid: the spot is on the obstacle, and why says there
    is no ground and why (too small, or every square touches a wall)."""
    r = 0.1
    small = find_spawn(np.full((5, 5), 2.0), r, Pose2D(-0.25, -0.25), ground=np.zeros((5, 5), bool),
                       samples=samples)  # fmt: skip
    assert not small.ground and small.z == 2.0
    assert "no ground has room" in small.why and "0.5 x 0.5 m, smaller than" in small.why
    h = np.full((40, 40), 2.0)
    h[::10, ::10] = 0.0  # a few holes, none with room
    walled = find_spawn(h, r, Pose2D(-2.0, -2.0), ground=h == 0, samples=samples)
    assert not walled.ground and "every 1.5 m square" in walled.why
    assert ("slope" in walled.why) == samples
    # The padding of a heightmap: a sample or two around a 3 x 3 m block of walls is no room.
    field = find_spawn(np.full((30, 30), 2.0), r, Pose2D(-1.5, -1.5),
                       ground=np.zeros((30, 30), bool), samples=True,
                       around=Around((1, 1, 2, 2), 0.0))  # fmt: skip
    assert not field.ground and "every 1.5 m square" in field.why


def test_ground_around_at_absurdly_fine_cells_is_bounded() -> None:
    """A slab of 10 m at 1e-12 m cells is 1e13 cells: only AROUND_MAX of them are searched
    (no MemoryError); the square does not fit, and why says so."""
    s = find_spawn(np.zeros((6, 7)), 1e-12, Pose2D(0.0, 0.0), around=Around((10**13,) * 4, 0.0))
    assert math.isfinite(s.x) and s.z == 0.0
