"""The fidelity step and command: recorded beams replayed in the world as written.

Exact worlds first: rooms whose walls lie on cell boundaries, and a planar terrain, recorded
with analytic ranges, replay to under a millimetre in every geometry the tool writes; moved or
turned, the same world scores clearly worse. Then the bundled recordings: the report exists,
its numbers are finite, and a rerun (and --stream, and Dask) gives the same bytes."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml
from numpy.typing import NDArray

from scan2terrain.cli import main
from scan2terrain.readers.cloudfile import read_cloud
from tests.fixtures import FR079, FUSE_DIR, NAV2

#: Cells of the exact rooms: a binary fraction, so cell edges are exact floats.
RES = 0.125
#: The room's inside (x0, y0, x1, y1); its walls are two cells thick around it, 2 m high.
ROOM = (-3.0, -2.0, 3.0, 2.0)
#: Hits are recorded this far into the surface they hit (metres): a point exactly on a voxel
#: boundary belongs to the voxel on its upper side, which may be the free one.
INTO = 0.0005


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def figures(folder: Path, world: str = "world_gz.sdf") -> dict[str, float]:
    doc = yaml.safe_load((folder / "fidelity.yaml").read_text())
    out: dict[str, float] = doc["worlds"][world]
    return out


# --- exact worlds -------------------------------------------------------------------------------


def room_map(tmp: Path) -> Path:
    """A map_server map of the room: free inside, walls two cells thick, no filter needed."""
    x0, y0, x1, y1 = ROOM
    cols = round((x1 - x0) / RES) + 4
    rows = round((y1 - y0) / RES) + 4
    img = np.zeros((rows, cols), np.uint8)  # black: occupied
    img[2:-2, 2:-2] = 254
    pgm = tmp / "room.pgm"
    pgm.write_bytes(f"P5\n{cols} {rows}\n255\n".encode() + img.tobytes())
    (tmp / "room.yaml").write_text(
        f"image: room.pgm\nresolution: {RES}\norigin: [{x0 - 2 * RES}, {y0 - 2 * RES}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return tmp / "room.yaml"


def room_ranges(origin: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    """From inside the room: the distance along unit ``d`` to its walls or floor (z = 0)."""
    x0, y0, x1, y1 = ROOM
    lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, np.inf])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = np.where(d > 0, (hi - origin) / d, np.inf)
        t_lo = np.where(d < 0, (lo - origin) / d, np.inf)
    out: NDArray[np.float64] = np.minimum(t_hi, t_lo).min(axis=1)
    return out


Ranges = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


def scan_file(
    path: Path, poses: list[tuple[float, float, float]], ranges_of: Ranges, beams: int
) -> Path:
    """An OctoMap scan file: per pose (sensor level, no rotation) ``beams`` points in the
    sensor frame, at elevations -20..+5 degrees (below the walls' 2 m), ranges analytic."""
    rng = np.random.default_rng(7)
    lines = []
    for x, y, z in poses:
        az = rng.uniform(-math.pi, math.pi, beams)
        el = np.radians(rng.uniform(-20.0, 5.0, beams))
        d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        r = ranges_of(np.array([x, y, z]), d) + INTO
        pts = d * r[:, None]
        lines.append(f"NODE {x} {y} {z} 0 0 0")
        lines += [f"{p[0]!r} {p[1]!r} {p[2]!r}" for p in pts.tolist()]
    path.write_text("\n".join(lines) + "\n")
    return path


POSES = [(-2.0, -1.0, 1.0), (0.0, 0.0, 0.6), (2.2, 1.3, 1.4), (1.0, -1.5, 0.9)]


@pytest.mark.parametrize("geometry", ["mesh", "boxes", "polylines"])
def test_a_room_replays_exactly_in_every_wall_geometry(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], geometry: str
) -> None:
    recording = scan_file(tmp_path / "room.dat", POSES, room_ranges, 2000)
    world = tmp_path / "w"
    code, _, err = run(
        capsys, "map2world", room_map(tmp_path), "-o", world, "--no-filter",
        "--geometry", geometry, "--height", 2.0,
    )  # fmt: skip
    assert code == 0, err
    for sim, name in (("gz", "world_gz.sdf"), ("classic", "world_classic.world")):
        out = tmp_path / f"f_{sim}"
        code, stdout, err = run(
            capsys, "fidelity", world / name, recording, "-o", out, "--simulator", sim
        )
        assert code == 0 and err == "", err
        f = figures(out, name)
        assert f["beams"] == 4 * 2000
        assert f["within_5cm"] == 1.0 and f["nothing"] == 0.0, f
        assert f["p95"] < 0.001, f  # INTO (0.5 mm) is the only difference
        assert "100.0% within 10 cm" in stdout


