"""octree2world: OctoMap .bt files and scan files to Gazebo worlds, checked by Gazebo's code."""

from __future__ import annotations

import bz2
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from scan2terrain.cli import main
from scan2terrain.commands import voxels
from scan2terrain.config import load_config
from scan2terrain.errors import InputError
from scan2terrain.grids.projection import project_occupancy
from scan2terrain.octree.bt import read_bt
from scan2terrain.readers import read_map_yaml
from scan2terrain.readers.octomap_scan import read_scans
from scan2terrain.readers.poses import rpy_matrix
from scan2terrain.world.folder import write_world_folder
from tests.fixtures import FR079, GEB079
from tests.gazebo_harness import probe_world, terrain_height
from tests.world_checks import H, check_world


def test_bt_to_world_lands_in_the_map_frame(tmp_path: Path) -> None:
    cfg = load_config(
        None,
        {
            "terrain.height": H,
            "filter.enabled": False,
            "octree.z_min": 0.1,
            "octree.z_max": 1.8,
            "world.geometry": "heightmap",
        },
    )
    result = voxels.octree2world(GEB079, tmp_path / "w", cfg)
    keys, occupied = read_bt(GEB079).expand()
    grid = project_occupancy(keys, occupied, 0.08, z_min=0.1, z_max=1.8)
    assert (grid.data == 100).sum() > 1000 and (grid.data == 0).sum() > 1000
    checked = check_world(result, grid, tmp_path)
    assert checked["gz"] > 5000


def test_scan_file_is_ray_cast_and_its_octree_written(tmp_path: Path) -> None:
    cfg = load_config(None, {"octree.resolution": 0.2, "world.simulator": "gz"})
    result = voxels.octree2world(FR079, tmp_path / "w", cfg)
    tree = voxels.build_octree(FR079, cfg)
    keys, occupied = tree.occupied_and_free()
    written = read_bt(result.out / "octree.bt")
    assert written.resolution == 0.2
    wk, wo = written.expand()
    order_a = np.lexsort(keys.T[::-1])
    order_b = np.lexsort(wk.T[::-1])
    np.testing.assert_array_equal(keys[order_a], wk[order_b])
    np.testing.assert_array_equal(occupied[order_a], wo[order_b])


