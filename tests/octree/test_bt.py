"""OctoMap .bt files, checked against OctoMap itself.

OctoMap is the reference twice over: the C++ library through octomap-python
(``pip install octomap-python``: ``OcTree.readBinary``/``writeBinary``/``insertPointCloud``) and
Debian's octomap-tools (``apt-get install -y octomap-tools``: ``bt2vrml`` lists the occupied leaves
of a .bt file, ``edit_octree`` reads a .bt file and writes it again with OctoMap's writer). Both
are required: without them these tests fail and say what to install.
"""

from __future__ import annotations

import importlib
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.exporters.pointcloud import write_points
from scan2terrain.octree.bt import BtTree, read_bt, write_bt
from tests.fixtures import GEB079

OFF = 32768
Voxels = tuple[NDArray[np.uint16], NDArray[np.bool_]]


@pytest.fixture(scope="module")
def octomap() -> ModuleType:
    try:
        return importlib.import_module("octomap")
    except ImportError:  # pragma: no cover - depends on the environment
        pytest.fail("octomap-python is needed for these tests: pip install octomap-python")


def require_tool(name: str) -> str:
    exe = shutil.which(name)
    if exe is None:
        pytest.fail(
            f"{name} not found: install OctoMap's command line tools with "
            "`apt-get install -y octomap-tools`"
        )
    return exe


# -- helpers -------------------------------------------------------------------------------------


def octomap_leaves(tree: Any) -> dict[str, NDArray[Any]]:
    """Leaves of an octomap-python tree in its iteration order."""
    keys, depth, occupied, centres, sizes = [], [], [], [], []
    for leaf in tree.begin_leafs():
        k = leaf.getIndexKey()  # lowest key of the leaf's cube
        keys.append((k[0], k[1], k[2]))
        depth.append(leaf.getDepth())
        occupied.append(tree.isNodeOccupied(leaf))
        centres.append(leaf.getCoordinate())
        sizes.append(leaf.getSize())
    return {
        "keys": np.array(keys, dtype=np.uint16).reshape(-1, 3),
        "depth": np.array(depth, dtype=np.uint8),
        "occupied": np.array(occupied, dtype=bool),
        "centres": np.array(centres, dtype=np.float32).reshape(-1, 3),
        "sizes": np.array(sizes, dtype=np.float64),
    }


def leaves_to_voxels(
    keys: NDArray[np.uint16], depth: NDArray[np.uint8], occ: NDArray[Any]
) -> Voxels:
    tree = BtTree(1.0, keys, depth, occ.astype(bool))
    return tree.expand()


def as_set(
    keys: NDArray[np.uint16], occupied: NDArray[np.bool_]
) -> set[tuple[int, int, int, bool]]:
    return {(int(a), int(b), int(c), bool(o)) for (a, b, c), o in zip(keys, occupied, strict=True)}


def box(lo: tuple[int, int, int], side: int) -> NDArray[np.int64]:
    grid: NDArray[np.int64] = np.indices((side, side, side)).reshape(3, -1).T
    return grid + np.asarray(lo, dtype=np.int64)


def synthetic_voxels(seed: int) -> Voxels:
    """Voxels that prune at several levels, with near-misses that must not prune."""
    rng = np.random.default_rng(seed)
    parts: list[tuple[NDArray[np.int64], NDArray[np.bool_]]] = []
    for side, state in ((2, True), (4, False), (8, True), (16, False)):
        lo = rng.integers(-200, 200, 3) // side * side  # aligned uniform cubes: one leaf each
        parts.append((box(tuple(lo), side), np.full(side**3, state)))
    # an aligned cube with one voxel of the other state: must stay expanded
    lo = rng.integers(-200, 200, 3) // 4 * 4
    states = np.ones(64, bool)
    states[rng.integers(64)] = False
    parts.append((box(tuple(lo), 4), states))
    # an aligned cube missing one voxel (unknown): must stay expanded
    lo = rng.integers(-200, 200, 3) // 2 * 2
    cube = box(tuple(lo), 2)
    parts.append((np.delete(cube, rng.integers(8), axis=0), np.zeros(7, bool)))
    # scattered voxels anywhere, the key range's ends included
    scattered = rng.integers(-300, 300, (400, 3))
    scattered[:2] = [(-OFF, -OFF, -OFF), (OFF - 1, OFF - 1, OFF - 1)]
    parts.append((scattered, rng.random(400) < 0.3))
    keys = np.concatenate([p for p, _ in parts]) + OFF
    occupied = np.concatenate([o for _, o in parts])
    keys, first = np.unique(keys, axis=0, return_index=True)  # earlier parts win
    return keys.astype(np.uint16), occupied[first]