def test_a_voxel_world_of_the_room_replays_exactly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """octree2world --geometry voxels on the recording itself: every voxel face the beams
    end on lies on the surface they hit."""
    recording = scan_file(tmp_path / "room.dat", POSES, room_ranges, 4000)
    world = tmp_path / "w"
    code, stdout, err = run(
        capsys, "octree2world", recording, "-o", world, "--resolution", RES,
        "--geometry", "voxels", "--simulator", "gz",
    )  # fmt: skip
    assert code == 0, err
    f = figures(world)
    assert f["within_5cm"] > 0.999 and f["p95"] < 0.001, f
    assert "fidelity (world_gz.sdf)" in stdout


def ramp_dem(tmp: Path) -> Path:
    """A 65 x 65 DEM at 1 m, a plane: z = 100 + 0.1 x + 0.05 y (x east, y north from its centre)."""
    n = 65
    col, row = np.meshgrid(np.arange(n), np.arange(n))
    x, y = col - 32.0, 32.0 - row
    path = tmp / "ramp.tif"
    tifffile.imwrite(path, (100 + 0.1 * x + 0.05 * y).astype(np.float32))
    return path


def ramp_ranges(origin: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Down onto the plane z = 0.1 x + 0.05 y + 100, in the world where its lowest sample
    (x = y = -32: 95.2 m) is at z = 95.2 (dem2world keeps elevations)."""
    n = np.array([-0.1, -0.05, 1.0])
    out: NDArray[np.float64] = (100.0 - origin @ n) / (d @ n)
    return out


def test_a_heightmap_replays_exactly(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A planar terrain: each cell's two triangles are the plane, whichever diagonal."""
    rng = np.random.default_rng(3)
    lines = []
    for k in range(6):
        o = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), 130.0])
        d = np.column_stack(
            [rng.uniform(-0.3, 0.3, 500), rng.uniform(-0.3, 0.3, 500), -np.ones(500)]
        )
        d /= np.linalg.norm(d, axis=1)[:, None]
        r = ramp_ranges(o, d) + INTO
        lines.append("NODE " + " ".join(repr(float(v)) for v in o) + " 0 0 0")
        lines += [f"{p[0]!r} {p[1]!r} {p[2]!r}" for p in (d * r[:, None]).tolist()]
        del k
    recording = tmp_path / "ramp.dat"
    recording.write_text("\n".join(lines) + "\n")
    world = tmp_path / "w"
    code, _, err = run(capsys, "dem2world", ramp_dem(tmp_path), "-o", world, "--resolution", 1)
    assert code == 0, err
    out = tmp_path / "f"
    code, _, err = run(capsys, "fidelity", world / "world_gz.sdf", recording, "-o", out)
    assert code == 0 and err == "", err
    f = figures(out)
    assert f["beams"] == 3000 and f["within_5cm"] == 1.0 and f["p95"] < 0.001, f


@pytest.mark.parametrize("move", ["shifted 0.2 m", "turned 2 degrees"])
def test_the_same_world_moved_scores_clearly_worse(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], move: str
) -> None:
    recording = scan_file(tmp_path / "room.dat", POSES, room_ranges, 2000)
    world = tmp_path / "w"
    run(capsys, "map2world", room_map(tmp_path), "-o", world, "--no-filter", "--simulator", "gz")
    text = (world / "world_gz.sdf").read_text()
    pose = "0.2 0 0 0 0 0" if move.startswith("shifted") else f"0 0 0 0 0 {math.radians(2)!r}"
    assert text.count("<pose>0 0 0 0 0 0</pose>") == 1
    (world / "moved.sdf").write_text(
        text.replace("<pose>0 0 0 0 0 0</pose>", f"<pose>{pose}</pose>")
    )
    out = tmp_path / "f"
    code, _, _err = run(capsys, "fidelity", world / "moved.sdf", recording, "-o", out)
    assert code == 0
    f = figures(out, "moved.sdf")
    assert f["within_5cm"] < 0.8 and f["p95"] > 0.1, f


