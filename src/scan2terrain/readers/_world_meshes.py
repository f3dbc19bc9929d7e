"""Mesh files of a Gazebo world (STL, OBJ, COLLADA) as triangles in the mesh's own frame.

What Gazebo's physics loads for a ``<mesh>`` collision is gz-common's ``MeshManager::Load``
(gz-sim; Gazebo Classic's ``common::MeshManager`` is where it was taken from), by extension:

* STL, binary or ASCII: parsed here with numpy (the format is 50 bytes a triangle; trimesh's
  import alone costs 0.7 s, longer than reading our walls). A binary file must hold the
  triangles its header counts (a truncated one is refused, not read short); an ASCII one must
  end its solid (``endsolid``). Vertices are float32, as the file holds them.
* OBJ and COLLADA (``.dae``): trimesh (pycollada for COLLADA), every mesh of the scene with its
  node transforms, as gz-common's loaders apply them. COLLADA's ``<unit meter>`` scales the
  whole mesh, as gz-common's ``ColladaLoader::Load`` does (``mesh->Scale(meter)``; trimesh only
  records it); ``<up_axis>`` is ignored, as gz-common ignores it (trimesh too), so a Y_UP file
  lies on its side in Gazebo and here alike. Our own files (``exporters/meshfile.py``) are
  Z_UP, metres, so the STL, OBJ and DAE of a world are the same triangles. Precision: pycollada
  reads COLLADA's numbers as float32 (gz-common as float64), gz-common reads OBJ as float32
  (tinyobjloader; trimesh as float64): either way within 6e-8 of a coordinate's size.

A file that cannot be read is one :class:`MeshError` (the caller names the file): corrupt,
truncated, holding no triangles or non-finite numbers, or a COLLADA file declaring XML
entities (refused before pycollada parses it: no entity is ever expanded).
"""

from __future__ import annotations

import io
import math
import re
import struct

import numpy as np
from lxml import etree
from numpy.typing import NDArray

from scan2terrain.readers._files import raised_in

#: Mesh formats by extension, as gz-common 4's MeshManager knows them.
MESH_FORMATS = {".stl": "stl", ".obj": "obj", ".dae": "dae"}

Triangles = tuple[NDArray[np.float64], NDArray[np.int64]]


class MeshError(ValueError):
    """A mesh file cannot be read; the message says why (the caller names the file)."""


def load_mesh(data: bytes, kind: str) -> Triangles:
    """The triangles of a mesh file's bytes: vertices float64 (V, 3) in the file's units after
    COLLADA's ``<unit meter>``, faces int64 (T, 3). ``kind`` is a value of
    :data:`MESH_FORMATS`."""
    if kind == "stl":
        vertices, faces = _stl(data)
    elif kind in ("obj", "dae"):
        vertices, faces = _trimesh(data, kind)
    else:
        raise MeshError(f"unknown mesh kind {kind!r}")
    if len(faces) == 0:
        raise MeshError("holds no triangles")
    if not np.isfinite(vertices).all():
        raise MeshError("holds vertices that are not finite numbers")
    return vertices, faces


def _stl(data: bytes) -> Triangles:
    """Binary STL when the size matches the header's count, else ASCII (``solid``)."""
    if len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        need = 84 + 50 * count
        if len(data) == need or (len(data) > need and not _looks_ascii(data)):
            record = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
            body = np.frombuffer(data, dtype=record, count=count, offset=84)
            vertices = body["v"].reshape(-1, 3).astype(np.float64)
            return vertices, np.arange(3 * count, dtype=np.int64).reshape(-1, 3)
    if _looks_ascii(data):
        return _ascii_stl(data)
    if len(data) < 84:
        raise MeshError(f"not an STL file: {len(data)} bytes, shorter than a binary STL header")
    (count,) = struct.unpack_from("<I", data, 80)
    raise MeshError(
        f"truncated or corrupt binary STL: its header counts {count:,} triangles "
        f"({84 + 50 * count:,} bytes), the file has {len(data):,} bytes"
    )


def _looks_ascii(data: bytes) -> bool:
    return data[:512].lstrip()[:5].lower() == b"solid" and b"facet" in data[:4096]


_FLOAT = rb"([-+0-9.eEinfINFaA]+)"
_VERTEX = re.compile(rb"vertex\s+" + _FLOAT + rb"\s+" + _FLOAT + rb"\s+" + _FLOAT)


def _ascii_stl(data: bytes) -> Triangles:
    if b"endsolid" not in data[-4096:].lower():
        raise MeshError("truncated ASCII STL: it does not end with 'endsolid'")
    found = _VERTEX.findall(data)
    facets = len(re.findall(rb"\bendfacet\b", data))
    if len(found) != 3 * facets:
        raise MeshError(
            f"corrupt ASCII STL: {facets:,} facets but {len(found):,} vertices (3 a facet)"
        )
    try:
        vertices = np.array(found, dtype=np.float64).reshape(-1, 3)
    except ValueError as exc:
        raise MeshError(f"corrupt ASCII STL: a vertex that is not a number ({exc})") from None
    return vertices, np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)


def _trimesh(data: bytes, kind: str) -> Triangles:
    meter = _collada_meter(data) if kind == "dae" else 1.0
    import trimesh

    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=kind, process=False)
    except Exception as exc:
        if not raised_in(exc, ("trimesh", "collada", "numpy", "lxml", "xml")):
            raise
        text = " ".join(str(exc).split())[:200]
        raise MeshError(f"cannot read it ({type(exc).__name__}: {text})") from exc
    pieces: list[Triangles] = []
    if isinstance(loaded, trimesh.Trimesh):
        pieces.append((np.asarray(loaded.vertices, np.float64), np.asarray(loaded.faces)))
    elif isinstance(loaded, trimesh.Scene):
        for node in loaded.graph.nodes_geometry:
            transform, name = loaded.graph[node]
            geometry = loaded.geometry.get(name)
            if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
                v = np.asarray(geometry.vertices, np.float64)
                m = np.asarray(transform, np.float64)
                pieces.append((v @ m[:3, :3].T + m[:3, 3], np.asarray(geometry.faces)))
    if not pieces:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    offsets = np.cumsum([0] + [len(v) for v, _ in pieces[:-1]])
    vertices = np.concatenate([v for v, _ in pieces]) * meter
    faces = np.concatenate(
        [f.astype(np.int64) + o for (_, f), o in zip(pieces, offsets, strict=True)]
    )
    return vertices, faces


def _collada_meter(data: bytes) -> float:
    """COLLADA's ``<asset><unit meter>`` (1 without one), read with a parser that expands no
    entity and fetches nothing; a file declaring entities is refused before pycollada sees it."""

    if b"<!ENTITY" in data:
        raise MeshError("declares XML entities: refused (they could expand or read files)")
    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise MeshError(f"not a COLLADA file: not XML ({exc})") from None
    if not isinstance(root.tag, str) or etree.QName(root).localname != "COLLADA":
        raise MeshError("not a COLLADA file: its root element is not <COLLADA>")
    unit = root.find("{*}asset/{*}unit")
    text = unit.get("meter") if unit is not None else None
    if text is None:
        return 1.0
    try:
        meter = float(text)
    except ValueError:
        raise MeshError(f"<unit meter={text!r}> is not a number") from None
    if not (meter > 0 and math.isfinite(meter)):
        raise MeshError(f"<unit meter={text!r}> must be a positive number")
    return meter