def octomap_tree_from_scans(
    octomap: ModuleType, resolution: float, seed: int, maxrange: float
) -> Any:
    """A small synthetic scan: a room's walls and floor seen from three poses."""
    rng = np.random.default_rng(seed)
    tree = octomap.OcTree(resolution)
    for _ in range(3):
        origin = rng.uniform(-0.5, 0.5, 3)
        direction = rng.normal(size=(3000, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        # distance to the box [-3, 3] x [-2, 2] x [-1, 1.5] along each ray
        upper = np.array([3.0, 2.0, 1.5]) - origin
        lower = np.array([-3.0, -2.0, -1.0]) - origin
        with np.errstate(divide="ignore"):
            t = np.where(direction > 0, upper / direction, lower / direction)
        dist = t.min(axis=1) * rng.uniform(0.98, 1.0, len(t))
        points = origin + direction * dist[:, None]
        tree.insertPointCloud(points, origin, maxrange=maxrange)
    return tree


# -- reading -------------------------------------------------------------------------------------


def test_geb079_leaves_match_octomap(octomap: ModuleType) -> None:
    ours = read_bt(GEB079)
    reference = octomap.OcTree(0.1)
    assert reference.readBinary(str(GEB079).encode())
    ref = octomap_leaves(reference)
    assert ours.resolution == reference.getResolution() == 0.08
    # same leaves, same states, in the same (depth first) order
    np.testing.assert_array_equal(ours.keys, ref["keys"])
    np.testing.assert_array_equal(ours.depth, ref["depth"])
    np.testing.assert_array_equal(ours.occupied, ref["occupied"])
    assert ours.occupied.sum() == 143_729 and len(ours) == 428_144
    assert set(np.unique(ours.depth)) == {13, 14, 15, 16}  # pruned leaves of several sizes
    # metric centres and sizes: OctoMap's point3d is float32, ours rounds to the same floats
    centres, sizes = ours.leaf_centres()
    np.testing.assert_array_equal(centres.astype(np.float32), ref["centres"])
    np.testing.assert_allclose(sizes, ref["sizes"], rtol=1e-12)
    occ = ours.occupied_leaves()
    assert len(occ) == 143_729 and occ.occupied.all()
    np.testing.assert_array_equal(occ.keys, ref["keys"][ref["occupied"]])


def test_geb079_round_trip_is_byte_identical() -> None:
    tree = read_bt(GEB079)
    keys, occupied = tree.expand()
    assert len(keys) == tree.num_voxels == 1_136_432
    packed = keys.astype(np.int64) @ np.array([1 << 32, 1 << 16, 1])
    assert len(np.unique(packed)) == len(keys)  # distinct voxels
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "geb079.bt"
        write_bt(out, resolution=tree.resolution, keys=keys, occupied=occupied)
        assert out.read_bytes() == GEB079.read_bytes()


def test_expand_limit_names_the_count() -> None:
    tree = read_bt(GEB079)
    with pytest.raises(ValueError, match="1136432 voxels"):
        tree.expand(max_voxels=1_000_000)


def test_expand_covers_each_leaf_cube() -> None:
    keys = np.array([[0, 0, 0], [8, 16, 24], [65535, 65535, 65535]], dtype=np.uint16)
    tree = BtTree(0.1, keys, np.array([15, 13, 16], np.uint8), np.array([True, False, True]))
    vk, vo = tree.expand()
    assert len(vk) == 8 + 512 + 1 == tree.num_voxels
    expected = {(x, y, z, True) for x in (0, 1) for y in (0, 1) for z in (0, 1)}
    expected |= {
        (8 + x, 16 + y, 24 + z, False) for x in range(8) for y in range(8) for z in range(8)
    }
    expected.add((65535, 65535, 65535, True))
    assert as_set(vk, vo) == expected
    centres, sizes = tree.leaf_centres()
    np.testing.assert_allclose(centres[0], ((1 - OFF) * 0.1,) * 3)
    np.testing.assert_allclose(
        centres[1], ((8 + 4 - OFF) * 0.1, (16 + 4 - OFF) * 0.1, (24 + 4 - OFF) * 0.1)
    )
    np.testing.assert_allclose(sizes, [0.2, 0.8, 0.1])


# -- writing -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("resolution", "seed", "maxrange"),
    [(0.1, 0, -1.0), (0.05, 1, -1.0), (0.2, 2, 2.5), (0.08, 3, -1.0)],
)
def test_write_matches_octomap_write_binary(
    octomap: ModuleType, tmp_path: Path, resolution: float, seed: int, maxrange: float
) -> None:
    """OctoMap's tree built from scans: its voxels' ML states through write_bt, OctoMap's bytes."""
    tree = octomap_tree_from_scans(octomap, resolution, seed, maxrange)
    leaves = octomap_leaves(tree)  # before writeBinary, which turns the tree max-likelihood
    keys, occupied = leaves_to_voxels(leaves["keys"], leaves["depth"], leaves["occupied"])
    assert occupied.any() and not occupied.all()
    tree.writeBinary(str(tmp_path / "octomap.bt").encode())
    write_bt(tmp_path / "ours.bt", resolution=resolution, keys=keys, occupied=occupied)
    theirs = (tmp_path / "octomap.bt").read_bytes()
    ours = (tmp_path / "ours.bt").read_bytes()
    assert ours[:200].split(b"data\n")[0] == theirs[:200].split(b"data\n")[0]
    assert ours == theirs


@pytest.mark.parametrize("seed", range(4))
def test_write_is_read_by_octomap(octomap: ModuleType, tmp_path: Path, seed: int) -> None:
    keys, occupied = synthetic_voxels(seed)
    path = tmp_path / "synthetic.bt"
    write_bt(path, resolution=0.1, keys=keys, occupied=occupied)
    reference = octomap.OcTree(0.5)
    assert reference.readBinary(str(path).encode())
    assert reference.getResolution() == 0.1
    leaves = octomap_leaves(reference)
    assert (leaves["depth"] < 16).any()  # the uniform cubes were pruned
    vk, vo = leaves_to_voxels(leaves["keys"], leaves["depth"], leaves["occupied"])
    assert as_set(vk, vo) == as_set(keys, occupied)
    # and our reader agrees with OctoMap's, leaf for leaf
    ours = read_bt(path)
    np.testing.assert_array_equal(ours.keys, leaves["keys"])
    np.testing.assert_array_equal(ours.depth, leaves["depth"])
    np.testing.assert_array_equal(ours.occupied, leaves["occupied"])


@pytest.mark.parametrize("seed", range(3))
def test_write_matches_octomap_built_voxel_by_voxel(
    octomap: ModuleType, tmp_path: Path, seed: int
) -> None:
    """The same voxels set one by one in OctoMap (which prunes as it goes) give the same bytes."""
    keys, occupied = synthetic_voxels(seed)
    tree = octomap.OcTree(0.1)
    centres = (keys.astype(np.float64) - OFF + 0.5) * 0.1
    for centre, state in zip(centres, occupied, strict=True):
        tree.updateNode(centre, bool(state))
    tree.writeBinary(str(tmp_path / "octomap.bt").encode())
    write_bt(tmp_path / "ours.bt", resolution=0.1, keys=keys, occupied=occupied)
    assert (tmp_path / "ours.bt").read_bytes() == (tmp_path / "octomap.bt").read_bytes()


def test_known_difference_octomap_prune_stops_early(octomap: ModuleType, tmp_path: Path) -> None:
    """OctoMap's prune() stops at the first level that merges nothing, which can leave pre-pruned
    same-state leaves unmerged; write_bt, given voxel states only, prunes completely."""
    tree = octomap.OcTree(0.1)
    keys = []
    for child in range(8):  # eight sibling 2x2x2 blocks, each with its own occupied log-odds
        corner = np.array([child & 1, (child >> 1) & 1, (child >> 2) & 1]) * 2 + OFF
        for voxel in box(tuple(corner), 2):
            keys.append(voxel)
            tree.updateNode((voxel - OFF + 0.5) * 0.1, 0.5 + 0.1 * child)
    tree.writeBinary(str(tmp_path / "octomap.bt").encode())
    keys_arr = np.array(keys, dtype=np.uint16)
    write_bt(tmp_path / "ours.bt", resolution=0.1, keys=keys_arr, occupied=np.ones(64, bool))
    theirs, ours = read_bt(tmp_path / "octomap.bt"), read_bt(tmp_path / "ours.bt")
    assert theirs.depth.tolist() == [15] * 8 and ours.depth.tolist() == [14]
    assert as_set(*theirs.expand()) == as_set(*ours.expand()) == as_set(keys_arr, np.ones(64, bool))


def test_empty_tree(octomap: ModuleType, tmp_path: Path) -> None:
    path = tmp_path / "empty.bt"
    write_bt(path, resolution=0.1, keys=np.zeros((0, 3), np.uint16), occupied=np.zeros(0, bool))
    assert path.read_bytes().endswith(b"id OcTree\nsize 0\nres 0.1\ndata\n")
    tree = read_bt(path)
    assert len(tree) == 0 and tree.resolution == 0.1 and tree.expand()[0].shape == (0, 3)
    reference = octomap.OcTree(0.1)
    assert reference.readBinary(str(path).encode()) and reference.size() == 0
    empty = octomap.OcTree(0.1)
    empty.writeBinary(str(tmp_path / "octomap.bt").encode())
    assert path.read_bytes() == (tmp_path / "octomap.bt").read_bytes()


def test_resolution_that_six_digits_cannot_hold(octomap: ModuleType, tmp_path: Path) -> None:
    """OctoMap prints res with 6 significant digits; we keep every digit such a value needs."""
    res = 0.123456789
    path = tmp_path / "r.bt"
    keys = np.array([[OFF, OFF, OFF]], np.uint16)
    write_bt(path, resolution=res, keys=keys, occupied=np.ones(1, bool))
    assert b"\nres 0.123456789\n" in path.read_bytes()
    assert read_bt(path).resolution == res
    reference = octomap.OcTree(0.1)
    assert reference.readBinary(str(path).encode()) and reference.getResolution() == res


def test_write_is_atomic_and_replaces(tmp_path: Path) -> None:
    path = tmp_path / "a.bt"
    path.write_bytes(b"old")
    keys, occupied = synthetic_voxels(0)
    write_bt(path, resolution=0.1, keys=keys, occupied=occupied)
    assert read_bt(path).num_voxels == len(keys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bt"]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"resolution": 0.0}, "resolution"),
        ({"resolution": float("nan")}, "resolution"),
        ({"keys": np.zeros((2, 3), np.int64)}, "uint16"),
        ({"keys": np.zeros((2, 2), np.uint16)}, r"\(M, 3\)"),
        ({"occupied": np.zeros(3, bool)}, "occupied"),
        ({"occupied": np.zeros(2, np.uint8)}, "occupied"),
        ({"keys": np.zeros((2, 3), np.uint16)}, "distinct"),
    ],
)
def test_write_rejects_bad_arguments(tmp_path: Path, kwargs: dict[str, Any], message: str) -> None:
    args: dict[str, Any] = {
        "resolution": 0.1,
        "keys": np.array([[1, 2, 3], [4, 5, 6]], np.uint16),
        "occupied": np.array([True, False]),
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        write_bt(tmp_path / "x.bt", **args)
    assert not list(tmp_path.iterdir())


@settings(max_examples=60, deadline=None)
@given(
    raw=st.lists(
        st.tuples(st.integers(0, 15), st.integers(0, 15), st.integers(0, 15), st.booleans()),
        max_size=120,
    ),
    base=st.tuples(*[st.sampled_from([0, 16, 32752, 32768, 65520])] * 3),
    fill=st.sampled_from([None, 2, 4, 8]),
)
def test_write_read_round_trip(
    raw: list[tuple[int, int, int, bool]], base: tuple[int, int, int], fill: int | None
) -> None:
    """Any voxel set survives write_bt -> read_bt -> expand, pruned or not."""
    cells = {(x, y, z): o for x, y, z, o in raw}
    if fill is not None:  # a uniform aligned cube, so that pruning happens
        state = bool(len(raw) % 2)
        cells.update(
            {(x, y, z): state for x in range(fill) for y in range(fill) for z in range(fill)}
        )
    keys = (np.array(list(cells), dtype=np.int64).reshape(-1, 3) + base).astype(np.uint16)
    occupied = np.array(list(cells.values()), dtype=bool)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "t.bt"
        write_bt(path, resolution=0.05, keys=keys, occupied=occupied)
        tree = read_bt(path)
    vk, vo = tree.expand()
    assert as_set(vk, vo) == as_set(keys, occupied)
    assert len(vk) == len(keys)
    if fill is not None and fill > 1:
        assert (tree.depth < 16).any()


# -- OctoMap's command line tools ----------------------------------------------------------------


def test_octomap_tools_read_what_we_write(octomap: ModuleType, tmp_path: Path) -> None:
    """bt2vrml draws one box per occupied leaf; edit_octree rewrites our file byte for byte.

    Debian's octomap-tools (1.9.7) does not ship octree2pointcloud; bt2vrml walks the same leaf
    iterator over occupied leaves and prints each centre and size.
    """
    bt2vrml = require_tool("bt2vrml")
    edit_octree = require_tool("edit_octree")
    tree = octomap_tree_from_scans(octomap, 0.1, 5, -1.0)
    leaves = octomap_leaves(tree)
    scan_keys, scan_occupied = leaves_to_voxels(leaves["keys"], leaves["depth"], leaves["occupied"])
    cube_keys, cube_occupied = synthetic_voxels(5)  # has pruned occupied cubes
    # moved 1000 voxels away from the scan (wrapping at the end of the key range stays distinct)
    cube_keys = ((cube_keys.astype(np.int64) + 1000) % 65536).astype(np.uint16)
    keys = np.concatenate([scan_keys, cube_keys])
    occupied = np.concatenate([scan_occupied, cube_occupied])
    path = tmp_path / "ours.bt"
    write_bt(path, resolution=0.1, keys=keys, occupied=occupied)
    ours = read_bt(path).occupied_leaves()

    subprocess.run([bt2vrml, path.name], cwd=tmp_path, check=True, capture_output=True)
    wrl = (tmp_path / "ours.bt.wrl").read_text()
    boxes = re.findall(
        r"translation (\S+) (\S+) (\S+)\s+children \[ Shape \{ geometry Box "
        r"\{ size (\S+) (\S+) (\S+)\}",
        wrl,
    )
    assert len(boxes) == len(ours) == wrl.count("Transform")
    assert len(ours) < occupied.sum()  # some occupied leaves are pruned cubes
    printed = np.array(boxes, dtype=np.float64)
    centres, sizes = ours.leaf_centres()
    np.testing.assert_allclose(printed[:, :3], centres, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(printed[:, 3:], np.repeat(sizes[:, None], 3, axis=1), rtol=1e-5)

    rewritten = tmp_path / "rewritten.bt"
    subprocess.run([edit_octree, "-o", str(rewritten), str(path)], check=True, capture_output=True)
    assert rewritten.read_bytes() == path.read_bytes()


# -- bad input -----------------------------------------------------------------------------------


def header(**fields: str) -> bytes:
    lines = {"id": "OcTree", "size": "3", "res": "0.1"}
    lines.update(fields)
    text = "# Octomap OcTree binary file\n#\n" + "".join(f"{k} {v}\n" for k, v in lines.items())
    return text.encode() + b"data\n"


# The root, its inner child 0, and that child's occupied child 0 (a depth-2 leaf): 2 records,
# 3 nodes.
TINY_DATA = b"\x03\x00" + b"\x02\x00"


def expect_input_error(path: Path, message: str = "") -> InputError:
    with pytest.raises(InputError) as info:
        read_bt(path)
    assert str(path) in str(info.value)
    assert message in str(info.value)
    assert "\n" not in str(info.value)
    return info.value


def test_tiny_tree_reads(tmp_path: Path) -> None:
    path = tmp_path / "tiny.bt"
    path.write_bytes(header() + TINY_DATA)
    tree = read_bt(path)
    assert tree.depth.tolist() == [2] and tree.occupied.tolist() == [True]
    assert tree.keys.tolist() == [[0, 0, 0]]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "not an OctoMap .bt file"),
        (b"hello\nworld\n", "not an OctoMap .bt file"),
        (b"# Octomap OcTree file\nid OcTree\nsize 1\nres 0.1\ndata\n", ".ot file"),
        (b"\x03\x00\x00\x00" + b"\x00" * 20, "old binary format"),
        (header(id="ColorOcTree") + TINY_DATA, "id ColorOcTree"),
        (header(id="CountingOcTree") + TINY_DATA, "id CountingOcTree"),
        (header(res="-1") + TINY_DATA, "res -1"),
        (header(res="0") + TINY_DATA, "res 0"),
        (header(res="abc") + TINY_DATA, "res abc"),
        (header(res="nan") + TINY_DATA, "res nan"),
        (header(res="1_0") + TINY_DATA, "res 1_0"),
        (header(size="-3") + TINY_DATA, "size -3"),
        (header(size="\u00b2") + TINY_DATA, "size"),
        (header(size="4") + TINY_DATA, "size 4"),
        (header(size="2") + TINY_DATA, "size 2"),
        (header()[: -len(b"data\n")], "no 'data'"),
        (b"# Octomap OcTree binary file\nsize 3\nres 0.1\ndata\n" + TINY_DATA, "no 'id'"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 3\ndata\n" + TINY_DATA, "no 'res'"),
        (header() + TINY_DATA[:3], "ends before the tree"),
        (header(), "ends before the tree"),
        # a chain of 17 inner nodes: deeper than OctoMap's 16 levels
        (header(size="19") + b"\x03\x00" * 17 + b"\x02\x00", "depth 16"),
    ],
)
def test_bad_files_raise_input_error(tmp_path: Path, content: bytes, message: str) -> None:
    path = tmp_path / "bad.bt"
    path.write_bytes(content)
    expect_input_error(path, message)


