"""OctoMap binary tree files (``.bt``): read them into leaf arrays, write voxels as OctoMap does.

The format, as OctoMap's ``OcTree::writeBinary``/``readBinary`` define it
(``AbstractOccupancyOcTree.cpp``, ``AbstractOcTree.cpp::readHeader``,
``OccupancyOcTreeBase.hxx::writeBinaryNode``/``readBinaryNode``):

* A text header: the first line starts with ``# Octomap OcTree binary file``; then
  whitespace-separated tokens: ``#`` starts a comment running to the end of its line, ``id <type>``,
  ``size <nodes>``, ``res <metres>``, unknown keywords are skipped to the end of their line, and
  ``data`` ends the header (the rest of its line is skipped too).
* The maximum-likelihood, pruned tree, depth first from the root: two bytes per inner node, the
  first for children 0-3 and the second for children 4-7, two bits per child at bit ``2 i``
  (value ``(byte >> 2 i) & 3``): 0 no child (unknown), 1 free leaf, 2 occupied leaf, 3 inner node.
  After its two bytes a node's inner children follow, in child order, each with its own subtree.
* Child ``i`` of a node at depth ``d`` holds the keys whose bit ``15 - d`` is ``i & 1`` in x,
  ``(i >> 1) & 1`` in y and ``(i >> 2) & 1`` in z (``OcTreeKey.h::computeChildIdx``), so the
  children, read in order, are the octants in Morton (z-order) order and depth first order is
  Morton order.
* ``size`` counts every node of the written tree, root and leaves included. OctoMap's reader
  rejects a file whose tree has another number of nodes; so does :func:`read_bt`. OctoMap ignores
  anything after the tree, and so do we.

Keys are OctoMap's: 16 bits per axis, ``key = floor(coord / resolution) + 32768``; a leaf at depth
``d`` is a cube of ``2 ** (16 - d)`` voxels a side, named here by its lowest (min-corner) key.

Both directions are vectorised per tree level (at most 16 numpy passes), never per node.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import MAX_CELL, MIN_CELL
from scan2terrain.errors import InputError
from scan2terrain.fileio import atomic_write
from scan2terrain.octree.keys import KEY_OFFSET
from scan2terrain.readers._files import regular_file

#: First line of every ``.bt`` file (``AbstractOccupancyOcTree::binaryFileHeader``).
BINARY_HEADER = b"# Octomap OcTree binary file"
#: First line of OctoMap's full-probability ``.ot`` files (``AbstractOcTree::fileHeader``).
_OT_HEADER = b"# Octomap OcTree file"
#: The comment line OctoMap writes after the first line.
_COMMENT = b"# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
#: Depth of a voxel (a leaf at the finest resolution).
TREE_DEPTH = 16
#: OctoMap's key of the cell holding coordinate 0.

_FREE, _OCCUPIED, _INNER = 1, 2, 3
_TOKEN = re.compile(rb"[ \t\n\v\f\r]*([^ \t\n\v\f\r]+)")
_UNSIGNED = re.compile(r"[0-9]+")
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")
#: Offsets (x, y, z) of child i's octant, in units of the child's side.
_CHILD_OFFSETS = np.array([(i & 1, (i >> 1) & 1, (i >> 2) & 1) for i in range(8)], dtype=np.uint32)
#: For every 16-bit node record: how many of its children are inner nodes (code 3).
_INNER_COUNT = sum(
    ((np.arange(1 << 16, dtype=np.uint32) >> (2 * i)) & 3 == _INNER).astype(np.int8)
    for i in range(8)
)


@dataclass(frozen=True)
class BtTree:
    """The leaves of an OctoMap tree as read from a ``.bt`` file.

    Attributes
    ----------
    resolution : float
        Voxel side in metres (the file's ``res``).
    keys : uint16 array (L, 3)
        Lowest OctoMap key (x, y, z) of each leaf.
    depth : uint8 array (L,)
        Tree depth of each leaf: 16 for a voxel, ``d`` < 16 for a cube of ``2 ** (16 - d)`` voxels
        a side left by pruning.
    occupied : bool array (L,)
        Maximum-likelihood state of each leaf (the file stores no probabilities).

    Leaves are in depth first order, children 0..7, as in the file. Space covered by no leaf is
    unknown.
    """

    resolution: float
    keys: NDArray[np.uint16]
    depth: NDArray[np.uint8]
    occupied: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.depth.shape[0])

    @property
    def num_voxels(self) -> int:
        """How many voxels the leaves cover (what :meth:`expand` would return)."""
        counts = np.bincount(self.depth, minlength=TREE_DEPTH + 1)
        return sum(int(n) << (3 * (TREE_DEPTH - d)) for d, n in enumerate(counts))

    def expand(self, max_voxels: int = 50_000_000) -> tuple[NDArray[np.uint16], NDArray[np.bool_]]:
        """Every voxel the leaves cover, with its state.

        Returns
        -------
        keys : uint16 array (M, 3)
        occupied : bool array (M,)
            Voxels of voxel-sized leaves come first, then those of ever larger leaves; within a
            leaf size, in leaf order.

        Raises
        ------
        ValueError
            If there are more than ``max_voxels`` voxels (one big free leaf can hide millions).
        """
        total = self.num_voxels
        if total > max_voxels:
            raise ValueError(
                f"the tree's {len(self)} leaves cover {total} voxels, more than "
                f"max_voxels={max_voxels}"
            )
        keys: list[NDArray[np.uint16]] = []
        states: list[NDArray[np.bool_]] = []
        for d in range(TREE_DEPTH, -1, -1):
            pick = self.depth == d
            if not pick.any():
                continue
            side = 1 << (TREE_DEPTH - d)
            grid = np.indices((side, side, side), dtype=np.uint16).reshape(3, -1).T
            cubes = self.keys[pick][:, None, :] + grid[None, :, :]
            keys.append(cubes.reshape(-1, 3))
            states.append(np.repeat(self.occupied[pick], side**3))
        if not keys:
            return np.zeros((0, 3), np.uint16), np.zeros(0, np.bool_)
        return np.concatenate(keys), np.concatenate(states)

    def occupied_leaves(self) -> BtTree:
        """The same tree without its free leaves."""
        pick = self.occupied
        return BtTree(self.resolution, self.keys[pick], self.depth[pick], self.occupied[pick])

    def leaf_centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Metric centres float64 (L, 3) and cube sides float64 (L,) of the leaves, in metres.

        A voxel's centre is ``(key - 32768 + 0.5) * resolution``; a leaf of side ``s`` voxels has
        its centre ``s / 2`` voxels above its lowest key. In float32 these equal OctoMap's
        ``keyToCoord`` exactly (powers of two scale without rounding).
        """
        side = np.exp2(TREE_DEPTH - self.depth.astype(np.float64))
        centres = (self.keys.astype(np.float64) - KEY_OFFSET + side[:, None] / 2) * self.resolution
        return centres, side * self.resolution


# -- reading -------------------------------------------------------------------------------------


def read_bt(path: Path) -> BtTree:
    """Read an OctoMap ``.bt`` file (``id OcTree``).

    Raises
    ------
    InputError
        Naming the file, if it is missing, not a regular file (checked before it is opened: a
        FIFO would wait for a writer, ``/dev/zero`` never end) or unreadable, is no binary
        OctoMap file, holds another tree type, has a ``res`` outside the cell sizes the
        configuration allows (``MIN_CELL``..``MAX_CELL`` metres), ends before its tree does,
        nests nodes deeper than 16 levels, or holds another number of nodes than its ``size``
        says (OctoMap's ``readBinary`` fails on that too).
    """
    path = Path(path)
    regular_file(path, "OctoMap .bt file", missing="no such file")
    try:
        buf = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except OSError as exc:
        raise InputError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    tree_type, size, resolution, start = _parse_header(path, buf)
    if tree_type not in ("OcTree", "1"):  # OctoMap reads the deprecated id "1" as OcTree
        raise InputError(
            path, f"tree type 'id {tree_type}' is not supported, only 'id OcTree' .bt files"
        )
    empty = BtTree(
        resolution, np.zeros((0, 3), np.uint16), np.zeros(0, np.uint8), np.zeros(0, np.bool_)
    )
    if size == 0:  # OctoMap reads no data at all then
        return empty
    records = np.frombuffer(buf, dtype="<u2", count=(len(buf) - start) // 2, offset=start)
    tree, nodes = _parse_records(path, records, resolution)
    if nodes != size:
        raise InputError(
            path,
            f"the header says 'size {size}' but the data holds a tree of {nodes} nodes "
            "(corrupt or edited file)",
        )
    return tree


def _parse_header(path: Path, buf: bytes) -> tuple[str, int, float, int]:
    """Return ``(id, size, res, offset of the first data byte)``, checked as OctoMap does."""
    newline = buf.find(b"\n")
    first = buf if newline < 0 else buf[:newline]
    if not first.startswith(BINARY_HEADER):
        if first.startswith(_OT_HEADER):
            raise InputError(
                path,
                "is a full-probability OctoMap .ot file, not a binary .bt file "
                "(convert it with OctoMap's convert_octree)",
            )
        if buf[:4] == b"\x03\x00\x00\x00":
            raise InputError(
                path,
                "is in OctoMap's old binary format (convert it with OctoMap's convert_octree)",
            )
        raise InputError(
            path, "not an OctoMap .bt file (its first line is not '# Octomap OcTree binary file')"
        )
    pos = len(buf) if newline < 0 else newline + 1
    tree_type = ""
    size: int | None = None
    resolution: float | None = None
    while True:
        token, pos = _next_token(buf, pos)
        if token is None:
            raise InputError(path, "the OctoMap header has no 'data' line (file cut short?)")
        if token == b"data" or token.startswith(b"#") or token not in (b"id", b"size", b"res"):
            # "data" and comments run to the end of their line; OctoMap skips unknown keywords
            # the same way (with a warning).
            end = buf.find(b"\n", pos)
            pos = len(buf) if end < 0 else end + 1
            if token == b"data":
                break
            continue
        value, pos = _next_token(buf, pos)
        text = "" if value is None else value.decode("latin-1")
        if token == b"id":
            tree_type = text
        elif token == b"size":
            if not _UNSIGNED.fullmatch(text):
                raise InputError(path, f"bad node count 'size {text}' in the OctoMap header")
            size = int(text)
        else:
            resolution = float(text) if _DECIMAL.fullmatch(text) else math.nan
            if not (math.isfinite(resolution) and resolution > 0):
                raise InputError(
                    path, f"bad resolution 'res {text}' in the OctoMap header (must be > 0)"
                )
            # 1e20 m voxels built an absurd world, 1e-300 m ones crashed later: the same
            # bounds as every cell size the configuration takes.
            if not MIN_CELL <= resolution <= MAX_CELL:
                raise InputError(
                    path,
                    f"resolution 'res {text}' in the OctoMap header is outside "
                    f"{MIN_CELL:g}..{MAX_CELL:g} m",
                )
    if not tree_type:
        raise InputError(path, "the OctoMap header has no 'id' (tree type)")
    if resolution is None:
        raise InputError(path, "the OctoMap header has no 'res' (resolution)")
    return tree_type, 0 if size is None else size, resolution, pos


def _next_token(buf: bytes, pos: int) -> tuple[bytes | None, int]:
    match = _TOKEN.match(buf, pos)
    if match is None:
        return None, len(buf)
    return match.group(1), match.end()


def _parse_records(
    path: Path, records: NDArray[np.uint16], resolution: float
) -> tuple[BtTree, int]:
    """Decode the depth first node records; return the leaves and the tree's node count.

    Record ``k``'s inner children follow it in the stream, each with its subtree. With ``c_k``
    inner children per record, ``open_k = 1 + sum_{i<k} (c_i - 1)`` nodes are announced but not
    yet read when record ``k`` starts; the tree ends at the first ``open == 0``. ``open`` falls by
    at most one per record, so the subtree of record ``j`` ends at the first later record with
    ``open == open_j - 1``: that is where ``j``'s next sibling starts. With "first child = next
    record" and "next sibling = end of my subtree" the tree is walked level by level.
    """
    inner_count = _INNER_COUNT[records].astype(np.int64)
    pending = np.empty(records.shape[0] + 1, dtype=np.int64)
    pending[0] = 1
    np.cumsum(inner_count - 1, out=pending[1:])
    pending[1:] += 1
    done = np.flatnonzero(pending == 0)
    if done.size == 0:
        raise InputError(
            path,
            f"the data ends before the tree does ({records.shape[0]} complete node records; "
            "truncated file?)",
        )
    n_records = int(done[0])
    pending = pending[: n_records + 1]
    records = records[:n_records]

    # subtree_end[j]: first k > j with pending[k] == pending[j] - 1 (sort by (pending, index)).
    order = np.argsort(pending, kind="stable")
    sorted_keys = pending[order] * (n_records + 1) + order
    query = (pending[:n_records] - 1) * (n_records + 1) + np.arange(1, n_records + 1)
    subtree_end = order[np.searchsorted(sorted_keys, query)]

    shifts = np.arange(0, 16, 2, dtype=np.uint16)
    leaf_keys: list[NDArray[np.uint32]] = []
    leaf_depth: list[NDArray[np.uint8]] = []
    leaf_occupied: list[NDArray[np.bool_]] = []
    nodes = np.zeros(1, dtype=np.int64)  # record index of each inner node at this depth
    corners = np.zeros((1, 3), dtype=np.uint32)  # their lowest keys
    visited = 0
    for depth in range(TREE_DEPTH + 1):
        if nodes.size == 0:
            break
        if depth == TREE_DEPTH:
            raise InputError(path, "corrupt data: a voxel (depth 16) has children")
        visited += nodes.size
        codes = ((records[nodes][:, None] >> shifts) & 3).astype(np.uint8)
        step = np.uint32(1 << (TREE_DEPTH - 1 - depth))
        parent, child = np.nonzero((codes == _FREE) | (codes == _OCCUPIED))
        leaf_keys.append(corners[parent] + _CHILD_OFFSETS[child] * step)
        leaf_depth.append(np.full(parent.size, depth + 1, dtype=np.uint8))
        leaf_occupied.append(codes[parent, child] == _OCCUPIED)

        parent, child = np.nonzero(codes == _INNER)  # grouped by parent, children in order
        rank = np.arange(parent.size) - np.searchsorted(parent, parent)
        next_nodes = nodes[parent] + 1
        for k in range(1, 8):
            later = rank >= k
            if not later.any():
                break
            next_nodes[later] = subtree_end[next_nodes[later]]
        nodes = next_nodes
        corners = corners[parent] + _CHILD_OFFSETS[child] * step
    if visited != n_records:  # cannot happen for any byte string; guards the algebra above
        raise InputError(path, "corrupt data: the node records do not form one tree")

    keys = np.concatenate(leaf_keys).astype(np.uint16)
    depth_arr = np.concatenate(leaf_depth)
    occupied = np.concatenate(leaf_occupied)
    order = np.argsort(_morton(keys), kind="stable")
    tree = BtTree(resolution, keys[order], depth_arr[order], occupied[order])
    return tree, n_records + len(tree)


# -- writing -------------------------------------------------------------------------------------


def write_bt(
    path: Path, *, resolution: float, keys: NDArray[np.uint16], occupied: NDArray[np.bool_]
) -> None:
    """Write :func:`bt_bytes` to ``path`` (a temporary name in the same folder, then renamed)."""
    atomic_write(Path(path), bt_bytes(resolution=resolution, keys=keys, occupied=occupied))


def bt_bytes(*, resolution: float, keys: NDArray[np.uint16], occupied: NDArray[np.bool_]) -> bytes:
    """Voxels as the ``.bt`` file OctoMap's ``OcTree::writeBinary`` writes for them.

    ``writeBinary`` first sets every node to its maximum-likelihood state and prunes: eight
    sibling leaves that all exist and share a state become one leaf, level by level up to (not
    including) the root. So does this function, and for the same voxel states the bytes are the
    same as OctoMap's (see the tests). The one header difference: OctoMap prints ``res`` with six
    significant digits, which for resolutions like 0.123456789 changes the map's scale on reading;
    such resolutions are written with all the digits needed to read them back exactly.

    Only voxel states are given, so the tree is pruned completely. OctoMap's ``prune()`` stops at
    the first level where nothing merges; starting from unpruned voxels that changes nothing (no
    merge at one level leaves no leaves to merge above it), and trees that OctoMap built
    (``insertPointCloud``, ``updateNode``, which prune as they go) or read from a file gave the
    same bytes in every test. The exception: a tree that holds pruned leaves with different
    log-odds but the same state, e.g. eight sibling 2x2x2 blocks each set to its own positive
    log-odds with ``updateNode``; there OctoMap's file keeps the eight leaves (its depth-15 pass
    merges nothing, so it stops), ours has one 4x4x4 leaf. Both hold the same voxel states.

    Parameters
    ----------
    resolution : float
        Voxel side in metres, > 0.
    keys : uint16 array (M, 3)
        Distinct OctoMap keys of the known voxels.
    occupied : bool array (M,)
        Their states.
    """
    keys = np.asarray(keys)
    occupied = np.asarray(occupied)
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be a positive number, got {resolution}")
    if keys.ndim != 2 or keys.shape[1] != 3 or keys.dtype != np.uint16:
        raise ValueError(f"keys must be a uint16 array (M, 3), got {keys.dtype} {keys.shape}")
    if occupied.shape != (keys.shape[0],) or occupied.dtype != np.bool_:
        raise ValueError(
            f"occupied must be a bool array ({keys.shape[0]},), got {occupied.dtype} "
            f"{occupied.shape}"
        )
    size, data = _encode(keys, occupied)
    res_text = f"{resolution:g}"
    if float(res_text) != resolution:
        res_text = repr(float(resolution))
    header = (
        BINARY_HEADER
        + b"\n"
        + _COMMENT
        + f"id OcTree\nsize {size}\nres {res_text}\ndata\n".encode()
    )
    return header + data


def _encode(keys: NDArray[np.uint16], occupied: NDArray[np.bool_]) -> tuple[int, bytes]:
    """Prune the voxels and serialise the tree; return ``(node count, data bytes)``: one
    compiled depth-first pass over the voxels in Morton order (:mod:`scan2terrain.octree._bt`),
    each voxel's state in the lowest bit of its sort key."""
    from scan2terrain.octree._bt import repeats, serialise, sort_keys

    if keys.shape[0] == 0:
        return 0, b""  # OctoMap has no root then and writes no data
    packed = sort_keys(np.ascontiguousarray(keys, dtype=np.uint16), occupied.astype(np.bool_))
    packed.sort()
    if repeats(packed):
        raise ValueError("keys must be distinct voxels")
    data, nodes = serialise(packed)
    return int(nodes), data.tobytes()


def _morton(keys: NDArray[np.uint16]) -> NDArray[np.uint64]:
    """Interleave the key bits (x lowest): the depth first order of OctoMap's children."""
    from scan2terrain.octree._bt import sort_keys

    k = np.ascontiguousarray(keys, dtype=np.uint16)
    codes: NDArray[np.uint64] = sort_keys(k, np.zeros(len(k), dtype=np.bool_)) >> np.uint64(1)
    return codes
