"""Meshes as files: binary STL, Wavefront OBJ and COLLADA 1.4.1 bytes.

The writers return deterministic bytes: binary STL (float32, what STL holds), Wavefront OBJ and
COLLADA 1.4.1 (float64 text, Python's shortest repr, which reads back to the same numbers; Z up,
metres; with per-face normals, one material), as Gazebo loads for visuals and collisions.
Vertices are in the map frame, metres, z up (:class:`scan2terrain.geometry.mesh.Mesh`).
"""

from __future__ import annotations

import re
import struct

import numpy as np

from scan2terrain.geometry.mesh import Mesh

__all__ = ["WALL_COLOUR", "dae_bytes", "obj_bytes", "stl_bytes"]

#: Colour of the walls' material in COLLADA (RGBA, linear).
WALL_COLOUR = (0.7, 0.7, 0.7, 1.0)


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
    lines = ["# scan2terrain mesh: map frame, metres, z up"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"f {a} {b} {c}" for a, b, c in (mesh.faces + 1).tolist()]
    return ("\n".join(lines) + "\n").encode("ascii")


def dae_bytes(mesh: Mesh, name: str) -> bytes:
    """COLLADA 1.4.1 with one geometry (positions, per-face normals, triangles) and one
    material, ``<unit meter="1"/>`` and ``<up_axis>Z_UP</up_axis>``. ``name`` (letters,
    digits, ``_ - .``; others become ``_``) names the geometry, material and scene node.
    Timestamps are fixed (1970-01-01) so the same mesh gives the same bytes."""
    from lxml import etree

    ident = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "mesh"
    if not re.match(r"[A-Za-z_]", ident):
        ident = "_" + ident
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
    effect = sub(effects, "effect", id=f"{ident}-effect")
    technique = sub(sub(effect, "profile_COMMON"), "technique", sid="common")
    lambert = sub(technique, "lambert")
    sub(sub(lambert, "diffuse"), "color", " ".join(map(repr, WALL_COLOUR)), sid="diffuse")
    materials = sub(root, "library_materials")
    material = sub(materials, "material", id=f"{ident}-material", name=f"{ident}-material")
    sub(material, "instance_effect", url=f"#{ident}-effect")

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
            " ".join(map(repr, values.reshape(-1).tolist())),
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
    triangles = sub(m, "triangles", material="walls", count=str(len(mesh.faces)))
    sub(triangles, "input", semantic="VERTEX", source=f"#{ident}-vertices", offset="0")
    sub(triangles, "input", semantic="NORMAL", source=f"#{ident}-normals", offset="1")
    face_index = np.repeat(np.arange(len(mesh.faces), dtype=np.int64), 3)
    p = np.stack([mesh.faces.reshape(-1), face_index], axis=1).reshape(-1)
    sub(triangles, "p", " ".join(map(str, p.tolist())))

    scenes = sub(root, "library_visual_scenes")
    scene = sub(scenes, "visual_scene", id="Scene", name="Scene")
    node = sub(scene, "node", id=ident, name=ident, type="NODE")
    instance = sub(node, "instance_geometry", url=f"#{ident}-mesh", name=ident)
    bind = sub(sub(instance, "bind_material"), "technique_common")
    sub(bind, "instance_material", symbol="walls", target=f"#{ident}-material")
    sub(sub(root, "scene"), "instance_visual_scene", url="#Scene")
    out: bytes = etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)
    return out
