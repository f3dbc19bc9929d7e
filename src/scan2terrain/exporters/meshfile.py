"""Meshes as files: binary STL, Wavefront OBJ and COLLADA 1.4.1 bytes.

The writers return deterministic bytes: binary STL (float32, what STL holds), Wavefront OBJ and
COLLADA 1.4.1 (float64 text, Python's shortest repr, which reads back to the same numbers; Z up,
metres; with per-face normals, one material, or one material per colour of coloured faces), as
Gazebo loads for visuals and collisions. Vertices are in the map frame, metres, z up
(:class:`scan2terrain.geometry.mesh.Mesh`).

Why face colours are materials, not COLLADA's per-vertex ``COLOR`` input: gz-common 4 (gz-sim
Fortress) reads only ``VERTEX``, ``NORMAL`` and ``TEXCOORD`` inputs of ``<triangles>`` and warns
"Triangle input semantic: 'COLOR' is currently not supported" for any other
(graphics/src/ColladaLoader.cc, ``LoadTriangles``); its ``SubMesh`` has no vertex colours. What
it does read is one material per ``<triangles>`` element (``LoadMaterial``: the ``<lambert>``,
``<phong>`` or ``<blinn>`` ``<ambient>``/``<diffuse>`` colours), each element becoming a submesh
with that material; Gazebo Classic's loader, from which gz-common's was taken, does the same.
"""

from __future__ import annotations

import re
import struct
from typing import NamedTuple

import numpy as np
from lxml import etree
from numpy.typing import NDArray

from scan2terrain.exporters._numbers import float_texts, joined_ints
from scan2terrain.geometry.mesh import Mesh

__all__ = [
    "MAX_MATERIALS",
    "WALL_COLOUR",
    "dae_bytes",
    "obj_bytes",
    "quantise_colours",
    "stl_bytes",
]

#: Colour of the walls' material in COLLADA (RGBA, linear).
WALL_COLOUR = (0.7, 0.7, 0.7, 1.0)
#: Materials (one submesh, one draw call each in Gazebo) a coloured COLLADA mesh may have.
MAX_MATERIALS = 256
#: Bits per channel of the palette's second try (:func:`quantise_colours`).
_PALETTE_BITS = 5


def stl_bytes(mesh: Mesh) -> bytes:
    """Binary STL: an 80-byte header, the face count, then per face its unit normal and three
    vertices (float32, little endian) and a zero attribute word. Map frame, metres."""
    header = b"scan2terrain mesh, binary STL, metres, map frame, z up".ljust(80, b" ")
    record = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
    body = np.zeros(len(mesh.faces), dtype=record)
    body["normal"] = mesh.normals()
    body["vertices"] = mesh.vertices[mesh.faces]
    return header + struct.pack("<I", len(mesh.faces)) + body.tobytes()


def obj_bytes(mesh: Mesh) -> bytes:
    """Wavefront OBJ text: ``v x y z`` lines (shortest repr, exact), then ``f a b c`` lines
    (1-based). Map frame, metres."""
    # One %-format for all vertices and one for all faces: C code, no Python line per vertex.
    vertices = ("v %s %s %s\n" * len(mesh.vertices)) % tuple(float_texts(mesh.vertices))
    faces = ("f %d %d %d\n" * len(mesh.faces)) % tuple((mesh.faces + 1).reshape(-1).tolist())
    return f"# scan2terrain mesh: map frame, metres, z up\n{vertices}{faces}".encode("ascii")


