"""Issue 28, hostile files round 2: numbers that must make sense against the file and the format.

MCAP record lengths against their chunk and the file, PNG palettes and bit depths, map YAML
resolutions and origins, PLY headers and list rows, rosbag2 metadata. Each input here was read
as valid (a world written from what was left), failed with exit 1, or said more than one line;
each is refused now through the real command with exit 2, exactly one stderr line
``scan2terrain: error: <path>: ...`` naming the field and the value, and nothing written.

The commands run once for the module through :func:`tests.mutation_runner.run_cases` (forked
children, stderr captured at file descriptor 2, so lines C libraries print count too).
"""

from __future__ import annotations

import random
import shutil
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from tests.fixtures import BAGS, EMBARK_MCAP
from tests.mutation_runner import Case, Outcome, one_line, run_cases

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

LIMIT_BYTES = 3 << 30
TIMEOUT_S = 60
WORLD = ["--simulator", "gz", "--no-preview"]


Inputs = dict[str, tuple[Path, list[str], dict[str, int]]]

# --- MCAP ---------------------------------------------------------------------------------------


def mcap_records(
    data: bytes, start: int = 8, stop: int | None = None
) -> list[tuple[int, int, int]]:
    """``(offset, opcode, length)`` of each record in ``data[start:stop]``."""
    out, pos, stop = [], start, len(data) - 8 if stop is None else stop
    while pos + 9 <= stop:
        op, length = struct.unpack_from("<BQ", data, pos)
        out.append((pos, op, length))
        if op == 0x02:  # the footer
            break
        pos += 9 + length
    return out


def chunk_layout(data: bytes, at: int) -> tuple[int, int, int, str]:
    """The chunk record at ``at``: (offset of its uncompressed size field, offset of its records,
    their compressed length, compression)."""
    (n,) = struct.unpack_from("<I", data, at + 9 + 28)
    compression = data[at + 9 + 32 : at + 9 + 32 + n].decode()
    (length,) = struct.unpack_from("<Q", data, at + 9 + 32 + n)
    return at + 9 + 16, at + 9 + 32 + n + 8, length, compression


def first_chunk(data: bytes) -> int:
    return next(pos for pos, op, _ in mcap_records(data) if op == 0x06)


def _room_rosbag2(folder: Path) -> tuple[Path, Path]:
    """The synthetic room as a rosbag2 MCAP folder (rosbags' writer: uncompressed chunks,
    profile ros2): (the folder, its .mcap)."""
    from tests.seeds import room

    path = folder / "room"
    room("tf").write(path, "mcap")
    return path, next(path.glob("*.mcap"))


def _room_ros1_mcap(folder: Path, compression: str) -> Path:
    """The synthetic room as a ROS1 MCAP file (profile ros1, read by scan2terrain's reader)."""
    from tests.bagmaker import ros1_bag_to_mcap
    from tests.seeds import room

    bag = folder / "room.tmp.bag"
    room("tf").write(bag, "ros1")
    path = folder / f"room-{compression}.mcap"
    ros1_bag_to_mcap(bag, path, compression=compression)  # type: ignore[arg-type]
    bag.unlink()
    return path


def _overrun_inner_record(mcap: Path, *, opcode: int = 0x05) -> tuple[int, int]:
    """In the first (uncompressed) chunk of ``mcap``, the last scan's message record made to
    claim bytes past the chunk's end, as record ``opcode`` (one MCAP readers skip when it is
    unknown, 0x80): (chunk offset, the length). Scans before it are whole."""
    data = bytearray(mcap.read_bytes())
    at = first_chunk(bytes(data))
    _, records, length, compression = chunk_layout(bytes(data), at)
    assert compression == ""
    inner = mcap_records(bytes(data), records, records + length)
    assert inner[-1][0] + 9 + inner[-1][2] == records + length
    longest = max(n for _, op, n in inner if op == 0x05)  # the scans
    scans = [pos for pos, op, n in inner if op == 0x05 and n == longest]
    assert len(scans) > 2
    pos = scans[-1]
    claim = records + length - pos - 9 + 1000
    struct.pack_into("<BQ", data, pos, opcode, claim)
    struct.pack_into("<I", data, at + 9 + 24, 0)  # no CRC (as MCAP allows): the length is at fault
    mcap.write_bytes(bytes(data))
    return at, claim


