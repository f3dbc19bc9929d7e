"""SDF model folders and worlds for a heightmap, for gz-sim (SDF 1.9) and Gazebo Classic (SDF 1.6).

Placement, from ../shared/REFERENCE.md:

* gz-sim: physics ignores ``<heightmap><pos>`` and uses only the collision's ``<pose>``; rendering
  uses ``<pos>`` in the world frame and ignores parent poses (gz-sim #1295, #1803). So the model
  sits at the origin, the collision ``<pose>`` and the visual ``<pos>`` both carry the offset, and
  a map point (x, y) is the world point (x, y).
* Gazebo Classic: a heightmap stays at the world origin whatever the model pose (#2167) and
  ``<pos>`` moves only the visual (#868). The terrain is therefore centred on the world origin and
  a map point (x, y) is the world point (x - cx, y - cy); :class:`Placement` carries (cx, cy).

Terrain tiles (grids larger than ``terrain.max_side``, :mod:`.tiles`): each tile is its own model
placed as above (gz-sim: collision ``<pose>`` and visual ``<pos>`` = the tile's centre; ``size``
from the tile's own side) and :func:`tiled_world_sdf` includes them all. gz-sim only: Gazebo
Classic renders a single heightmap per scene (gazebo-classic ``rendering/Scene.cc``: "Only one
Heightmap can be created per Scene") and cannot move one away from the world origin (#2167).

Walls instead of a heightmap (``world.geometry``: mesh, boxes, polylines): both simulators place
meshes, boxes and polylines anywhere, so in both the model sits at the world origin, the geometry
is written in map coordinates, and a map point (x, y) is the world point (x, y). One static model
with one link holds a ground plane over the map and the walls, from z = 0 to the wall height.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from lxml import etree
from numpy.typing import NDArray

from scan2terrain.exporters.heightmap import CLASSIC, GZ, Heightmap
from scan2terrain.geometry.caps import splitmix64
from scan2terrain.texts import decimal_text
from scan2terrain.types import EarthAnchor

SDF_VERSION = {GZ: "1.9", CLASSIC: "1.6"}
#: The names of the slabs under a terrain and under walls or voxels (pictures and the viewer
#: frame what stands on them).
FLOOR_COLLISION, GROUND_COLLISION = "floor_collision", "ground_collision"


def is_ground(part: str) -> bool:
    """Whether a collision read back (a ``WorldGeometry.parts`` line, ``model/link/name: ...``)
    is one of our slabs under the walls or the terrain."""
    return any(f"/{name}:" in part for name in (GROUND_COLLISION, FLOOR_COLLISION))


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
#: The systems a gz-sim world loads (file, class, options): a world that lists any system gets
#: only those, so physics, entity creation (the spawn service), the scene broadcaster (the GUI)
#: are listed with the sensors (lidars and cameras render with ogre2) and the IMU, as in
#: gz-sim's examples/worlds/sensors.sdf. gz-sim 7+ names; Fortress maps them from 6.16 on
#: (``gz-sim-`` -> ``ignition-gazebo-`` in SystemLoader.cc, ``gz::sim::systems::`` aliases).
GZ_SYSTEMS: tuple[tuple[str, str, tuple[tuple[str, str], ...]], ...] = (
    ("gz-sim-physics-system", "gz::sim::systems::Physics", ()),
    ("gz-sim-user-commands-system", "gz::sim::systems::UserCommands", ()),
    ("gz-sim-scene-broadcaster-system", "gz::sim::systems::SceneBroadcaster", ()),
    ("gz-sim-sensors-system", "gz::sim::systems::Sensors", (("render_engine", "ogre2"),)),
    ("gz-sim-imu-system", "gz::sim::systems::Imu", ()),
)
TEXTURE_DIR = "materials/textures"
HEIGHTMAP_FILE = "heightmap.png"


@dataclass(frozen=True)
class Placement:
    """Where the terrain sits in the simulated world.

    ``offset`` is subtracted from map coordinates to get world coordinates: (0, 0) for gz-sim,
    the terrain centre for Gazebo Classic, (0, 0) for walls in both. ``geometry`` is
    ``heightmap``, or ``mesh``/``boxes``/``polylines`` for walls (:func:`walls_placement`).
    """

    simulator: str
    model_name: str
    sampling: int
    size: tuple[float, float, float]
    offset: tuple[float, float]
    geometry: str = "heightmap"


def placement_for(
    hm: Heightmap, simulator: str, model_name: str, sampling: int | None
) -> Placement:
    s = DEFAULT_SAMPLING[simulator] if sampling is None else sampling
    side = hm.size_xy(simulator, s)
    offset = (0.0, 0.0) if simulator == GZ else hm.centre
    return Placement(simulator, model_name, s, (side, side, hm.z_range), offset)


def _fmt(*values: float) -> str:
    return " ".join(repr(round(float(v), 9)) for v in values)


def sub_element(
    parent: etree._Element, tag: str, text: str | None = None, **attrib: str
) -> etree._Element:
    """A child ``tag`` of ``parent`` with ``attrib`` and, if given, ``text``."""
    el = etree.SubElement(parent, tag, attrib)
    if text is not None:
        el.text = text
    return el


def _heightmap(
    parent: etree._Element, uri: str, p: Placement, pos: tuple[float, float, float] | None
) -> etree._Element:
    hmap = sub_element(sub_element(parent, "geometry"), "heightmap")
    sub_element(hmap, "uri", uri)
    sub_element(hmap, "size", _fmt(*p.size))
    if pos is not None:
        sub_element(hmap, "pos", _fmt(*pos))
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
        tex = sub_element(hmap, "texture")
        sub_element(tex, "diffuse", d)
        sub_element(tex, "normal", n)
        sub_element(tex, "size", "1")
    floor, unknown, wall = levels
    marks = [(floor + unknown) / 2, (unknown + wall) / 2]
    if unknown <= floor:
        marks[0] = (floor + wall) / 2
    if unknown >= wall:
        marks[1] = (floor + wall) / 2
    for m in marks:
        blend = sub_element(hmap, "blend")
        sub_element(blend, "min_height", _fmt(m))
        sub_element(blend, "fade_dist", _fmt(max(0.01, 0.05 * (wall - floor))))


def model_sdf(
    hm: Heightmap, p: Placement, *, levels: tuple[float, float, float], comment: str
) -> bytes:
    """``model.sdf`` for the terrain. ``levels``: floor, unknown and obstacle heights (metres)."""
    sdf = etree.Element("sdf", version=SDF_VERSION[p.simulator])
    sdf.append(etree.Comment(comment))
    model = sub_element(sdf, "model", name=p.model_name)
    sub_element(model, "static", "true")
    link = sub_element(model, "link", name="terrain_link")
    uri = f"model://{p.model_name}/{TEXTURE_DIR}/{HEIGHTMAP_FILE}"
    collision = sub_element(link, "collision", name="terrain_collision")
    if p.simulator == GZ:
        sub_element(collision, "pose", _fmt(hm.centre[0], hm.centre[1], hm.z_min, 0, 0, 0))
    chm = _heightmap(collision, uri, p, None)
    sub_element(chm, "sampling", str(p.sampling))
    # A floor under the terrain, its top at the heightmap's 0 (the floor of a map, the lowest
    # ground of a terrain): Bullet's height field (gz-sim: DART's bullet detector) loses its
    # grip on a box whose edges lie on the pixel grid (its 4-point manifold fills with the
    # side contacts of the flat triangles around it) and lets it sink through, then fall
    # forever; on the slab it rests. A slab, not a <plane>: dartsim makes a plane a 2100 m
    # cube, whose contacts are centimetres off in places (see _walls_model).
    floor = sub_element(link, "collision", name=FLOOR_COLLISION)
    cx, cy, z0 = (hm.centre[0], hm.centre[1], hm.z_min) if p.simulator == GZ else (0, 0, 0)
    sub_element(floor, "pose", _fmt(cx, cy, z0 - GROUND_THICKNESS / 2, 0, 0, 0))
    sub_element(
        sub_element(sub_element(floor, "geometry"), "box"),
        "size",
        _fmt(p.size[0], p.size[1], GROUND_THICKNESS),
    )
    visual = sub_element(link, "visual", name="terrain_visual")
    pos = (hm.centre[0], hm.centre[1], hm.z_min) if p.simulator == GZ else None
    vhm = _heightmap(visual, uri, p, pos)
    _textures(vhm, p, levels)
    sub_element(vhm, "use_terrain_paging", "false")
    sub_element(vhm, "sampling", str(p.sampling))
    return _bytes(sdf)


def model_config(p: Placement, description: str) -> bytes:
    model = etree.Element("model")
    sub_element(model, "name", p.model_name)
    sub_element(model, "version", "1.0")
    sub_element(model, "sdf", "model.sdf", version=SDF_VERSION[p.simulator])
    author = sub_element(model, "author")
    sub_element(author, "name", "scan2terrain")
    sub_element(author, "email", "")
    sub_element(model, "description", description)
    return _bytes(model)


def world_sdf(
    p: Placement, *, world_name: str, comment: str, anchor: EarthAnchor | None = None
) -> bytes:
    """A world holding a sun and the terrain model (by ``model://`` URI)."""
    return tiled_world_sdf([p], world_name=world_name, comment=comment, anchor=anchor)


def tiled_world_sdf(
    placements: Sequence[Placement],
    *,
    world_name: str,
    comment: str,
    anchor: EarthAnchor | None = None,
) -> bytes:
    """A world holding a sun and every model of ``placements`` (terrain tiles, by ``model://``
    URI, each at the world origin: a tile's offset is in its collision pose and visual pos),
    and, with ``anchor``, where its origin is on the earth (``<spherical_coordinates>``).

    All placements are for one simulator; gz-sim only when there are several heightmaps
    (Gazebo Classic renders one heightmap per scene and keeps each at the world origin).
    """
    if not placements or len({q.simulator for q in placements}) != 1:
        raise ValueError("placements must be one or more, all for one simulator")
    p = placements[0]
    if len(placements) > 1 and p.simulator != GZ:
        raise ValueError("only gz-sim worlds can hold several heightmap tiles")
    sdf = etree.Element("sdf", version=SDF_VERSION[p.simulator])
    sdf.append(etree.Comment(comment))
    world = sub_element(sdf, "world", name=world_name)
    if p.simulator == GZ:
        # Only DART collides with heightmaps in gz-sim, and DART's default (ODE) collision
        # detector has holes in heightmaps: ask for bullet.
        physics = sub_element(world, "physics", name="dart_bullet", type="dart")
        sub_element(physics, "max_step_size", "0.001")
        sub_element(physics, "real_time_factor", "1")
        sub_element(sub_element(physics, "dart"), "collision_detector", "bullet")
        for filename, name, options in GZ_SYSTEMS:
            plugin = sub_element(world, "plugin", filename=filename, name=name)
            for key, value in options:
                sub_element(plugin, key, value)
    else:
        physics = sub_element(world, "physics", name="ode", type="ode")
        sub_element(physics, "max_step_size", "0.001")
        sub_element(physics, "real_time_factor", "1")
    if anchor is not None:
        sph = sub_element(world, "spherical_coordinates")
        sub_element(sph, "surface_model", "EARTH_WGS84")
        sub_element(sph, "world_frame_orientation", "ENU")
        # 1e-9 degrees is 0.1 mm on the ground.
        sub_element(sph, "latitude_deg", decimal_text(anchor.latitude_deg, 9))
        sub_element(sph, "longitude_deg", decimal_text(anchor.longitude_deg, 9))
        sub_element(sph, "elevation", decimal_text(anchor.elevation, 3))
        sub_element(sph, "heading_deg", decimal_text(anchor.heading_deg, 6))
    sun = sub_element(world, "light", name="sun", type="directional")
    sub_element(sun, "cast_shadows", "true")
    sub_element(sun, "pose", "0 0 10 0 0 0")
    sub_element(sun, "diffuse", "0.8 0.8 0.8 1")
    sub_element(sun, "specular", "0.2 0.2 0.2 1")
    sub_element(sun, "direction", "-0.5 0.1 -0.9")
    for q in placements:
        inc = sub_element(world, "include")
        sub_element(inc, "uri", f"model://{q.model_name}")
        sub_element(inc, "name", q.model_name)
        sub_element(inc, "pose", "0 0 0 0 0 0")
    return _bytes(sdf)


def texture_pngs() -> dict[str, bytes]:
    """Plain 16 x 16 textures for gz-sim terrain, file name -> PNG bytes."""
    from PIL import Image

    out = {}
    for name, rgb in GZ_TEXTURE_COLOURS.items():
        buf = io.BytesIO()
        Image.fromarray(np.full((16, 16, 3), rgb, dtype=np.uint8)).save(buf, format="PNG")
        out[f"{name}.png"] = buf.getvalue()
    return out


# --- walls: mesh, boxes, polylines ----------------------------------------------------------

#: Folder of a wall model's mesh files and their stem: meshes/walls.stl, .dae, .obj.
MESH_DIR = "meshes"
MESH_STEM = "walls"
#: Visual colours (RGB 0..1): walls a warm grey, the ground lighter, as on the heightmap textures.
WALL_RGB = (0.55, 0.5, 0.45)
GROUND_RGB = (0.8, 0.8, 0.78)

#: The walls' ground slab: metres thick (top at z = 0) and beyond the grid on every side.
GROUND_THICKNESS = 1.0
GROUND_MARGIN = 10.0


@dataclass(frozen=True)
class Ground:
    """The floor under the walls, over the grid, in the map (= world) frame.

    ``centre`` (metres) and ``yaw`` (radians) place it, ``size`` (metres) is the grid's extent:
    the visual is a plane that size, the collision a ``GROUND_THICKNESS`` slab whose top is
    z = 0, ``GROUND_MARGIN`` wider all round (a robot driven off the map's edge stays up).
    """

    centre: tuple[float, float]
    size: tuple[float, float]
    yaw: float = 0.0
    z: float = 0.0  #: the top of the slab and the plane (voxel worlds: under the lowest voxel)


def walls_placement(
    simulator: str, model_name: str, geometry: str, ground: Ground, height: float
) -> Placement:
    """Walls sit at the world origin in both simulators: map frame = world frame, offset 0."""
    return Placement(
        simulator, model_name, 0, (ground.size[0], ground.size[1], height), (0.0, 0.0), geometry
    )


def _walls_model(
    p: Placement, ground: Ground, comment: str
) -> tuple[etree._Element, etree._Element]:
    """``<sdf><model>`` (static, at the origin) with one link holding the ground plane."""
    sdf = etree.Element("sdf", version=SDF_VERSION[p.simulator])
    sdf.append(etree.Comment(comment))
    model = sub_element(sdf, "model", name=p.model_name)
    sub_element(model, "static", "true")
    link = sub_element(model, "link", name="walls_link")
    cx, cy = ground.centre
    # Collision: a slab whose top is z = 0, GROUND_MARGIN wider than the grid all round. Not a
    # <plane>: gz-physics' dartsim makes a plane a 2100 m cube (SDFFeatures.cc ConstructPlane),
    # and Bullet's cylinder-box contacts against it are off by centimetres in places (a wheel
    # sank 4.4 cm into Willow Garage's floor); against a box the size of the map they are exact.
    collision = sub_element(link, "collision", name=GROUND_COLLISION)
    sub_element(collision, "pose", _fmt(cx, cy, ground.z - GROUND_THICKNESS / 2, 0, 0, ground.yaw))
    slab = (*(side + 2 * GROUND_MARGIN for side in ground.size), GROUND_THICKNESS)
    sub_element(sub_element(sub_element(collision, "geometry"), "box"), "size", _fmt(*slab))
    visual = sub_element(link, "visual", name="ground_visual")
    sub_element(visual, "pose", _fmt(cx, cy, ground.z, 0, 0, ground.yaw))
    plane = sub_element(sub_element(visual, "geometry"), "plane")
    sub_element(plane, "normal", "0 0 1")
    sub_element(plane, "size", _fmt(*ground.size))
    _material(visual, GROUND_RGB)
    return sdf, link


def _material(visual: etree._Element, rgb: tuple[float, float, float]) -> None:
    material = sub_element(visual, "material")
    sub_element(material, "ambient", _fmt(*rgb, 1))
    sub_element(material, "diffuse", _fmt(*rgb, 1))
    sub_element(material, "specular", "0.1 0.1 0.1 1")


def mesh_model_sdf(p: Placement, ground: Ground, *, comment: str) -> bytes:
    """``model.sdf`` for walls given as mesh files in the model folder (map coordinates, metres).

    Collision: ``meshes/walls.stl`` (Gazebo Classic's ODE and gz-sim's DART both read STL);
    visual: ``meshes/walls.dae`` (Classic renders COLLADA, not STL, with materials; gz-sim reads
    both). The OBJ copy beside them is for other tools.
    """
    sdf, link = _walls_model(p, ground, comment)
    base = f"model://{p.model_name}/{MESH_DIR}/{MESH_STEM}"
    for kind, ext in (("collision", "stl"), ("visual", "dae")):
        el = sub_element(link, kind, name=f"walls_{kind}")
        sub_element(sub_element(sub_element(el, "geometry"), "mesh"), "uri", f"{base}.{ext}")
        if kind == "visual":
            _material(el, WALL_RGB)
    return _bytes(sdf)


def voxels_model_sdf(
    p: Placement, ground: Ground, stems: list[str], *, comment: str, coloured: bool = False
) -> bytes:
    """``model.sdf`` for a voxel world: one static link holding the ground and, per chunk
    ``meshes/<stem>``, a collision (``.stl``) and a visual (``.dae``), in map coordinates.
    ``coloured``: the DAE carries the voxels' colours (no material is set over them)."""
    sdf, link = _walls_model(p, ground, comment)
    for stem in stems:
        base = f"model://{p.model_name}/{MESH_DIR}/{stem}"
        for kind, ext in (("collision", "stl"), ("visual", "dae")):
            el = sub_element(link, kind, name=f"{stem}_{kind}")
            sub_element(sub_element(sub_element(el, "geometry"), "mesh"), "uri", f"{base}.{ext}")
            if kind == "visual" and not coloured:
                _material(el, WALL_RGB)
    return _bytes(sdf)


def boxes_model_sdf(
    p: Placement, ground: Ground, boxes: NDArray[np.float64], *, comment: str
) -> bytes:
    """``model.sdf`` with one box collision per wall box and one visual for them all
    (``meshes/walls.dae``, :func:`scan2terrain.geometry.mesh.boxes_mesh`: the same boxes), all
    in one static link. A model per box would hit Gazebo's limits on real maps, and a visual per
    box doubles what Gazebo parses (Willow Garage: 1.3 s of a 2.3 s load); no boxes, no visual.

    Parameters
    ----------
    boxes : float array, shape (K, 5)
        Per box: centre x, y (metres, map frame = model frame), size x, size y (metres, along
        the box's own axes) and yaw (radians). Boxes stand on z = 0 and are ``p.size[2]`` high.
    """
    sdf, link = _walls_model(p, ground, comment)
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    x, y, sx, sy, yaw = (_numbers(b[:, k]) for k in range(5))
    half, height = _fmt(p.size[2] / 2), _fmt(p.size[2])
    # Thousands of identical little elements: written as text and parsed once (10x faster than
    # one lxml call per element). Every value is a number or a fixed name: nothing to escape.
    parts = []
    for i in range(len(b)):
        pose = f"<pose>{x[i]} {y[i]} {half} 0.0 0.0 {yaw[i]}</pose>"
        geometry = f"<geometry><box><size>{sx[i]} {sy[i]} {height}</size></box></geometry>"
        parts.append(f'<collision name="wall_{i}_collision">{pose}{geometry}</collision>')
    _extend(link, parts)
    if len(b):
        visual = sub_element(link, "visual", name="walls_visual")
        uri = f"model://{p.model_name}/{MESH_DIR}/{MESH_STEM}.dae"
        sub_element(sub_element(sub_element(visual, "geometry"), "mesh"), "uri", uri)
        _material(visual, WALL_RGB)
    return _bytes(sdf)


def polylines_model_sdf(
    p: Placement,
    ground: Ground,
    polygons: Sequence[Sequence[NDArray[np.float64]]],
    *,
    comment: str,
) -> bytes:
    """``model.sdf`` with one extruded-polyline collision and visual per polygon.

    Parameters
    ----------
    polygons : sequence of sequences of float arrays, each shape (N, 2)
        Per polygon its rings, exterior first then holes, in metres, map frame (= model frame),
        not closed. Each ring is one ``<polyline>`` of the same ``<geometry>``: Gazebo extrudes
        all the polylines of a geometry together and leaves out what lies inside an even number
        of rings (gz-common ``MeshManager::CreateExtrudedPolyline``, triangles whose centroid is
        inside an even number of rings are dropped), so the holes stay open. Extruded from z = 0
        to ``p.size[2]``. The points are written as :func:`gz_polyline_points` moves them
        (by less than 1e-12 of the largest coordinate), exactly (shortest round-trip repr).
    """
    sdf, link = _walls_model(p, ground, comment)
    height = f"<height>{_fmt(p.size[2])}</height>"
    material = _material_xml(WALL_RGB)
    parts = []
    for i, rings in enumerate(gz_polyline_points(polygons)):
        lines = []
        for ring in rings:
            xy = [repr(v) for v in ring.ravel().tolist()]
            points = "".join(
                f"<point>{u} {v}</point>" for u, v in zip(xy[::2], xy[1::2], strict=True)
            )
            lines.append(f"<polyline>{points}{height}</polyline>")
        geometry = f"<geometry>{''.join(lines)}</geometry>"
        parts.append(f'<collision name="wall_{i}_collision">{geometry}</collision>')
        parts.append(f'<visual name="wall_{i}_visual">{geometry}{material}</visual>')
    _extend(link, parts)
    return _bytes(sdf)


#: Largest nudge of a polyline coordinate, in quanta (see :func:`gz_polyline_points`).
POLYLINE_NUDGE = 256
#: Smallest cell (metres) for polylines: gz-common merges the points of a polyline geometry
#: closer than 1e-4 m (``MeshManager::AddUniquePointToVerticesTable``), and outline points can
#: be half a cell apart (a simplified outline's chamfers).
POLYLINE_MIN_CELL = 1e-3


def gz_polyline_points(
    polygons: Sequence[Sequence[NDArray[np.float64]]],
) -> list[list[NDArray[np.float64]]]:
    """The rings as ``<polyline>`` points that gz-common 4 (and Gazebo Classic 11) can extrude.

    Gazebo builds a polyline geometry with ``MeshManager::CreateExtrudedPolyline`` (gz-sim's
    Physics system and SceneManager; gz-common 4 and 5, Classic 11), which triangulates all its
    rings with GTS (``GTSMeshUtils::DelaunayTriangulation``) and fails or crashes on the
    outlines of a grid, whose points lie on a lattice:

    * hole test: a triangle is dropped when a ray from its centroid crosses an even number of
      ring edges, counted for ``min(y1, y2) <= y < (y1 + y2) - min(y1, y2)``. In floating point
      that upper bound is not ``max(y1, y2)``, so a ray at the height of a vertex (every
      triangle whose corners are evenly spaced in y) counts both edges there, or neither: a
      triangle inside is dropped, or one in a hole kept. gz-common then finds a ring edge with
      no triangle, or two ("Unable to extrude mesh. Triangulation failed": no shape at all),
      or, when the dropped triangle touches no ring, builds the shape with a hole in its caps;
    * GTS (0.7.6, ``cdt.c``) assumes points in general position. Point location walks from a
      triangle's barycentre to the new point and restarts from a neighbour's barycentre
      whenever the walk passes exactly through a vertex, without bound (stack overflow:
      SIGSEGV); inserting a ring edge that crosses triangles asserts that when the edge's end
      point is collinear with the far side of a crossed triangle it is that side's vertex
      (``remove_intersected_edge``: SIGABRT, or a corrupt surface without assertions). On a
      lattice both happen; where the walk starts depends on a hash of pointers, so whether
      they do changes from run to run.

    So every coordinate is moved onto a grid of ``q = 2^(e - 50)`` metres, ``2^e`` above the
    largest absolute coordinate (at least 1 m): sums of three coordinates are then exact, the
    bound above is ``max(y1, y2)`` and a centroid lies on a vertex's height only when it truly
    does. And each point is nudged by a hash of its position, up to ``POLYLINE_NUDGE`` quanta in
    x and in y: no three points are exactly collinear, no four exactly cocircular, unless by a
    coincidence GTS has not met in our tests. Equal points move equally (rings touching at a
    point still touch, in every geometry); a point moves by less than ``257 q``, 1e-12 of the
    largest coordinate (0.2 nm within 1 km of the origin), so no wall changes its cells. The
    same input gives the same bytes.

    Parameters
    ----------
    polygons : sequence of sequences of float arrays, each shape (N, 2)
        Per polygon its rings, metres, finite.

    Returns
    -------
    list of lists of float64 arrays, each shape (N, 2)
        The same structure, moved.
    """

    rings = [np.asarray(r, dtype=np.float64).reshape(-1, 2) for poly in polygons for r in poly]
    if not rings:
        return [[] for _ in polygons]
    xy = np.concatenate(rings)
    if not np.isfinite(xy).all():
        raise ValueError("polyline points must be finite")
    biggest = max(float(np.abs(xy).max()), 1.0)
    quantum = float(np.ldexp(1.0, int(np.frexp(biggest)[1]) - 50))
    steps = np.rint(xy / quantum)  # integers, |steps| <= 2^50
    bits = steps.astype(np.int64).view(np.uint64)
    mixed = splitmix64(splitmix64(bits[:, 0]) ^ bits[:, 1])
    span = np.uint64(2 * POLYLINE_NUDGE + 1)
    nudge = np.stack([mixed % span, (mixed >> np.uint64(32)) % span], axis=1)
    moved = (steps + (nudge.astype(np.int64) - POLYLINE_NUDGE)) * quantum
    pieces = iter(np.split(moved, np.cumsum([len(r) for r in rings])[:-1]))
    return [[next(pieces) for _ in poly] for poly in polygons]


def _numbers(values: NDArray[np.float64]) -> list[str]:
    """Each value as :func:`_fmt` writes it (row-major)."""
    return [repr(round(v, 9)) for v in np.asarray(values, dtype=np.float64).ravel().tolist()]


def _material_xml(rgb: tuple[float, float, float]) -> str:
    colour = _fmt(*rgb, 1)
    return (
        f"<material><ambient>{colour}</ambient><diffuse>{colour}</diffuse>"
        "<specular>0.1 0.1 0.1 1</specular></material>"
    )


def _extend(parent: etree._Element, parts: list[str]) -> None:
    """Append the elements of generated XML text (trusted: numbers and fixed names)."""
    parent.extend(list(etree.fromstring(f"<parts>{''.join(parts)}</parts>")))


def _bytes(root: etree._Element) -> bytes:
    return bytes(etree.tostring(root, pretty_print=True, xml_declaration=True, encoding="UTF-8"))