def quantise_colours(
    colours: NDArray[np.uint8], max_colours: int = MAX_MATERIALS
) -> tuple[NDArray[np.uint8], NDArray[np.intp]]:
    """At most ``max_colours`` colours standing for ``colours`` (F, 3) uint8 RGB: the palette
    (K, 3) uint8, sorted by ``(r, g, b)``, and each row's palette index (F,).

    The first that fits: the colours as they are, if at most ``max_colours`` differ; else each
    channel rounded to 5 bits (32 levels, ``round(c * 31 / 255)`` and back to
    ``round(level * 255 / 31)``, so 0 and 255 stay), if at most ``max_colours`` of those differ;
    else the ``max_colours`` 5-bit colours that most rows have (ties: the smaller ``(r, g, b)``),
    each row taking the one nearest to its 5-bit colour (squared RGB distance; ties: the
    smaller). Integer arithmetic throughout: the same colours give the same palette.
    """
    rgb = np.asarray(colours)
    if rgb.ndim != 2 or rgb.shape[1] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"colours must be (F, 3) uint8, got {rgb.dtype} {rgb.shape}")
    if max_colours < 1:
        raise ValueError(f"max_colours must be at least 1, got {max_colours}")
    packed = _pack_rgb(rgb)
    palette, index = np.unique(packed, return_inverse=True)
    if len(palette) <= max_colours:
        return _unpack_rgb(palette), index.reshape(-1)
    levels = (1 << _PALETTE_BITS) - 1
    level = (rgb.astype(np.int64) * (2 * levels) + 255) // 510  # round(c * 31 / 255), half up
    coarse = (level * 510 + levels) // (2 * levels)  # round(level * 255 / 31), half up
    palette, index, counts = np.unique(_pack_rgb(coarse), return_inverse=True, return_counts=True)
    index = index.reshape(-1)
    if len(palette) <= max_colours:
        return _unpack_rgb(palette), index
    # The most frequent 5-bit colours (np.unique sorted them, so a stable sort by count keeps
    # the smaller colour first among equals), then each 5-bit colour's nearest of them.
    kept = np.sort(palette[np.argsort(-counts, kind="stable")[:max_colours]])
    chosen = _unpack_rgb(kept).astype(np.int64)
    candidates = _unpack_rgb(palette).astype(np.int64)
    nearest = np.empty(len(palette), dtype=np.intp)
    for lo in range(0, len(palette), 4096):  # (4096, K) distances at a time
        d = candidates[lo : lo + 4096, None, :] - chosen[None, :, :]
        nearest[lo : lo + 4096] = np.argmin((d * d).sum(axis=2), axis=1)
    return _unpack_rgb(kept), nearest[index]


def _pack_rgb(rgb: NDArray[np.integer]) -> NDArray[np.int64]:
    r = rgb.astype(np.int64)
    packed: NDArray[np.int64] = (r[:, 0] << 16) | (r[:, 1] << 8) | r[:, 2]
    return packed


def _unpack_rgb(packed: NDArray[np.int64]) -> NDArray[np.uint8]:
    return np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1).astype(
        np.uint8
    )


class _Group(NamedTuple):
    """One ``<triangles>`` element of a COLLADA mesh and its material."""

    symbol: str  #: the material symbol the element names
    material: str  #: material id
    effect: str  #: effect id
    rgba: tuple[float, ...]
    ambient: bool  #: the colour is also the material's ambient one
    faces: NDArray[np.int64]  #: indices of its faces, in mesh order