def test_a_world_far_off_warns_with_the_likely_cause(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = scan_file(tmp_path / "room.dat", POSES, room_ranges, 500)
    world = tmp_path / "w"
    run(capsys, "map2world", room_map(tmp_path), "-o", world, "--no-filter", "--simulator", "gz")
    text = (world / "world_gz.sdf").read_text()
    (world / "off.sdf").write_text(
        text.replace("<pose>0 0 0 0 0 0</pose>", "<pose>1 0.5 0 0 0 0</pose>")
    )
    code, _stdout, err = run(capsys, "fidelity", world / "off.sdf", recording, "-o", tmp_path / "f")
    assert code == 0
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("scan2terrain: warning: off.sdf: only "), err
    assert "within 10 cm" in lines[0] and "fidelity.png" in lines[0]


# --- a hand-written world -----------------------------------------------------------------------

HAND_WORLD = """<?xml version="1.0"?>
<sdf version="1.9">
  <world name="hand">
    <model name="ground">
      <static>true</static>
      <link name="l">
        <collision name="c"><geometry>
          <plane><normal>0 0 1</normal><size>100 100</size></plane>
        </geometry></collision>
      </link>
    </model>
    <model name="crate">
      <static>true</static>
      <pose>4 0 0.5 0 0 0</pose>
      <link name="l">
        <collision name="c"><geometry><box><size>1 2 1</size></box></geometry></collision>
      </link>
    </model>
    <model name="pillar">
      <static>true</static>
      <pose>0 5 1 0 0 0</pose>
      <link name="l">
        <collision name="c"><geometry>
          <cylinder><radius>0.5</radius><length>2</length></cylinder>
        </geometry></collision>
      </link>
    </model>
    <include>
      <uri>model://slab</uri>
      <pose>-6 0 0 0 0 1.5707963267948966</pose>
    </include>
  </world>
</sdf>
"""

SLAB_MODEL = """<?xml version="1.0"?>
<sdf version="1.9">
  <model name="slab">
    <static>true</static>
    <link name="l">
      <collision name="c"><geometry><mesh><uri>meshes/slab.stl</uri></mesh></geometry></collision>
    </link>
  </model>
</sdf>
"""


def hand_world(tmp: Path) -> Path:
    """The world above: a crate whose -x face is at x = 3.5, a pillar of radius 0.5 at
    (0, 5), and a mesh slab (a box 4 x 0.4 x 2, turned 90 degrees: its +x face at x = -5.8)."""
    import trimesh

    models = tmp / "models" / "slab"
    (models / "meshes").mkdir(parents=True)
    (models / "model.sdf").write_text(SLAB_MODEL)
    (models / "model.config").write_text(
        "<?xml version='1.0'?><model><name>slab</name><sdf version='1.9'>model.sdf</sdf></model>"
    )
    box = trimesh.creation.box(extents=(4.0, 0.4, 2.0))
    box.apply_translation((0, 0, 1.0))
    box.export(models / "meshes" / "slab.stl")
    world = tmp / "hand.sdf"
    world.write_text(HAND_WORLD)
    return world


def test_a_hand_written_world_gives_the_analytic_ranges(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world = hand_world(tmp_path)
    # A sensor at (0, 0, 0.5) looking at each object level: +x to the crate (3.5 m), +y to the
    # pillar (4.5 m), -x to the slab (5.8 m); and down at the ground (0.5 m / sin).
    heading = [(1.0, 0.0, 0.0, 3.5), (0.0, 1.0, 0.0, 4.5), (-1.0, 0.0, 0.0, 5.8)]
    down = [(math.cos(a) * 0.6, math.sin(a) * 0.6, -0.8) for a in np.linspace(0, 6, 7)]
    pts = [(dx * (r + INTO), dy * (r + INTO), dz * (r + INTO)) for dx, dy, dz, r in heading]
    for dx, dy, dz in down:  # |(0.6, 0.8)| = 1: the ground 0.5 m below is 0.625 m away
        pts.append((dx * (0.625 + INTO), dy * (0.625 + INTO), dz * (0.625 + INTO)))
    recording = tmp_path / "look.dat"
    recording.write_text(
        "NODE 0 0 0.5 0 0 0\n" + "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in pts)
    )
    out = tmp_path / "f"
    env_free = {"GZ_SIM_RESOURCE_PATH": str(tmp_path / "models")}
    with pytest.MonkeyPatch.context() as mp:
        for k, v in env_free.items():
            mp.setenv(k, v)
        code, _stdout, err = run(capsys, "fidelity", world, recording, "-o", out)
    assert code == 0 and err == "", err
    f = figures(out, "hand.sdf")
    assert f["beams"] == 10 and f["within_5cm"] == 1.0 and f["p95"] < 0.001, f


# --- bad input ----------------------------------------------------------------------------------


def test_a_world_with_a_missing_mesh_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world = hand_world(tmp_path)
    (tmp_path / "models/slab/meshes/slab.stl").unlink()
    recording = scan_file(tmp_path / "room.dat", POSES[:1], room_ranges, 10)
    out = tmp_path / "f"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GZ_SIM_RESOURCE_PATH", str(tmp_path / "models"))
        code, stdout, err = run(capsys, "fidelity", world, recording, "-o", out)
    assert code == 2 and stdout == ""
    assert len(err.splitlines()) == 1 and err.startswith("scan2terrain: error: "), err
    assert "slab.stl" in err
    assert not out.exists()


def test_a_recording_with_no_scans_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world = hand_world(tmp_path)
    nav2 = NAV2
    out = tmp_path / "f"
    code, stdout, err = run(capsys, "fidelity", world, nav2, "-o", out)
    assert code == 2 and stdout == "" and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_poses_that_do_not_cover_the_scans_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A TUM trajectory from another time: no scan has a pose."""
    tum = tmp_path / "elsewhen.tum"
    tum.write_text("1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n")
    out = tmp_path / "f"
    code, stdout, err = run(
        capsys, "fidelity", hand_world(tmp_path), FUSE_DIR, "-o", out, "--trajectory", tum
    )
    assert code == 2 and stdout == "" and len(err.splitlines()) == 1, err
    assert "without a pose" in err
    assert not out.exists()


# --- the bundled recordings ---------------------------------------------------------------------


def test_bag2world_writes_the_replay_and_reruns_give_the_same_bytes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    outs = []
    for k in range(2):
        out = tmp_path / f"w{k}"
        code, stdout, err = run(capsys, "bag2world", FUSE_DIR, "-o", out)
        assert code == 0, err
        outs.append((out, stdout))
    (a, report), (b, _) = outs
    for name in ("fidelity.yaml", "fidelity.png", "fidelity_ends.ply", "trajectory.tum"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    doc = yaml.safe_load((a / "fidelity.yaml").read_text())
    # fidelity_ends.ply: one point per replayed beam, its error the figures' own.
    ends = read_cloud(a / "fidelity_ends.ply", attributes=True)
    error = np.asarray(ends.attributes["error"], dtype=np.float64)
    gz = doc["worlds"]["world_gz.sdf"]
    assert len(error) == gz["beams"] == doc["beams_used"]
    hit = error != -1.0
    assert (~hit).mean() == pytest.approx(gz["nothing"], abs=1e-4)
    assert (error[hit] <= 0.10).sum() / len(error) == pytest.approx(gz["within_10cm"], abs=2e-3)
    assert np.median(error[hit]) == pytest.approx(gz["median"], abs=2e-3)
    assert set(doc["worlds"]) == {"world_gz.sdf", "world_classic.world"}
    for f in doc["worlds"].values():
        values = [v for k, v in f.items() if k != "tenths"]
        assert all(math.isfinite(v) for v in values), f
        assert len(f["tenths"]) == 10 and sum(t["beams"] for t in f["tenths"]) == f["beams"]
    assert doc["beams_used"] == doc["returns"] > 100_000
    assert "fidelity (world_gz.sdf): " in report
    tum = (a / "trajectory.tum").read_text().splitlines()
    assert len([line for line in tum if not line.startswith("#")]) == 457  # one pose per scan


def test_no_fidelity_leaves_the_replay_out_but_keeps_the_trajectory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "w"
    code, stdout, err = run(capsys, "bag2world", FUSE_DIR, "-o", out, "--no-fidelity")
    assert code == 0, err
    assert (out / "trajectory.tum").is_file()
    assert not (out / "fidelity.yaml").exists() and not (out / "fidelity.png").exists()
    assert "fidelity (" not in stdout and "fidelity.yaml" not in stdout


def test_stream_gives_the_same_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = {}
    for how in ("default", "stream"):
        out = tmp_path / how
        extra = ["--stream"] if how == "stream" else []
        code, _, err = run(
            capsys, "bag2world", FUSE_DIR, "-o", out, "--insert", "endpoints", *extra
        )
        assert code == 0, err
        paths[how] = out
    for name in ("fidelity.yaml", "fidelity.png", "trajectory.tum", "map/map.pgm"):
        assert (paths["default"] / name).read_bytes() == (paths["stream"] / name).read_bytes(), name


@pytest.mark.slow
def test_dask_gives_the_same_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = {}
    for how, extra in (("default", []), ("dask", ["--workers", "2"])):
        out = tmp_path / how
        code, _, err = run(
            capsys, "bag2world", FUSE_DIR, "-o", out, "--insert", "endpoints", *extra
        )
        assert code == 0, err
        paths[how] = out
    for name in ("fidelity.yaml", "fidelity.png", "trajectory.tum"):
        assert (paths["default"] / name).read_bytes() == (paths["dask"] / name).read_bytes(), name


def test_octree2world_on_a_scan_file_replays_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """FR-079's 3D scan as voxels: finer voxels are closer to the building (its floor, grazed
    by a laser 6 cm above it, sits up to a voxel high), and the report says so."""
    within = []
    for res in (0.1, 0.05):
        out = tmp_path / f"w{res}"
        code, stdout, err = run(
            capsys, "octree2world", FR079, "-o", out, "--resolution", res, "--simulator", "gz",
            "--geometry", "voxels",
        )  # fmt: skip
        assert code == 0, err
        f = figures(out)
        assert f["beams"] == 88206 and all(math.isfinite(v) for k, v in f.items() if k != "tenths")
        assert "fidelity (world_gz.sdf)" in stdout
        within.append(f["within_10cm"])
    assert within[1] > within[0] + 0.1, within


# --- where the walls' faces go ------------------------------------------------------------------


@pytest.mark.parametrize("geometry", ["mesh", "boxes", "polylines"])
def test_faces_where_the_hits_lie_replay_better_than_cell_boundaries(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], geometry: str
) -> None:
    """The synthetic room's walls lie mid-cell (bagmaker): on the cell boundaries the faces
    stand half a cell in front of what the laser saw; half a cell into the wall they are on it."""
    from tests.bagmaker import synthetic_room

    bag = synthetic_room("tf", n_scans=60).write(tmp_path / "room.bag", "ros1")
    got = {}
    for faces in ("cells", "hits"):
        out = tmp_path / faces
        code, _, err = run(
            capsys, "bag2world", bag, "-o", out, "--simulator", "gz", "--geometry", geometry,
            "--wall-faces", faces,
        )  # fmt: skip
        assert code == 0 and err == "", err
        got[faces] = figures(out)
    cells, hits = got["cells"], got["hits"]
    assert -0.03 < cells["signed_median"] < -0.02 and cells["within_5cm"] < 0.93, cells
    assert abs(hits["signed_median"]) < 0.002 and hits["within_5cm"] > 0.99, hits