def test_missing_file_and_folder(tmp_path: Path) -> None:
    expect_input_error(tmp_path / "absent.bt", "no such file")
    expect_input_error(tmp_path, "cannot read")


def test_truncated_geb079(tmp_path: Path) -> None:
    data = GEB079.read_bytes()
    start = data.index(b"data\n") + 5
    cuts = [1, 10, 28, 29, 60, 110, start - 20, start - 7, start - 3, start - 1, start]
    cuts += [start + 1, start + 2, start + 1001, len(data) // 2, len(data) - 2, len(data) - 1]
    path = tmp_path / "geb079_cut.bt"
    for cut in cuts:
        path.write_bytes(data[:cut])
        expect_input_error(path)


def test_trailing_bytes_are_ignored_as_octomap_does(octomap: ModuleType, tmp_path: Path) -> None:
    path = tmp_path / "trailing.bt"
    path.write_bytes(GEB079.read_bytes() + b"\x00\xff trailing garbage\n")
    reference = octomap.OcTree(0.1)
    assert reference.readBinary(str(path).encode())
    assert len(read_bt(path)) == len(read_bt(GEB079))


def test_size_mismatch_is_an_error_as_in_octomap(octomap: ModuleType, tmp_path: Path) -> None:
    path = tmp_path / "size.bt"
    path.write_bytes(GEB079.read_bytes().replace(b"size 532566", b"size 532565"))
    assert not octomap.OcTree(0.1).readBinary(str(path).encode())
    expect_input_error(path, "size 532565")


def test_header_tokens_as_octomap_reads_them(tmp_path: Path) -> None:
    """Comments, unknown keywords (skipped with their line) and the deprecated id 1."""
    path = tmp_path / "h.bt"
    path.write_bytes(
        b"# Octomap OcTree binary file with more words\r\n# a comment\n\nfoo bar baz\n"
        b"id 1\n  size\t3\nres 5e-2 \ndata and the rest of the line\n" + TINY_DATA
    )
    tree = read_bt(path)
    assert tree.resolution == 0.05 and len(tree) == 1


def test_corrupted_bytes_never_crash(tmp_path: Path) -> None:
    keys, occupied = synthetic_voxels(7)
    good = tmp_path / "good.bt"
    write_bt(good, resolution=0.1, keys=keys, occupied=occupied)
    data = bytearray(good.read_bytes())
    start = data.index(b"data\n") + 5
    rng = np.random.default_rng(0)
    path = tmp_path / "corrupt.bt"
    outcomes = {"read": 0, "error": 0}
    for _ in range(300):
        bad = bytearray(data)
        for pos in rng.integers(start, len(bad), rng.integers(1, 4)):
            bad[pos] = int(rng.integers(256))
        path.write_bytes(bytes(bad))
        try:
            read_bt(path)
            outcomes["read"] += 1
        except InputError as exc:
            assert str(path) in str(exc)
            outcomes["error"] += 1
    assert outcomes["error"] > 0


@settings(max_examples=300, deadline=None)
@given(
    head=st.sampled_from([b"", b"# Octomap OcTree binary file\n", header(), header(size="9")]),
    tail=st.binary(max_size=64),
)
def test_arbitrary_bytes_never_crash(head: bytes, tail: bytes) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.bt"
        path.write_bytes(head + tail)
        try:
            tree = read_bt(path)
        except InputError as exc:
            assert str(path) in str(exc)
        else:
            assert tree.keys.shape == (len(tree), 3)


# -- PLY / PCD -----------------------------------------------------------------------------------


def parse_ply(path: Path) -> NDArray[np.float64]:
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    head = raw[:end].decode("ascii").splitlines()
    assert head[:2] == ["ply", "format binary_little_endian 1.0"]
    (count,) = (int(line.split()[2]) for line in head if line.startswith("element vertex"))
    props = [line.split()[1:] for line in head if line.startswith("property")]
    assert props == [["double", "x"], ["double", "y"], ["double", "z"]]
    assert len(raw) - end == count * 24
    return np.frombuffer(raw, dtype="<f8", offset=end).reshape(count, 3)


def parse_pcd(path: Path) -> NDArray[np.float32]:
    raw = path.read_bytes()
    end = raw.index(b"DATA binary\n") + len(b"DATA binary\n")
    fields = dict(
        line.split(" ", 1) for line in raw[:end].decode("ascii").splitlines() if line[0] != "#"
    )
    assert fields["VERSION"] == "0.7" and fields["FIELDS"] == "x y z"
    assert fields["SIZE"] == "4 4 4" and fields["TYPE"] == "F F F" and fields["COUNT"] == "1 1 1"
    assert fields["HEIGHT"] == "1" and fields["VIEWPOINT"] == "0 0 0 1 0 0 0"
    count = int(fields["POINTS"])
    assert int(fields["WIDTH"]) == count and len(raw) - end == count * 12
    return np.frombuffer(raw, dtype="<f4", offset=end).reshape(count, 3)


def test_point_files_hold_the_points(tmp_path: Path) -> None:
    centres, _ = read_bt(GEB079).occupied_leaves().leaf_centres()
    write_points(tmp_path / "occ.ply", centres)
    write_points(tmp_path / "occ.PCD", centres)
    np.testing.assert_array_equal(parse_ply(tmp_path / "occ.ply"), centres)
    np.testing.assert_array_equal(parse_pcd(tmp_path / "occ.PCD"), centres.astype(np.float32))
    write_points(tmp_path / "none.ply", np.zeros((0, 3)))
    write_points(tmp_path / "none.pcd", np.zeros((0, 3)))
    assert (
        parse_ply(tmp_path / "none.ply").shape == parse_pcd(tmp_path / "none.pcd").shape == (0, 3)
    )
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_point_files_are_deterministic(tmp_path: Path) -> None:
    points = np.random.default_rng(0).normal(size=(50, 3)) * 1e6
    write_points(tmp_path / "a.ply", points)
    write_points(tmp_path / "b.ply", points)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    np.testing.assert_array_equal(parse_ply(tmp_path / "a.ply"), points)  # doubles: exact


@pytest.mark.parametrize(
    ("name", "points", "message"),
    [
        ("p.obj", np.zeros((1, 3)), "extension"),
        ("p", np.zeros((1, 3)), "extension"),
        ("p.ply", np.zeros((2, 2)), r"\(N, 3\)"),
        ("p.pcd", np.array([[0.0, np.nan, 0.0]]), "finite"),
    ],
)
def test_point_files_reject(tmp_path: Path, name: str, points: NDArray[Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        write_points(tmp_path / name, points)
    assert not list(tmp_path.iterdir())