def _set_chunk_field(mcap: Path, field: str, value: int) -> int:
    """The first chunk record's ``length`` (the record's) or ``size`` (its uncompressed size)
    set to ``value``; its offset."""
    data = bytearray(mcap.read_bytes())
    at = first_chunk(bytes(data))
    size_at, *_ = chunk_layout(bytes(data), at)
    struct.pack_into("<Q", data, at + 1 if field == "length" else size_at, value)
    mcap.write_bytes(bytes(data))
    return at


def mcap_inputs(tmp: Path) -> Inputs:
    """name -> (the input, its command, what the refusal must name)."""
    out: Inputs = {}
    for name in ("inner", "past-file", "size"):
        folder, mcap = _room_rosbag2(tmp / f"ros2-{name}")
        if name == "inner":  # an unknown record: skipped, the scans before it were kept
            at, claim = _overrun_inner_record(mcap, opcode=0x80)
        elif name == "past-file":
            claim = 1 << 40
            at = _set_chunk_field(mcap, "length", claim)
        else:
            claim = 6000
            at = _set_chunk_field(mcap, "size", claim)
        out[f"mcap-ros2-{name}"] = (
            folder,
            ["convert", "{in}", "{out}.xyz"],
            {"at": at, "n": claim},
        )
    zstd = tmp / "ros2-zstd"
    shutil.copytree(EMBARK_MCAP, zstd)
    mcap = next(zstd.glob("*.mcap"))
    at = _set_chunk_field(mcap, "size", 1_000_000)
    out["mcap-ros2-zstd-size"] = (
        zstd, ["convert", "{in}", "{out}.xyz", "--topic", "/base_scan"], {"at": at, "n": 1_000_000}
    )  # fmt: skip
    plain = _room_ros1_mcap(tmp, "none")
    at, claim = _overrun_inner_record(plain)
    out["mcap-ros1-inner"] = (plain, ["convert", "{in}", "{out}.xyz"], {"at": at, "n": claim})
    packed = _room_ros1_mcap(tmp, "zstd")
    at = _set_chunk_field(packed, "size", 6000)
    out["mcap-ros1-zstd-size"] = (packed, ["convert", "{in}", "{out}.xyz"], {"at": at, "n": 6000})
    return out


# --- PNG ----------------------------------------------------------------------------------------