def test_occupied_voxel_points_export(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "w"
    assert main(["octree2world", str(GEB079), "-o", str(out), "--points", "ply", "-q"]) == 0
    data = (out / "occupied_voxels.ply").read_bytes()
    _, body = data.split(b"end_header\n", 1)
    pts = np.frombuffer(body, dtype="<f8").reshape(-1, 3)
    keys, occupied = read_bt(GEB079).expand()
    assert len(pts) == int(occupied.sum())
    lowest = keys[occupied].min(axis=0).astype(np.int64)
    np.testing.assert_allclose(pts.min(axis=0), (lowest - 32768 + 0.5) * 0.08)


def test_height_grid_world(tmp_path: Path) -> None:
    cfg = load_config(
        None,
        {
            "octree.grid": "height",
            "octree.fill": "none",
            "filter.enabled": False,
            "world.simulator": "gz",
            "octree.z_max": 2.0,
        },
    )
    result = voxels.octree2world(GEB079, tmp_path / "w", cfg)
    from scan2terrain.grids.projection import column_stats

    keys, occupied = read_bt(GEB079).expand()
    stats = column_stats(keys, occupied, 0.08, z_max=2.0)
    (w,) = result.worlds
    _, probes = probe_world(w.world, [w.models], tmp_path / "probe")
    (col,) = [p for p in probes if p.kind == "collision"]
    rows, cols = np.nonzero(stats.known)
    x, y = stats.origin.transform(
        (cols.astype(np.float64) + 0.5) * 0.08, (rows.astype(np.float64) + 0.5) * 0.08
    )
    got = terrain_height(col, x, y, "gz")
    want = stats.max_z[rows, cols]
    # Only cells whose neighbours share the height: Gazebo interpolates between vertices, and
    # vertices sit on cell centres, so at a centre the height is exact.
    span = float(np.nanmax(stats.max_z) - np.nanmin(stats.max_z))
    assert np.abs(got - want).max() <= 0.01 * span


def test_scan_reader_applies_node_poses(tmp_path: Path) -> None:
    text = "NODE 1 2 0.5 0 0 1.5707963267948966\n1 0 0\n0 2 0\nNODE 0 0 0 0 0 0\n3 3 3\n"
    (tmp_path / "s.dat").write_text(text)
    scans = list(read_scans(tmp_path / "s.dat"))
    assert len(scans) == 2
    np.testing.assert_allclose(scans[0].origin, [1, 2, 0.5])
    np.testing.assert_allclose(scans[0].points, [[1, 3, 0.5], [-1, 2, 0.5]], atol=1e-12)
    np.testing.assert_allclose(scans[1].points, [[3, 3, 3]])
    r = rpy_matrix(0.1, -0.2, 0.3)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


def test_fr079_scan_file_reads_as_one_scan_at_the_origin() -> None:
    (scan,) = list(read_scans(FR079))
    assert scan.points.shape == (88206, 3) and not scan.origin.any()


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("empty.dat", b"", "no points"),
        ("bad.dat", b"1 2 3\n4 five 6\n", "line 2: expected 'x y z'"),
        ("badnode.dat", b"NODE 1 2\n1 2 3\n", "line 1: expected 'NODE x y z roll pitch yaw'"),
        ("notbz.dat.bz2", b"not bzip2", "cannot read as an OctoMap text scan file"),
        ("trunc.bt", b"", "trunc.bt: "),
        ("text.bt", b"hello\nworld\n", "text.bt: "),
    ],
)
def test_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, content: bytes, message: str
) -> None:
    src = tmp_path / name
    src.write_bytes(content)
    outs = tmp_path / "outs"
    outs.mkdir()
    code = main(["octree2world", str(src), "-o", str(outs / "w")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and err.count("\n") == 1
    assert list(outs.iterdir()) == []


def test_truncated_real_bt_and_far_origin(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = GEB079.read_bytes()
    (tmp_path / "cut.bt").write_bytes(data[: len(data) // 2])
    assert main(["octree2world", str(tmp_path / "cut.bt"), "-o", str(tmp_path / "w")]) == 2
    assert "cut.bt" in capsys.readouterr().err and not (tmp_path / "w").exists()
    # A scan whose sensor pose is outside the octree's key range (+-3276.8 m at 0.1 m).
    far = "NODE 5000 0 0 0 0 0\n1 0 0\n"
    (tmp_path / "far.dat").write_text(far)
    assert (
        main(
            [
                "octree2world",
                str(tmp_path / "far.dat"),
                "-o",
                str(tmp_path / "w"),
                "--resolution",
                "0.1",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "far.dat" in err and "outside the octree's key range" in err


def test_height_mode_with_nothing_in_band(tmp_path: Path) -> None:
    cfg = load_config(None, {"octree.grid": "height", "octree.z_min": 100.0, "octree.z_max": 200.0})
    with pytest.raises(InputError, match="no occupied voxel in the z band"):
        voxels.octree2world(GEB079, tmp_path / "w", cfg)
    assert not (tmp_path / "w").exists()


def test_compressed_scan_file_round_trip(tmp_path: Path) -> None:
    pts = np.random.default_rng(0).uniform(-2, 2, (50, 3))
    (tmp_path / "s.dat.bz2").write_bytes(
        bz2.compress("\n".join(" ".join(repr(float(v)) for v in p) for p in pts).encode())
    )
    (scan,) = list(read_scans(tmp_path / "s.dat.bz2"))
    np.testing.assert_array_equal(scan.points, pts)
    assert math.isclose(float(np.abs(scan.origin).sum()), 0.0)


def test_scan_file_progress_bar(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """octree2world reads scan files with a bar on request (scans, points/s; no total, the file
    is read once), none for a .bt, none by default when stderr is not a terminal."""
    text = "NODE 0 0 0 0 0 0\n1 0 0\n0 2 0\nNODE 1 0 0 0 0 0\n3 3 1\n"
    (tmp_path / "s.dat").write_text(text)
    argv = ["octree2world", str(tmp_path / "s.dat"), "--resolution", "0.5", "--no-fidelity"]
    assert main([*argv, "-o", str(tmp_path / "a"), "--progress"]) == 0
    err = capsys.readouterr().err
    assert "2scan" in err.replace(" ", "") and "points/s" in err, err
    assert main([*argv, "-o", str(tmp_path / "b")]) == 0
    assert capsys.readouterr().err == ""
    assert main(["octree2world", str(GEB079), "-o", str(tmp_path / "c"), "--progress"]) == 0
    assert capsys.readouterr().err == ""


def pruned_bt(path: Path) -> None:
    """A tree as octomap_server leaves one: under a node at depth 7, seven free leaves of
    256^3 voxels (117 M voxels) and, in the eighth octant, one occupied voxel at depth 16."""

    def encode(node: object) -> tuple[bytes, int]:
        if not isinstance(node, list):
            return b"", 1
        code, body, count = 0, b"", 1
        for i, child in enumerate(node):
            kind = 3 if isinstance(child, list) else {None: 0, "free": 1, "occ": 2}[child]
            code |= kind << (2 * i)
            more, n = encode(child) if isinstance(child, list) else (b"", int(child is not None))
            body += more
            count += n
        return struct.pack("<H", code) + body, count

    def chain(levels: int, bottom: list[object]) -> list[object]:
        node = bottom
        for _ in range(levels):
            node = [node, None, None, None, None, None, None, None]
        return node

    voxel = chain(7, ["occ", None, None, None, None, None, None, None])  # depth 8 .. 15
    block: list[object] = [*["free"] * 7, voxel]  # the node at depth 7
    data, count = encode(chain(7, block))  # root .. depth 6 above it
    head = f"# Octomap OcTree binary file\nid OcTree\nsize {count}\nres 0.1\ndata\n"
    path.write_bytes(head.encode() + data)


def test_pruned_tree_with_a_huge_free_leaf(tmp_path: Path) -> None:
    """Pruned leaves are projected as columns, never expanded: the old path refused this tree
    with a max_voxels ValueError (exit 1)."""
    path = tmp_path / "pruned.bt"
    pruned_bt(path)
    bt = read_bt(path)
    assert sorted(bt.depth.tolist()) == [8] * 7 + [16]
    assert bt.num_voxels == 7 * 256**3 + 1
    for band in ([], ["--z-max", "-3250"]):
        out = tmp_path / f"w{len(band)}"
        assert main(["octree2world", str(path), "-o", str(out), "-q", "--no-filter", *band]) == 0
        _, grid = read_map_yaml(out / "map/map_gz.yaml")
        assert grid.data.shape == (512, 512)
        assert (grid.data == 100).sum() == 1 and (grid.data == 0).sum() == 512 * 512 - 1
    assert (
        main(["octree2world", str(path), "-o", str(tmp_path / "h"), "-q", "--grid", "height"]) == 0
    )


def _wall_voxels() -> tuple[np.ndarray, np.ndarray]:
    """A 2 m wall of occupied voxels over free floor, as OctoMap keys at 0.1 m."""
    xs, ys, zs = np.meshgrid(np.arange(32700, 32740), np.arange(32760, 32780), [32768, 32769])
    keys = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], axis=1).astype(np.uint16)
    occupied = keys[:, 0] < 32704
    return keys, occupied


def test_octree_file_is_made_beside_the_world_with_the_same_bytes(tmp_path: Path) -> None:
    """The .bt bytes come from a second thread while the world is built: the file holds the
    same bytes as bt_bytes makes alone, and the world is the same as without it."""
    from scan2terrain.octree.bt import bt_bytes

    keys, occupied = _wall_voxels()
    cfg = load_config(None, {})
    with voxels.octree_folder(voxels.Voxels(keys, occupied, 0.1), source=GEB079, cfg=cfg) as a:
        write_world_folder(a, tmp_path / "a", overwrite=False)
    b = voxels.voxels_folder(keys, occupied, 0.1, source=GEB079, cfg=cfg)
    write_world_folder(b, tmp_path / "b", overwrite=False)
    bt = (tmp_path / "a/octree.bt").read_bytes()
    assert bt == bt_bytes(resolution=0.1, keys=keys, occupied=occupied)
    for name in ("map/map.pgm", "world_gz.sdf", "preview.png"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_a_failing_octree_file_fails_the_world_and_writes_nothing(tmp_path: Path) -> None:
    """An error on the .bt thread reaches the caller when the folder is written (a bug of
    ours: the keys come from the octree, distinct), and no half-written folder is left."""
    from scan2terrain.commands.voxels import octree_file

    keys, occupied = _wall_voxels()
    twice = np.concatenate([keys, keys[:1]])
    with (
        pytest.raises(ValueError, match="distinct"),
        octree_file(0.1, twice, np.concatenate([occupied, occupied[:1]])) as extra,
    ):
        cfg = load_config(None, {})
        folder = voxels.voxels_folder(keys, occupied, 0.1, source=GEB079, cfg=cfg)
        write_world_folder(folder.with_extra(extra), tmp_path / "w", overwrite=False)
    assert not (tmp_path / "w").exists()
    assert [p.name for p in tmp_path.iterdir()] == []


def test_a_scan_files_height_grid_is_its_points_as_for_clouds(tmp_path: Path) -> None:
    """Issue 25 item 1, every path: octree2world on an OctoMap scan file takes a height grid's
    heights from its points, as cloud2world does from the same points ray-cast from the same
    pose (it took voxel centres: heights in steps of the resolution)."""
    from PIL import Image

    rng = np.random.default_rng(3)
    xy = rng.uniform(-6, 6, size=(20_000, 2))
    z = 0.4 * np.sin(xy[:, 0] / 2) + 0.05 * xy[:, 1]  # smooth ground, 1.7 m of relief
    sensor = np.array([0.0, 0.0, 2.0])
    local = np.column_stack([xy, z]) - sensor  # the sensor frame: identity rotation
    scan = tmp_path / "ground.dat"
    rows = "\n".join(" ".join(repr(float(v)) for v in p) for p in local)
    scan.write_text(f"NODE 0 0 2 0 0 0\n{rows}\n")
    cloud = tmp_path / "ground.xyz"
    cloud.write_text(rows + "\n")
    common = ["--grid", "height", "--resolution", "0.25", "--simulator", "gz", "-q"]
    assert main(["octree2world", str(scan), "-o", str(tmp_path / "a"), *common]) == 0
    assert main(["cloud2world", str(cloud), "-o", str(tmp_path / "b"), *common,
                 "--insert", "raycast", "--pose", "0", "0", "2", "0", "0", "0"]) == 0  # fmt: skip
    pngs = [
        np.asarray(
            Image.open(next((tmp_path / w).glob("models/*/materials/textures/heightmap.png")))
        )
        for w in ("a", "b")
    ]
    np.testing.assert_array_equal(pngs[0], pngs[1])
    assert len(np.unique(pngs[0])) > 100  # smooth, not 7 voxel layers