def dae_bytes(
    mesh: Mesh,
    name: str,
    *,
    face_colours: NDArray[np.uint8] | None = None,
    max_materials: int = MAX_MATERIALS,
) -> bytes:
    """COLLADA 1.4.1 with one geometry (positions, per-face normals, triangles) and one
    material, ``<unit meter="1"/>`` and ``<up_axis>Z_UP</up_axis>``. ``name`` (letters,
    digits, ``_ - .``; others become ``_``) names the geometry, material and scene node.
    Timestamps are fixed (1970-01-01) so the same mesh gives the same bytes.

    ``face_colours`` (F, 3) uint8 RGB, one per face: the faces are written as one
    ``<triangles>`` element per colour of :func:`quantise_colours` (at most ``max_materials``),
    in the palette's ``(r, g, b)`` order, each face in its element in mesh order; each colour
    is a material ``<name>-rgb-RRGGBB-material`` (symbol ``rgb-RRGGBB``, hex) whose lambert
    ``<ambient>`` and ``<diffuse>`` are ``RR/255 GG/255 BB/255 1`` (the 8-bit values as stored,
    not linearised). gz-common 4 and Gazebo Classic load each element as a submesh with its
    material (see the module's docstring); they do not read per-vertex colours. Without
    ``face_colours`` the output is one grey material (:data:`WALL_COLOUR`), as it always was.
    """

    ident = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "mesh"
    if not re.match(r"[A-Za-z_]", ident):
        ident = "_" + ident
    if face_colours is None:
        every = np.arange(len(mesh.faces), dtype=np.int64)
        groups = [
            _Group("walls", f"{ident}-material", f"{ident}-effect", WALL_COLOUR, False, every)
        ]
    else:
        fc = np.asarray(face_colours)
        if fc.shape != (len(mesh.faces), 3) or fc.dtype != np.uint8:
            raise ValueError(
                f"face_colours must be ({len(mesh.faces)}, 3) uint8, one per face; "
                f"got {fc.dtype} {fc.shape}"
            )
        palette, index = quantise_colours(fc, max_materials)
        order = np.argsort(index, kind="stable").astype(np.int64)  # by colour, then face
        bounds = np.searchsorted(index[order], np.arange(len(palette) + 1))
        groups = []
        for k, (r, g, b) in enumerate(palette.tolist()):
            symbol = f"rgb-{r:02X}{g:02X}{b:02X}"
            groups.append(
                _Group(
                    symbol,
                    f"{ident}-{symbol}-material",
                    f"{ident}-{symbol}-effect",
                    (r / 255, g / 255, b / 255, 1.0),
                    True,
                    order[bounds[k] : bounds[k + 1]],
                )
            )
    ns = "http://www.collada.org/2005/11/COLLADASchema"
    # lxml-stubs type nsmap keys as str; None is lxml's key for the default namespace.
    root = etree.Element(f"{{{ns}}}COLLADA", nsmap={None: ns}, version="1.4.1")  # type: ignore[dict-item]

    def sub(
        parent: etree._Element, tag: str, text: str | None = None, **attrib: str
    ) -> etree._Element:
        el = etree.SubElement(parent, f"{{{ns}}}{tag}", attrib)
        if text is not None:
            el.text = text
        return el

    asset = sub(root, "asset")
    contributor = sub(asset, "contributor")
    sub(contributor, "authoring_tool", "scan2terrain")
    sub(asset, "created", "1970-01-01T00:00:00Z")
    sub(asset, "modified", "1970-01-01T00:00:00Z")
    sub(asset, "unit", name="meter", meter="1")
    sub(asset, "up_axis", "Z_UP")

    effects = sub(root, "library_effects")
    for group in groups:
        effect = sub(effects, "effect", id=group.effect)
        technique = sub(sub(effect, "profile_COMMON"), "technique", sid="common")
        lambert = sub(technique, "lambert")
        colour = " ".join(map(repr, group.rgba))
        if group.ambient:  # gz-common's default ambient is grey: lit by ambient light, keep hue
            sub(sub(lambert, "ambient"), "color", colour, sid="ambient")
        sub(sub(lambert, "diffuse"), "color", colour, sid="diffuse")
    materials = sub(root, "library_materials")
    for group in groups:
        material = sub(materials, "material", id=group.material, name=group.material)
        sub(material, "instance_effect", url=f"#{group.effect}")

    geometries = sub(root, "library_geometries")
    geometry = sub(geometries, "geometry", id=f"{ident}-mesh", name=ident)
    m = sub(geometry, "mesh")
    normals = mesh.normals()
    for kind, values in (("positions", mesh.vertices), ("normals", normals)):
        source = sub(m, "source", id=f"{ident}-{kind}")
        array_id = f"{ident}-{kind}-array"
        sub(
            source,
            "float_array",
            " ".join(float_texts(values)),
            id=array_id,
            count=str(values.size),
        )
        accessor = sub(
            sub(source, "technique_common"),
            "accessor",
            source=f"#{array_id}",
            count=str(len(values)),
            stride="3",
        )
        for axis in "XYZ":
            sub(accessor, "param", name=axis, type="float")
    vertices = sub(m, "vertices", id=f"{ident}-vertices")
    sub(vertices, "input", semantic="POSITION", source=f"#{ident}-positions")
    for group in groups:
        triangles = sub(m, "triangles", material=group.symbol, count=str(len(group.faces)))
        sub(triangles, "input", semantic="VERTEX", source=f"#{ident}-vertices", offset="0")
        sub(triangles, "input", semantic="NORMAL", source=f"#{ident}-normals", offset="1")
        face_index = np.repeat(group.faces, 3)  # the normal of each corner is its face's
        p = np.stack([mesh.faces[group.faces].reshape(-1), face_index], axis=1).reshape(-1)
        sub(triangles, "p", joined_ints(p))

    scenes = sub(root, "library_visual_scenes")
    scene = sub(scenes, "visual_scene", id="Scene", name="Scene")
    node = sub(scene, "node", id=ident, name=ident, type="NODE")
    instance = sub(node, "instance_geometry", url=f"#{ident}-mesh", name=ident)
    bind = sub(sub(instance, "bind_material"), "technique_common")
    for group in groups:
        sub(bind, "instance_material", symbol=group.symbol, target=f"#{group.material}")
    sub(sub(root, "scene"), "instance_visual_scene", url="#Scene")
    out: bytes = etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)
    return out