def png(
    width: int,
    height: int,
    depth: int,
    colour: int,
    rows: bytes,
    *,
    before: list[tuple[bytes, bytes]] = (),  # type: ignore[assignment]
    after: list[tuple[bytes, bytes]] = (),  # type: ignore[assignment]
) -> bytes:
    """A PNG of these IHDR fields and raw ``rows`` (filter bytes included), every chunk's CRC
    right: ``before`` the IDAT chunk, ``after`` it."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return b"".join(
        [
            b"\x89PNG\r\n\x1a\n",
            chunk(b"IHDR", ihdr),
            *(chunk(k, d) for k, d in before),
            chunk(b"IDAT", zlib.compress(rows)),
            *(chunk(k, d) for k, d in after),
            chunk(b"IEND", b""),
        ]
    )


def _grey_rows(width: int, height: int, row_bytes: int, fill: int = 0x11) -> bytes:
    """``height`` rows of ``row_bytes`` bytes, each after filter byte 0."""
    return (b"\0" + bytes([fill]) * row_bytes) * height


PALETTE = bytes(range(48))  # 16 entries


def png_inputs(tmp: Path) -> Inputs:
    """Palette images without their palette, bit depths PNG does not allow with the colour
    type, palettes that cannot be, and palette indices past the palette."""
    w, h = 24, 16
    files = {
        # colour type 3 without PLTE: Pillow decoded it with a palette of its own
        "png-palette-missing": png(w, h, 8, 3, _grey_rows(w, h, w)),
        "png-palette-after-idat": png(w, h, 8, 3, _grey_rows(w, h, w), after=[(b"PLTE", PALETTE)]),
        "png-palette-ragged": png(
            w, h, 8, 3, _grey_rows(w, h, w), before=[(b"PLTE", PALETTE[:-1])]
        ),
        "png-palette-index": png(w, h, 8, 3, _grey_rows(w, h, w, 200), before=[(b"PLTE", PALETTE)]),
        "png-depth-rgb4": png(w, h, 4, 2, _grey_rows(w, h, w * 3 // 2)),
        "png-depth-palette16": png(
            w, h, 16, 3, _grey_rows(w, h, w * 2), before=[(b"PLTE", PALETTE)]
        ),
        "png-depth-grey3": png(w, h, 3, 0, _grey_rows(w, h, w * 3 // 8)),
        "png-depth-ga4": png(w, h, 4, 4, _grey_rows(w, h, w)),
        "png-colour-type-5": png(w, h, 8, 5, _grey_rows(w, h, w * 2)),
    }
    out: Inputs = {}
    for name, data in files.items():
        path = tmp / f"{name}.png"
        path.write_bytes(data)
        out[name] = (
            path,
            ["image2world", "{in}", "-o", "{out}", "--resolution", "0.1", *WORLD],
            {},
        )
    yaml = tmp / "map.yaml"
    yaml.write_text(
        "image: png-palette-missing.png\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    out["png-palette-missing-map"] = (yaml, ["map2world", "{in}", "-o", "{out}", *WORLD], {})
    return out


# --- map YAML ------------------------------------------------------------------------------------

#: (key, value as written in the YAML, the float read) of each hostile map YAML.
MAP_VALUES = {
    "map-resolution-e-300": ("resolution", "1e-300", 1e-300),
    "map-resolution-denormal": ("resolution", "5e-324", 5e-324),
    "map-resolution-nano": ("resolution", "1e-9", 1e-9),
    "map-resolution-huge": ("resolution", "2e5", 2e5),
    "map-origin-x": ("origin", "[2e9, 0, 0]", 2e9),
    "map-origin-y": ("origin", "[0, -5e300, 0]", -5e300),
}


def map_yaml(folder: Path, name: str, **values: str) -> Path:
    """A map_server YAML beside a small PGM, with ``values`` in place of the usual ones."""
    import numpy as np
    from PIL import Image

    image = folder / "m.pgm"
    if not image.exists():
        grid = np.full((20, 30), 254, np.uint8)
        grid[5:8, 5:25] = 0
        Image.fromarray(grid).save(image)
    fields = {"image": "m.pgm", "resolution": "0.05", "origin": "[0, 0, 0]", "negate": "0",
              "occupied_thresh": "0.65", "free_thresh": "0.196", **values}  # fmt: skip
    path = folder / f"{name}.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
    return path


def map_inputs(tmp: Path) -> Inputs:
    return {
        name: (map_yaml(tmp, name, **{key: text}), ["map2world", "{in}", "-o", "{out}", *WORLD], {})
        for name, (key, text, _) in MAP_VALUES.items()
    }


# --- PLY ----------------------------------------------------------------------------------------


def _ply_points(n: int = 150) -> NDArray[np.float32]:
    import numpy as np

    return np.random.default_rng(3).uniform(-5, 5, (n, 3)).astype(np.float32)


def ply_list(fmt: str, *, count: str = "uchar", counts: list[int] | None = None) -> bytes:
    """150 vertices x y z and a list ``extra`` of ``counts[k]`` (else k % 3) floats 1.5."""
    pts = _ply_points()
    counts = [k % 3 for k in range(len(pts))] if counts is None else counts
    head = (
        f"ply\nformat {fmt} 1.0\nelement vertex {len(pts)}\nproperty float x\n"
        f"property float y\nproperty float z\nproperty list {count} float extra\nend_header\n"
    )
    if fmt == "ascii":
        rows = "".join(
            f"{x:.4f} {y:.4f} {z:.4f} {c}{' 1.5' * max(c, 0)}\n"
            for c, (x, y, z) in zip(counts, pts, strict=True)
        )
        return (head + rows).encode()
    code = {"uchar": "B", "char": "b", "int": "i"}[count]
    body = b"".join(
        struct.pack(f"<3f{code}", *p, c) + struct.pack(f"<{max(c, 0)}f", *[1.5] * max(c, 0))
        for c, p in zip(counts, pts, strict=True)
    )
    return head.encode() + body


def ply_face_first(fmt: str, face_count: int) -> bytes:
    """A face element (a list of ``face_count`` ints that should be 3) before the vertices."""
    pts = _ply_points()
    head = (
        f"ply\nformat {fmt} 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
        f"element vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n"
    )
    if fmt == "ascii":
        rows = "".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in pts)
        return (head + f"{face_count} 0 1 2\n" + rows).encode()
    return head.encode() + struct.pack("<B3i", face_count, 0, 1, 2) + pts.tobytes()


def ply_fixed(*, header_extra: str = "", x0: float | None = None) -> bytes:
    """150 vertices x y z as binary floats (doubles), the first x replaced by ``x0``."""
    pts = _ply_points().astype("<f8")
    if x0 is not None:
        pts[3, 0] = x0
    head = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 150\nproperty double x\n"
        f"property double y\nproperty double z\n{header_extra}end_header\n"
    )
    return head.encode() + pts.tobytes()


def _with_byte(data: bytes, at: int, value: int) -> bytes:
    out = bytearray(data)
    out[at] = value
    return bytes(out)


#: name -> (the file's bytes, words its refusal must hold).
PLY_CASES: dict[str, tuple[Callable[[], bytes], tuple[str, ...]]] = {
    "ply-dup-x": (
        lambda: ply_fixed().replace(b"property double x\n", b"property double x\n" * 2),
        ("element vertex declares property 'x' twice",),
    ),
    "ply-dup-x-list": (
        lambda: ply_list("ascii").replace(b"property float x\n", b"property float x\n" * 2),
        ("element vertex declares property 'x' twice",),
    ),
    "ply-dup-element": (
        lambda: ply_fixed(header_extra="element vertex 0\nproperty float x\n"),
        ("declares element 'vertex' twice",),
    ),
    "ply-header-control": (
        lambda: ply_fixed().replace(b"property double z\n", b"property double z\x1c\n"),
        ("PLY header", "control character 0x1c"),
    ),
    "ply-list-bin-count-last": (
        lambda: _with_byte(ply_list("binary_little_endian"), -9, 250),  # the last row's count
        ("row 149 of element vertex", "list 'extra' holds 250 values, past the end"),
    ),
    "ply-list-bin-negative": (
        lambda: ply_list("binary_little_endian", count="char", counts=[1] * 7 + [-5] + [1] * 142),
        ("row 7 of element vertex", "list 'extra' has a count of -5"),
    ),
    "ply-list-bin-count-small": (
        lambda: ply_list("binary_little_endian", counts=[2] * 150)[:-4],
        ("element vertex",),
    ),
    "ply-list-bin-trunc": (
        lambda: ply_list("binary_little_endian")[:-3],
        ("row 149 of element vertex", "list 'extra' holds 2 values, past the end"),
    ),
    "ply-list-ascii-trunc": (
        lambda: ply_list("ascii")[:-5],
        ("row 149 of element vertex", "list 'extra' holds 2 values, past the end"),
    ),
    "ply-list-ascii-count-big": (
        lambda: ply_list("ascii").replace(b" 2 1.5 1.5\n", b" 9 1.5 1.5\n", 1),
        ("element vertex",),
    ),
    "ply-list-ascii-count-word": (
        lambda: ply_list("ascii").replace(b" 2 1.5 1.5\n", b" 2.5 1.5 1.5\n", 1),
        ("row 2 of element vertex", "list 'extra' count '2.5' is not an integer"),
    ),
    "ply-list-ascii-count-range": (
        lambda: ply_list("ascii").replace(b" 1 1.5\n", b" 300 1.5\n", 1),
        ("row 1 of element vertex", "list 'extra' count 300 is beyond its type uchar"),
    ),
    "ply-face-first-bin": (
        lambda: ply_face_first("binary_little_endian", 200),
        ("element vertex",),
    ),
    "ply-face-first-ascii": (lambda: ply_face_first("ascii", 9), ("element vertex",)),
    "ply-coordinate-huge": (
        lambda: ply_fixed(x0=1e300),
        ("vertex 3: x = 1e+300 m makes no sense",),
    ),
}


def ply_inputs(tmp: Path) -> Inputs:
    out: Inputs = {}
    for name, (data, _) in PLY_CASES.items():
        path = tmp / f"{name}.ply"
        path.write_bytes(data())
        out[name] = (path, ["convert", "{in}", "{out}.xyz"], {})
        out[f"{name}-world"] = (path, ["cloud2world", "{in}", "-o", "{out}", "--resolution", "0.2",
                                       *WORLD], {})  # fmt: skip
    return out


# --- rosbag2 metadata ---------------------------------------------------------------------------

#: name -> (metadata.yaml's bytes from the good one's, words the refusal must hold).
META_CASES: dict[str, tuple[Callable[[bytes], bytes], str]] = {
    "meta-binary": (
        lambda good: random.Random(28).randbytes(600),
        "is not UTF-8 text",
    ),
    "meta-nul": (lambda good: good[:100] + b"\0\0\0" + good[103:], "malformed YAML at line"),
    "meta-list": (lambda good: b"- 1\n- 2\n", "no 'rosbag2_bagfile_information' mapping"),
    "meta-dup-key": (
        lambda good: good.replace(b"  version: ", b"  storage_identifier: sqlite3\n  version: ", 1),
        "found duplicate key 'storage_identifier'",  # ruamel's words, as rosbags reads it
    ),
    "meta-no-duration": (
        lambda good: good.replace(b"  duration:", b"  lasted:", 1),
        "rosbag2_bagfile_information has no 'duration'",
    ),
}


def meta_inputs(tmp: Path) -> Inputs:
    """The db3 and MCAP rosbag2 folders with a damaged metadata.yaml each: the file named."""
    out: Inputs = {}
    for fixture in ("bag2_derived_sick_lms1xx_db3", "bag2_derived_embark_luminar_mcap"):
        good = (BAGS / fixture / "metadata.yaml").read_bytes()
        for name, (damage, _) in META_CASES.items():
            folder = tmp / f"{fixture}-{name}"
            folder.mkdir()
            for f in (BAGS / fixture).iterdir():
                if f.suffix in (".db3", ".mcap"):
                    (folder / f.name).symlink_to(f)
            (folder / "metadata.yaml").write_bytes(damage(good))
            kind = "db3" if "db3" in fixture else "mcap"
            for command in (["inspect", str(folder)], ["convert", str(folder), "{out}.xyz"]):
                case = f"{name}-{kind}-{command[0]}"
                out[case] = (folder / "metadata.yaml", command, {})
    return out


# --- poses and names ---------------------------------------------------------------------------

FAR = 3.5e76  # a tf translation seen after one flipped byte: points written at 3.5e76 m


def _room_with(variant: str, change: Callable[[list[Any]], list[Any]]) -> Any:
    """The fuzz's synthetic room with its messages changed by ``change``."""
    import copy
    import dataclasses

    from tests.seeds import room

    r = room(variant)  # cached: changed in a copy
    return dataclasses.replace(r, messages=change(copy.deepcopy(r.messages)))


