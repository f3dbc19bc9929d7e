"""What anything scan2terrain writes must look like, whatever it was made from (issue 28).

:func:`output_problems` is the mutation fuzz's oracle for a run that exited 0: a damaged input
that is read must still give a world (or a cloud) that makes sense. It looks at every file a
command wrote and returns what is wrong (empty: nothing):

- every number in the SDF, world, model.config and COLLADA files (element text and attributes;
  comments describe the input and are not read), in the YAML files, in the OBJ, STL and TUM
  files and in a converted cloud (.xyz, .ply) is finite; the XML and YAML parse;
- SDF geometry stays within the limits of :mod:`scan2terrain.readers._limits`: a ``<pose>``,
  ``<pos>`` or polyline ``<point>`` within ``MAX_COORDINATE_M`` in x and y and its z within
  ``MAX_ELEVATION_M`` (plus ``SLACK_M`` for floors, wall tops and spawn heights); every
  ``<size>``, ``<scale>``, ``<radius>``, ``<length>`` and polyline ``<height>`` above 0, sizes at
  least ``MIN_SPACING_M`` and at most twice those limits; OBJ/STL/COLLADA vertices, spawn poses
  and map YAML origins likewise, a map YAML's resolution within ``MIN_SPACING_M ..
  MAX_SPACING_M``; a cloud's points within ``MAX_COORDINATE_M`` on every axis (a cloud may be
  geocentric, so its z is not an elevation);
- heightmap images (every ``<heightmap><uri>``) are square, ``2^n + 1`` pixels a side, and the
  brightest pixel over a world's heightmaps is full scale (255 or 65535 by the PNG's bit
  depth), or every pixel is 0 (a flat field: ``exporters/heightmap.quantise``); a terrain cut
  into tiles is one world, so its brightest tile is the one at full scale.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

import numpy as np

from scan2terrain.readers._limits import (
    MAX_COORDINATE_M,
    MAX_ELEVATION_M,
    MAX_SPACING_M,
    MIN_SPACING_M,
)

#: What a world's z may exceed the elevation limit by: the floor box under a terrain, wall
#: tops, spawn heights above the ground (metres).
SLACK_M = 100.0
#: The largest z in a world, and the largest span (size) along z.
MAX_Z = MAX_ELEVATION_M + SLACK_M
MAX_SIZE_XY, MAX_SIZE_Z = 2 * MAX_COORDINATE_M, 2 * MAX_ELEVATION_M + SLACK_M
#: At most this many problems are reported per output.
MAX_REPORTED = 8


def output_problems(out: Path) -> list[str]:
    """What is wrong with the files a command wrote at ``out`` (a world folder or a cloud
    file; nothing there: nothing to check)."""
    if out.is_file():
        found = _cloud(out)
    elif out.is_dir():
        found = []
        for path in sorted(p for p in out.rglob("*") if p.is_file()):
            try:
                found += [f"{path.relative_to(out)}: {p}" for p in _file(path)]
            except Exception as exc:  # a file the checks cannot read is itself a problem
                found.append(f"{path.relative_to(out)}: unreadable: {type(exc).__name__}: {exc}")
        try:
            found += _heightmaps(out)
        except Exception as exc:  # reported above when a world file is unreadable
            found.append(f"heightmaps unreadable: {type(exc).__name__}: {exc}")
    else:
        found = []
    if len(found) > MAX_REPORTED:
        found = [*found[:MAX_REPORTED], f"... and {len(found) - MAX_REPORTED} more"]
    return found


def _file(path: Path) -> list[str]:
    suffix = path.suffix.lower()
    if suffix in (".sdf", ".world"):
        return _sdf(path)
    if suffix in (".config", ".dae"):
        return _xml_numbers(_parse_xml(path), dae=suffix == ".dae")
    if suffix == ".yaml":
        return _yaml(path)
    if suffix == ".obj":
        return _obj(path)
    if suffix == ".stl":
        return _stl(path)
    if suffix == ".tum":  # t x y z qx qy qz qw, one pose a line
        table = np.loadtxt(path, ndmin=2, comments="#", dtype=np.float64)
        return [] if np.isfinite(table).all() else ["non-finite values"]
    return []


# --- XML ----------------------------------------------------------------------------------------


def _parse_xml(path: Path) -> ET.Element:
    return ET.parse(path).getroot()


def _xml_numbers(root: ET.Element, *, dae: bool = False) -> list[str]:
    """Every number in element text and attribute values is finite (comments describe the
    input and are not read by Gazebo); a COLLADA ``float_array`` (positions, normals) within
    MAX_COORDINATE_M."""
    bad: list[str] = []
    for el in root.iter():
        for text in (el.text, *el.attrib.values()):
            if text:
                bad += [t for t in text.split() if _is_non_finite(t)]
        if dae and el.tag.endswith("float_array") and el.text:
            values = np.array(el.text.split(), dtype=np.float64)
            if values.size and np.abs(values).max() > MAX_COORDINATE_M:
                bad.append(f"COLLADA values up to {np.abs(values).max():.3g}")
    return [f"non-finite or absurd numbers {bad[:3]}"] if bad else []


def _is_non_finite(token: str) -> bool:
    try:
        return not math.isfinite(float(token))
    except ValueError:
        return False


def _floats(el: ET.Element | None) -> list[float]:
    return [] if el is None or el.text is None else [float(t) for t in el.text.split()]


def _sdf(path: Path) -> list[str]:
    root = _parse_xml(path)
    found = _xml_numbers(root)
    for el in root.iter():
        tag, values = el.tag, None
        if tag in ("pose", "pos", "point", "size", "scale", "radius", "length", "height"):
            values = _floats(el)
        if not values:
            continue
        if not all(math.isfinite(v) for v in values):
            continue  # reported above
        if tag in ("pose", "pos", "point"):
            if max(abs(v) for v in values[:2]) > MAX_COORDINATE_M:
                found.append(f"<{tag}> {el.text} beyond {MAX_COORDINATE_M:g} m")
            if len(values) >= 3 and abs(values[2]) > MAX_Z:
                found.append(f"<{tag}> {el.text}: z beyond {MAX_Z:g} m")
        elif tag == "size":
            xy, z = values[:2], values[2:]
            if min(values) <= 0:
                found.append(f"<size> {el.text}: not above 0")
            elif min(xy) < MIN_SPACING_M or max(xy) > MAX_SIZE_XY:
                found.append(f"<size> {el.text}: x, y outside {MIN_SPACING_M:g}..{MAX_SIZE_XY:g}")
            elif z and z[0] > MAX_SIZE_Z:
                found.append(f"<size> {el.text}: z over {MAX_SIZE_Z:g}")
        elif min(values) <= 0 or max(values) > MAX_SIZE_XY:
            found.append(f"<{tag}> {el.text}: outside (0, {MAX_SIZE_XY:g}]")
    return found


# --- YAML ---------------------------------------------------------------------------------------


def _walk(value: Any) -> Iterator[float]:
    if isinstance(value, bool):
        return
    if isinstance(value, (int, float)):
        yield float(value)
    elif isinstance(value, dict):
        for v in value.values():
            yield from _walk(v)
    elif isinstance(value, list):
        for v in value:
            yield from _walk(v)


def _yaml(path: Path) -> list[str]:
    import yaml

    doc = yaml.safe_load(path.read_bytes())
    bad = [v for v in _walk(doc) if not math.isfinite(v)]
    found = [f"non-finite numbers {bad[:3]}"] if bad else []
    if not isinstance(doc, dict) or bad:
        return found
    if {"image", "resolution", "origin"} <= doc.keys():  # a map_server map
        res, origin = doc["resolution"], doc["origin"]
        if not MIN_SPACING_M <= res <= MAX_SPACING_M:
            found.append(f"resolution {res!r} outside {MIN_SPACING_M:g}..{MAX_SPACING_M:g} m")
        if max(abs(v) for v in origin[:2]) > MAX_COORDINATE_M:
            found.append(f"origin {origin} beyond {MAX_COORDINATE_M:g} m")
    for key, entry in doc.items():  # spawn.yaml: {simulator: {world, pose: [x, y, z, r, p, y]}}
        if isinstance(entry, dict) and isinstance(entry.get("pose"), list):
            pose = entry["pose"]
            if max(abs(v) for v in pose[:2]) > MAX_COORDINATE_M or abs(pose[2]) > MAX_Z:
                found.append(f"{key} pose {pose} beyond the limits")
    return found


# --- meshes and clouds --------------------------------------------------------------------------


def _vertices_problems(what: str, xyz: np.ndarray, *, z_limit: float = MAX_Z) -> list[str]:
    if xyz.size == 0:
        return []
    if not np.isfinite(xyz).all():
        return [f"{what}: non-finite values"]
    found = []
    if np.abs(xyz[:, :2]).max() > MAX_COORDINATE_M:
        found.append(f"{what}: x, y up to {np.abs(xyz[:, :2]).max():.3g} m")
    if np.abs(xyz[:, 2]).max() > z_limit:
        found.append(f"{what}: z up to {np.abs(xyz[:, 2]).max():.3g} m")
    return found


def _obj(path: Path) -> list[str]:
    rows: dict[bytes, list[list[bytes]]] = {b"v": [], b"vn": [], b"vt": [], b"f": []}
    for line in path.read_bytes().splitlines():
        words = line.split()
        if words and words[0] in rows:
            rows[words[0]].append(words[1:])
    found = []
    v = np.array([[float(t) for t in w[:3]] for w in rows[b"v"]], dtype=np.float64).reshape(-1, 3)
    found += _vertices_problems("v", v)
    for kind in (b"vn", b"vt"):
        values = [float(t) for w in rows[kind] for t in w]
        if not all(math.isfinite(x) for x in values):
            found.append(f"{kind.decode()}: non-finite values")
    faces = [int(t.split(b"/")[0]) for w in rows[b"f"] for t in w]
    if faces and (min(faces) < 1 or max(faces) > len(v)):
        found.append(f"f: vertex indices {min(faces)}..{max(faces)} of {len(v)} vertices")
    return found


def _stl(path: Path) -> list[str]:
    raw = path.read_bytes()
    if raw[:5] == b"solid" and b"facet" in raw[:1000]:  # ASCII STL
        v = [float(t) for line in raw.splitlines() if line.split()[:1] == [b"vertex"]
             for t in line.split()[1:4]]  # fmt: skip
        return _vertices_problems("vertex", np.array(v).reshape(-1, 3))
    (n,) = struct.unpack_from("<I", raw, 80)
    if len(raw) != 84 + 50 * n:
        return [f"binary STL of {len(raw)} bytes for {n} triangles"]
    tri = np.frombuffer(raw, dtype=np.dtype([("f", "<f4", 12), ("a", "<u2")]), offset=84)
    return _vertices_problems("triangles", tri["f"][:, 3:].reshape(-1, 3).astype(np.float64))


def _cloud(path: Path) -> list[str]:
    """A converted cloud: .xyz/.txt/.csv text or .ply; other formats are not looked at."""
    suffix = path.suffix.lower()
    if suffix == ".xyz":  # x y z [more columns], one point a line
        table = np.loadtxt(path, ndmin=2, dtype=np.float64)
        if not np.isfinite(table).all():
            return [f"{path.name}: non-finite values"]
        return _vertices_problems(path.name, table[:, :3], z_limit=MAX_COORDINATE_M)
    if suffix == ".ply":
        return _vertices_problems(path.name, _ply_xyz(path.read_bytes()), z_limit=MAX_COORDINATE_M)
    return []


PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
             "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
             "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4",
             "float64": "f8"}  # fmt: skip


def _ply_xyz(raw: bytes) -> np.ndarray:
    """x, y, z of the vertex element of a PLY as written by scan2terrain (no list properties
    in the vertex element)."""
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    fmt = lines[1].split()[1]
    props: list[tuple[str, str]] = []
    count, in_vertex = 0, False
    for line in lines:
        words = line.split()
        if words[:1] == ["element"]:
            in_vertex = words[1] == "vertex"
            count = int(words[2]) if in_vertex else count
        elif words[:1] == ["property"] and in_vertex:
            props.append((words[-1], PLY_TYPES[words[1]]))
    if fmt == "ascii":
        table = np.loadtxt(raw[end:].splitlines()[:count], ndmin=2)
        names = [n for n, _ in props]
        return table[:, [names.index(a) for a in "xyz"]].astype(np.float64)
    order = "<" if fmt == "binary_little_endian" else ">"
    dtype = np.dtype([(n, order + t) for n, t in props])
    rows = np.frombuffer(raw, dtype=dtype, count=count, offset=end)
    return np.column_stack([rows[a].astype(np.float64) for a in "xyz"])


# --- heightmaps ---------------------------------------------------------------------------------


def _heightmap_files(sdf: Path, out: Path) -> list[Path]:
    """The images a world or model file's ``<heightmap><uri>`` elements name, and those of the
    models it includes."""
    root = _parse_xml(sdf)
    found: list[Path] = []
    for el in root.iter("heightmap"):
        uri = el.findtext("uri")
        if uri:
            found.append(_resolve(uri, sdf, out))
    for inc in root.iter("include"):
        uri = inc.findtext("uri")
        if uri and uri.startswith("model://"):
            model = out / "models" / uri.removeprefix("model://").split("/")[0] / "model.sdf"
            if model.is_file():
                found += _heightmap_files(model, out)
    return sorted(set(found))


def _resolve(uri: str, sdf: Path, out: Path) -> Path:
    if uri.startswith("model://"):
        return out / "models" / uri.removeprefix("model://")
    if uri.startswith("file://"):
        return Path(uri.removeprefix("file://"))
    return sdf.parent / uri


def _heightmaps(out: Path) -> list[str]:
    """Each world's heightmap images: square, 2^n + 1 a side; the brightest pixel over them
    full scale, or all pixels 0. A model file not included by any world is a world of its
    own."""
    from PIL import Image

    worlds = [p for p in out.rglob("*") if p.suffix in (".sdf", ".world") and p.name != "model.sdf"]
    groups = [_heightmap_files(w, out) for w in worlds]
    included = {p for g in groups for p in g}
    for model in out.rglob("model.sdf"):
        own = _heightmap_files(model, out)
        if own and not set(own) & included:
            groups.append(own)
    found = []
    for group in groups:
        if not group:
            continue
        brightest, depths = 0, set()
        for png in group:
            name = png.relative_to(out) if png.is_relative_to(out) else png
            if not png.is_file():
                found.append(f"{name}: a heightmap the world names is missing")
                continue
            raw = png.read_bytes()
            depths.add(raw[24])
            with Image.open(png) as im:
                pixels = np.asarray(im)
            rows, cols = pixels.shape[:2]
            if rows != cols or rows < 3 or (rows - 1) & (rows - 2):
                found.append(f"{name}: {cols}x{rows} px, not square 2^n + 1")
            brightest = max(brightest, int(pixels.max()))
        if len(depths) == 1:
            full = (1 << depths.pop()) - 1
            if brightest not in (0, full):
                found.append(f"heightmap: brightest pixel {brightest}, not full scale {full}")
        elif depths:
            found.append(f"heightmaps of one world at bit depths {sorted(depths)}")
    return found
