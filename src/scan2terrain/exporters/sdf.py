"""SDF model folders and worlds for a heightmap, for gz-sim (SDF 1.9) and Gazebo Classic (SDF 1.6).

Placement, from ../shared/REFERENCE.md:

* gz-sim: physics ignores ``<heightmap><pos>`` and uses only the collision's ``<pose>``; rendering
  uses ``<pos>`` in the world frame and ignores parent poses (gz-sim #1295, #1803). So the model
  sits at the origin, the collision ``<pose>`` and the visual ``<pos>`` both carry the offset, and
  a map point (x, y) is the world point (x, y).
* Gazebo Classic: a heightmap stays at the world origin whatever the model pose (#2167) and
  ``<pos>`` moves only the visual (#868). The terrain is therefore centred on the world origin and
  a map point (x, y) is the world point (x - cx, y - cy); :class:`Placement` carries (cx, cy).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

from lxml import etree

from scan2terrain.exporters.heightmap import CLASSIC, GZ, Heightmap

SDF_VERSION = {GZ: "1.9", CLASSIC: "1.6"}
#: Gazebo's own default vertex sampling for each SDF version we write.
DEFAULT_SAMPLING = {GZ: 1, CLASSIC: 2}
#: Textures that ship with Gazebo Classic (gazebo/media/materials/textures), lowest terrain first.
CLASSIC_TEXTURES = (
    ("file://media/materials/textures/dirt_diffusespecular.png", "floor"),
    ("file://media/materials/textures/grass_diffusespecular.png", "unknown"),
    ("file://media/materials/textures/fungus_diffusespecular.png", "obstacle"),
)
CLASSIC_NORMAL = "file://media/materials/textures/flat_normal.png"
#: gz-sim installs no terrain textures at a fixed path, so the model carries small plain ones.
GZ_TEXTURE_COLOURS = {
    "floor": (205, 205, 200),
    "unknown": (150, 175, 205),
    "obstacle": (95, 70, 55),
    "normal": (128, 128, 255),
}
TEXTURE_DIR = "materials/textures"
HEIGHTMAP_FILE = "heightmap.png"


@dataclass(frozen=True)
class Placement:
    """Where the terrain sits in the simulated world.

    ``offset`` is subtracted from map coordinates to get world coordinates: (0, 0) for gz-sim,
    the terrain centre for Gazebo Classic.
    """

    simulator: str
    model_name: str
    sampling: int
    size: tuple[float, float, float]
    offset: tuple[float, float]


def placement_for(
    hm: Heightmap, simulator: str, model_name: str, sampling: int | None
) -> Placement:
    s = DEFAULT_SAMPLING[simulator] if sampling is None else sampling
    side = hm.size_xy(simulator, s)
    offset = (0.0, 0.0) if simulator == GZ else hm.centre
    return Placement(simulator, model_name, s, (side, side, hm.z_range), offset)


def _fmt(*values: float) -> str:
    return " ".join(repr(round(float(v), 9)) for v in values)


def _sub(
    parent: etree._Element, tag: str, text: str | None = None, **attrib: str
) -> etree._Element:
    el = etree.SubElement(parent, tag, attrib)
    if text is not None:
        el.text = text
    return el


def _heightmap(
    parent: etree._Element, uri: str, p: Placement, pos: tuple[float, float, float] | None
) -> etree._Element:
    hmap = _sub(_sub(parent, "geometry"), "heightmap")
    _sub(hmap, "uri", uri)
    _sub(hmap, "size", _fmt(*p.size))
    if pos is not None:
        _sub(hmap, "pos", _fmt(*pos))
    return hmap


def _textures(hmap: etree._Element, p: Placement, levels: tuple[float, float, float]) -> None:
    """Floor, unknown and obstacle textures, blended at the midpoints between their heights."""
    if p.simulator == CLASSIC:
        diffuse = [(uri, CLASSIC_NORMAL) for uri, _ in CLASSIC_TEXTURES]
    else:
        base = f"model://{p.model_name}/{TEXTURE_DIR}"
        diffuse = [
            (f"{base}/{k}.png", f"{base}/normal.png") for k in ("floor", "unknown", "obstacle")
        ]
    for d, n in diffuse:
        tex = _sub(hmap, "texture")
        _sub(tex, "diffuse", d)
        _sub(tex, "normal", n)
        _sub(tex, "size", "1")
    floor, unknown, wall = levels
    marks = [(floor + unknown) / 2, (unknown + wall) / 2]
    if unknown <= floor:
        marks[0] = (floor + wall) / 2
    if unknown >= wall:
        marks[1] = (floor + wall) / 2
    for m in marks:
        blend = _sub(hmap, "blend")
        _sub(blend, "min_height", _fmt(m))
        _sub(blend, "fade_dist", _fmt(max(0.01, 0.05 * (wall - floor))))


def model_sdf(
    hm: Heightmap, p: Placement, *, levels: tuple[float, float, float], comment: str
) -> bytes:
    """``model.sdf`` for the terrain. ``levels``: floor, unknown and obstacle heights (metres)."""
    sdf = etree.Element("sdf", version=SDF_VERSION[p.simulator])
    sdf.append(etree.Comment(comment))
    model = _sub(sdf, "model", name=p.model_name)
    _sub(model, "static", "true")
    link = _sub(model, "link", name="terrain_link")
    uri = f"model://{p.model_name}/{TEXTURE_DIR}/{HEIGHTMAP_FILE}"
    collision = _sub(link, "collision", name="terrain_collision")
    if p.simulator == GZ:
        _sub(collision, "pose", _fmt(hm.centre[0], hm.centre[1], hm.z_min, 0, 0, 0))
    chm = _heightmap(collision, uri, p, None)
    _sub(chm, "sampling", str(p.sampling))
    visual = _sub(link, "visual", name="terrain_visual")
    pos = (hm.centre[0], hm.centre[1], hm.z_min) if p.simulator == GZ else None
    vhm = _heightmap(visual, uri, p, pos)
    _textures(vhm, p, levels)
    _sub(vhm, "use_terrain_paging", "false")
    _sub(vhm, "sampling", str(p.sampling))
    return _bytes(sdf)


def model_config(p: Placement, description: str) -> bytes:
    model = etree.Element("model")
    _sub(model, "name", p.model_name)
    _sub(model, "version", "1.0")
    _sub(model, "sdf", "model.sdf", version=SDF_VERSION[p.simulator])
    author = _sub(model, "author")
    _sub(author, "name", "scan2terrain")
    _sub(author, "email", "")
    _sub(model, "description", description)
    return _bytes(model)


def world_sdf(p: Placement, *, world_name: str, comment: str) -> bytes:
    """A world holding a sun and the terrain model (by ``model://`` URI)."""
    sdf = etree.Element("sdf", version=SDF_VERSION[p.simulator])
    sdf.append(etree.Comment(comment))
    world = _sub(sdf, "world", name=world_name)
    if p.simulator == GZ:
        # Only DART collides with heightmaps in gz-sim, and DART's default (ODE) collision
        # detector has holes in heightmaps: ask for bullet.
        physics = _sub(world, "physics", name="dart_bullet", type="dart")
        _sub(physics, "max_step_size", "0.001")
        _sub(physics, "real_time_factor", "1")
        _sub(_sub(physics, "dart"), "collision_detector", "bullet")
    else:
        physics = _sub(world, "physics", name="ode", type="ode")
        _sub(physics, "max_step_size", "0.001")
        _sub(physics, "real_time_factor", "1")
    sun = _sub(world, "light", name="sun", type="directional")
    _sub(sun, "cast_shadows", "true")
    _sub(sun, "pose", "0 0 10 0 0 0")
    _sub(sun, "diffuse", "0.8 0.8 0.8 1")
    _sub(sun, "specular", "0.2 0.2 0.2 1")
    _sub(sun, "direction", "-0.5 0.1 -0.9")
    inc = _sub(world, "include")
    _sub(inc, "uri", f"model://{p.model_name}")
    _sub(inc, "name", p.model_name)
    _sub(inc, "pose", "0 0 0 0 0 0")
    return _bytes(sdf)


def texture_pngs() -> dict[str, bytes]:
    """Plain 16 x 16 textures for gz-sim terrain, file name -> PNG bytes."""
    import numpy as np
    from PIL import Image

    out = {}
    for name, rgb in GZ_TEXTURE_COLOURS.items():
        buf = io.BytesIO()
        Image.fromarray(np.full((16, 16, 3), rgb, dtype=np.uint8)).save(buf, format="PNG")
        out[f"{name}.png"] = buf.getvalue()
    return out


def _bytes(root: etree._Element) -> bytes:
    return bytes(etree.tostring(root, pretty_print=True, xml_declaration=True, encoding="UTF-8"))