def _far_tf(messages: list[Any]) -> list[Any]:
    """The third /tf message's first transform moved FAR along x."""
    tf = [i for i, m in enumerate(messages) if m[0] == "/tf"]
    topic, kind, t, msg = messages[tf[2]]
    msg["transforms"][0]["transform"]["translation"]["x"] = FAR
    messages[tf[2]] = (topic, kind, t, msg)
    return messages


def _far_odom(messages: list[Any]) -> list[Any]:
    odom = [i for i, m in enumerate(messages) if m[0] == "/odom"]
    messages[odom[2]][3]["pose"]["pose"]["position"]["y"] = -FAR
    return messages


def _named(messages: list[Any]) -> list[Any]:
    """Topics whose names hold a newline and a group separator (Python's splitlines breaks at
    both; a terminal shows neither)."""
    return [(f"{m[0]}\x1d\nx", *m[1:]) for m in messages]


def pose_inputs(tmp: Path) -> Inputs:
    """A tf or odometry pose far beyond the Earth; names with control characters."""
    from tests.bagmaker import ros1_bag_to_mcap

    out: Inputs = {}
    odom = tmp / "far-odom"
    _room_with("odom", _far_odom).write(odom, "sqlite3")
    out["odom-far"] = (odom, ["convert", "{in}", "{out}.xyz"], {})
    room = tmp / "room"
    _room_with("tf", list).write(room, "mcap")
    tum = tmp / "far.tum"
    tum.write_text(f"1700000000 0 0 0 0 0 0 1\n1700000001 {FAR} 0 0 0 0 0 1\n")
    out["tum-far"] = (tum, ["convert", str(room), "{out}.xyz", "--poses", "trajectory",
                            "--trajectory", "{in}"], {})  # fmt: skip
    bag = tmp / "named.bag"
    _room_with("tf", _named).write(bag, "ros1")
    named = tmp / "named.mcap"
    ros1_bag_to_mcap(bag, named, compression="none")
    out["topic-controls"] = (named, ["convert", "{in}", "{out}.xyz", "--topic", "/none"], {})
    return out


# --- the commands, run once -----------------------------------------------------------------------

BUILDERS: list[Callable[[Path], Inputs]] = [
    mcap_inputs,
    png_inputs,
    map_inputs,
    ply_inputs,
    meta_inputs,
    pose_inputs,
]


@pytest.fixture(scope="module")
def commands(
    tmp_path_factory: pytest.TempPathFactory,
) -> dict[str, tuple[Path, Outcome, dict[str, int]]]:
    """name -> (the hostile input, how its command ended, what it must name)."""
    tmp = tmp_path_factory.mktemp("sanity")
    inputs: Inputs = {}
    for build in BUILDERS:
        folder = tmp / build.__name__
        folder.mkdir()
        inputs.update(build(folder))
    cases = []
    for name, (src, argv, _) in inputs.items():
        out = tmp / "out" / name
        out.mkdir(parents=True)
        filled = [a.replace("{in}", str(src)).replace("{out}", str(out / "o")) for a in argv]
        cases.append(Case(name, filled, str(out)))
    results = run_cases(
        cases, limit_bytes=LIMIT_BYTES, timeout_s=TIMEOUT_S, workdir=tmp / "_runner"
    )
    return {
        c.name: (inputs[c.name][0], o, inputs[c.name][2])
        for c, o in zip(cases, results, strict=True)
    }


# --- 1. MCAP: every record inside its chunk, every chunk inside the file --------------------------


@pytest.mark.parametrize(
    "case",
    ["mcap-ros2-inner", "mcap-ros2-past-file", "mcap-ros1-inner"],
)
def test_an_mcap_record_running_past_its_chunk_or_the_file_is_refused(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str
) -> None:
    """Seen (mcap-ros2-inner): the messages before the record were read, a world written."""
    src, o, named = commands[case]
    line = one_line(o, src)
    assert f"the chunk at byte {named['at']}" in line, line
    assert f"{named['n']:,} bytes" in line, line


@pytest.mark.parametrize("case", ["mcap-ros2-size", "mcap-ros2-zstd-size", "mcap-ros1-zstd-size"])
def test_an_mcap_chunk_whose_size_disagrees_with_its_data_is_refused(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str
) -> None:
    """Seen (ros2): rosbags took the sizes of the chunk index and read the chunk as valid."""
    src, o, named = commands[case]
    line = one_line(o, src)
    assert f"the chunk at byte {named['at']}" in line, line
    assert f"{named['n']:,}" in line, line


# --- 2. PNG: a palette image needs its palette, a bit depth its colour type -----------------------


@pytest.mark.parametrize(
    ("case", "named"),
    [
        ("png-palette-missing", "colour type 3 (palette) without a PLTE chunk"),
        (
            "png-palette-after-idat",
            "colour type 3 (palette) without a PLTE chunk before its image data",
        ),
        ("png-palette-ragged", "PLTE chunk of 47 bytes"),
        ("png-palette-index", "index 200 past its 16 palette entries"),
        ("png-depth-rgb4", "bit depth 4 with colour type 2 (RGB)"),
        ("png-depth-palette16", "bit depth 16 with colour type 3 (palette)"),
        ("png-depth-grey3", "bit depth 3 with colour type 0 (grey)"),
        ("png-depth-ga4", "bit depth 4 with colour type 4 (grey and alpha)"),
        ("png-colour-type-5", "colour type 5"),
        ("png-palette-missing-map", "colour type 3 (palette) without a PLTE chunk"),
    ],
)
def test_a_png_against_the_format_s_rules_is_refused(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str, named: str
) -> None:
    """Seen (png-palette-missing): read as valid, Pillow making up a palette."""
    src, o, _ = commands[case]
    if case.endswith("-map"):  # the map's image is named, not its YAML
        src = src.parent / "png-palette-missing.png"
    line = one_line(o, src)
    assert named in line, line


@pytest.mark.parametrize("colours", [2, 4, 16, 200])
def test_palette_pngs_as_pillow_writes_them_are_read(tmp_path: Path, colours: int) -> None:
    """Pillow writes 1, 2, 4 or 8 bits a pixel and a palette of the colours used."""
    import numpy as np
    from PIL import Image

    from scan2terrain.readers.image import read_grey_image

    index = (np.arange(24 * 16).reshape(16, 24) % colours).astype(np.uint8)
    img = Image.fromarray(index, mode="P")
    img.putpalette([v for k in range(colours) for v in (k, 255 - k, k // 2)])
    path = tmp_path / "p.png"
    img.save(path, bits=max(1, (colours - 1).bit_length()))
    assert path.read_bytes()[25] == 3  # colour type 3: a palette image
    grey = read_grey_image(path)
    assert grey.values.shape == (16, 24) and int(grey.values.max()) > 0


# --- 3. map YAML: a resolution and an origin a map can have ---------------------------------------


@pytest.mark.parametrize("case", list(MAP_VALUES))
def test_a_map_yaml_resolution_or_origin_beyond_the_physical_limits_is_refused(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str
) -> None:
    """Seen: 1e-300 and 5e-324 m cells were exit 1 ("need at least one array to
    concatenate"), 1e-9 and 2e5 m cells wrote worlds."""
    src, o, _ = commands[case]
    key, _, value = MAP_VALUES[case]
    line = one_line(o, src)
    field = "resolution" if key == "resolution" else f"origin {'x' if 'x' in case else 'y'}"
    assert f": {field} = {value:.6g} m makes no sense" in line, line


@pytest.mark.parametrize(
    ("key", "text"),
    [("resolution", "1e-6"), ("resolution", "1.2e5"), ("origin", "[1e9, -1e9, 0]")],
)
def test_map_yaml_values_at_the_limits_are_read(tmp_path: Path, key: str, text: str) -> None:
    from scan2terrain.readers.mapserver import read_map_metadata

    meta = read_map_metadata(map_yaml(tmp_path, "m", **{key: text}))
    if key == "resolution":
        assert meta.resolution == float(text)
    else:
        assert (meta.origin.x, meta.origin.y) == (1e9, -1e9)


# --- 4. PLY: one line for every damaged header and list -------------------------------------------


@pytest.mark.parametrize("world", [False, True], ids=["convert", "cloud2world"])
@pytest.mark.parametrize("case", list(PLY_CASES))
def test_a_damaged_ply_is_refused_in_one_line(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str, world: bool
) -> None:
    """Seen: x declared twice ran over 30 s; wrong list counts, truncated lists and a face
    element before the vertices said two lines (a warning, then the error) or wrote a world
    from misread rows."""
    src, o, _ = commands[f"{case}-world" if world else case]
    line = one_line(o, src)
    for words in PLY_CASES[case][1]:
        assert words in line, line
    assert o.seconds < 20, o.describe()


@pytest.mark.parametrize(
    "data",
    [
        lambda: ply_list("ascii"),
        lambda: ply_list("binary_little_endian"),
        lambda: ply_list("binary_little_endian", count="int"),
        lambda: ply_list("ascii", count="char"),
        lambda: ply_face_first("ascii", 3),
        lambda: ply_face_first("binary_little_endian", 3),
        lambda: ply_list("binary_little_endian") + b"\n",
    ],
)
def test_plys_with_lists_are_read(tmp_path: Path, data: Callable[[], bytes]) -> None:
    import numpy as np

    from scan2terrain.readers.cloudfile import read_cloud

    path = tmp_path / "l.ply"
    path.write_bytes(data())
    got = read_cloud(path)
    np.testing.assert_allclose(got.points, _ply_points(), atol=1e-4)


# --- 5. rosbag2: a metadata.yaml that is not one ------------------------------------------------


@pytest.mark.parametrize("command", ["inspect", "convert"])
@pytest.mark.parametrize("kind", ["db3", "mcap"])
@pytest.mark.parametrize("case", list(META_CASES))
def test_a_rosbag2_metadata_file_that_is_not_one_is_named(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str, kind: str, command: str
) -> None:
    """Seen (binary): two lines; and the folder named, its storage file blamed."""
    src, o, _ = commands[f"{case}-{kind}-{command}"]
    line = one_line(o, src)
    assert META_CASES[case][1] in line, line


# --- 6. poses within reach of the Earth; names from files shown, not obeyed -----------------------


def test_a_tf_sample_beyond_the_earth_is_dropped_like_a_nan(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Seen (mcap/flip1@14): convert wrote points at 3.5e76 m."""
    import numpy as np

    from scan2terrain.cli import main

    _room_with("tf", _far_tf).write(tmp_path / "room", "mcap")
    assert main(["convert", str(tmp_path / "room"), str(tmp_path / "o.xyz")]) == 0
    assert "tf: 1 sample(s) ignored: translation beyond 1e+09 m" in capsys.readouterr().out
    xyz = np.loadtxt(tmp_path / "o.xyz")
    assert len(xyz) > 100
    assert np.abs(xyz).max() < 20, np.abs(xyz).max()


@pytest.mark.parametrize(("case", "named"), [
    ("odom-far", f"odometry: translations must be within 1e+09 m, not {-FAR:g} (row 3, y)"),
    ("tum-far", f"line 2: x {FAR:g} is beyond 1e+09 m"),
])  # fmt: skip
def test_a_trajectory_pose_beyond_the_earth_is_refused(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]], case: str, named: str
) -> None:
    src, o, _ = commands[case]
    line = one_line(o, src)
    assert named in line, line


def test_names_from_a_file_are_shown_escaped_on_one_line(
    commands: dict[str, tuple[Path, Outcome, dict[str, int]]],
) -> None:
    """Seen (mcap-ros1/flip1@2): a topic name with a newline made the error two lines."""
    src, o, _ = commands["topic-controls"]
    line = one_line(o, src)
    assert "/scan\\x1d\\nx" in line, line
