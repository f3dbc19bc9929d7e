"""A Gazebo world read back: its collision geometry as triangles in the WORLD frame.

For the fidelity check (issue 26), which casts recorded laser beams into a world exactly as
its files say. What is read is what the physics collides with: every ``<collision>`` of every
``<link>`` of every ``<model>`` of the first ``<world>`` (nested models and ``<include>``\\ d
ones at any depth; an include's ``<pose>`` and ``<name>`` override the included model's), at
its initial pose, static or not: world pose = model pose * link pose * collision pose (SDF
``<pose>`` x y z roll pitch yaw, rotation ``Rz(yaw) Ry(pitch) Rx(roll)``; ``degrees="true"``
and ``rotation_format="quat_xyzw"`` are read; a pose ``relative_to`` (or SDF 1.5's ``frame``)
another frame than its parent's is refused). Visuals are not read. gz-sim's ``gpu_lidar``
renders the visuals, so a world whose visuals differ from its collisions (a heightmap's visual
placed by ``<pos>``, a mesh visual of other detail) can give a real Gazebo lidar other ranges
than these; our own worlds' visuals are the collisions' shapes.

Shapes (:mod:`._world_shapes`, :mod:`._world_meshes`, :mod:`._world_heightmap`): box, cylinder,
sphere, capsule and ellipsoid (curved ones within 1 mm of the surface), plane (dartsim's
2100 m cube for ``gz``, ODE's infinite plane cut to 2100 m for ``classic``), mesh (STL, OBJ,
COLLADA; ``<scale>`` applied; ``<submesh>`` refused), polyline (every ``<polyline>`` of the
geometry extruded together, even-odd, to the first one's height, as gz-common does), heightmap
(as gz-physics' dartsim or Classic's ODE lays it out, with Bullet's or ODE's diagonals).
``<empty/>`` is nothing; any other geometry (``<image>``) is refused.

Files: ``model://NAME/rest`` is ``NAME/rest`` under the ``models/`` folder beside the world,
then each of ``model_paths``, then each folder of ``GZ_SIM_RESOURCE_PATH``,
``IGN_GAZEBO_RESOURCE_PATH`` and ``GAZEBO_MODEL_PATH`` (colon-separated), the first that has it;
a URI without a scheme is relative to the file that names it, ``file://`` names a path (absolute,
or relative as that); other schemes (Fuel's https) are refused: nothing is downloaded. An
``<include>`` of a folder reads the SDF file its ``model.config`` names (the highest
``<sdf version>``), else its ``model.sdf``. With ``files``, every path under the world's folder
is looked up there first (relative POSIX keys), then on disk.

XML is parsed by lxml without entity expansion, DTD loading or network access. Whatever is
wrong with an input is one :class:`~scan2terrain.errors.InputError` naming the file at fault
(the world, a model file, a mesh, an image) and, for an element, its line: missing or not
regular, not XML, not SDF, an include that resolves nowhere or includes itself, a shape with
absurd numbers (not finite, negative, beyond 1e7 m), a mesh or image that cannot be decoded,
no collision geometry at all, or more than :data:`MAX_TRIANGLES` triangles.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from lxml import etree
from numpy.typing import NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers import _world_heightmap as hm
from scan2terrain.readers import _world_shapes as shapes
from scan2terrain.readers import _world_xml as sdf
from scan2terrain.readers._world_files import RESOURCE_PATH_VARIABLES, Store, heightmap_image
from scan2terrain.readers._world_meshes import MESH_FORMATS, MeshError, load_mesh

__all__ = [
    "MAX_TRIANGLES",
    "RESOURCE_PATH_VARIABLES",
    "SIMULATORS",
    "Simulator",
    "WorldGeometry",
    "read_world",
]

Simulator = Literal["gz", "classic"]
SIMULATORS: tuple[Simulator, ...] = ("gz", "classic")
#: Triangles a world may have in all (a 4097 x 4097 heightmap is 33.5 M): 1.2 GB of arrays.
MAX_TRIANGLES = 50_000_000
#: Includes nested deeper than this are refused (a loop is refused as soon as it closes).
MAX_INCLUDE_DEPTH = 64
_SHAPES = "box, cylinder, sphere, capsule, ellipsoid, plane, mesh, polyline, heightmap"


@dataclass(frozen=True)
class WorldGeometry:
    """The collision geometry of a world, in its WORLD frame.

    vertices : float64 (V, 3), metres.
    triangles : int32 (T, 3), indices into ``vertices``.
    parts : one line per collision read, in document order, e.g.
        ``"walls/walls_link/walls_collision: mesh walls.stl, 2,864 triangles"``.
    part_triangles : how many of ``triangles`` each part has, in the same order (the
        triangles of part k are ``triangles[sum(part_triangles[:k]):][:part_triangles[k]]``).
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int32]
    parts: tuple[str, ...]
    part_triangles: tuple[int, ...] = ()
    #: How many of ``vertices`` each part has: part k's are one run, after those of parts < k,
    #: and only its triangles use them.
    part_vertices: tuple[int, ...] = ()

    def part(self, k: int) -> NDArray[np.float64]:
        """The triangles of part ``k`` as coordinates, float64 (T, 3, 3)."""
        start = sum(self.part_triangles[:k])
        rows = self.triangles[start : start + self.part_triangles[k]]
        return self.vertices[rows]


def read_world(
    world: Path,
    *,
    simulator: Simulator = "gz",
    files: Mapping[str, bytes] | None = None,
    model_paths: Sequence[Path] = (),
) -> WorldGeometry:
    """The collision triangles of ``world`` (.sdf or .world) as ``simulator``'s physics places
    them (heightmaps and planes differ; see the module docstring).

    Parameters
    ----------
    world : Path
        The world file.
    simulator : "gz" or "classic"
        Whose physics: gz-sim with dartsim, or Gazebo Classic with ODE.
    files : mapping of str to bytes, optional
        File contents by path relative to the world's folder (POSIX, e.g.
        ``"models/m/model.sdf"``), looked up before the disk: a world folder not yet written.
    model_paths : sequence of Path
        Folders holding model folders, searched for ``model://`` after ``models/``.

    Raises
    ------
    InputError
        Naming the file at fault and the problem (see the module docstring).
    """
    if simulator not in SIMULATORS:
        raise ValueError(f"simulator must be one of {SIMULATORS}, got {simulator!r}")
    world = Path(world)
    reader = _Reader(Store(world, files, model_paths), simulator)
    reader.read_world(world)
    return reader.result(world)


# --------------------------------------------------------------------------- the walk


class _Reader:
    """Walks a world and collects its collision triangles in the world frame."""

    def __init__(self, store: Store, simulator: Simulator) -> None:
        self.store = store
        self.simulator = simulator
        self.vertices: list[NDArray[np.float64]] = []
        self.faces: list[NDArray[np.integer]] = []
        self.parts: list[str] = []
        self.part_triangles: list[int] = []
        self.part_vertices: list[int] = []
        self.triangle_count = 0
        self.vertex_count = 0
        self.world = Path()
        self.meshes: dict[str, tuple[NDArray[np.float64], NDArray[np.int64]]] = {}
        self.parser = etree.XMLParser(
            resolve_entities=False,
            no_network=True,
            huge_tree=False,
            load_dtd=False,
            remove_comments=True,
            remove_pis=True,
        )

    # ----------------------------------------------------------------- XML

    def parse(self, path: Path, what: str) -> etree._Element:
        root = self.xml(path, what)
        if root.tag != "sdf":
            raise InputError(path, f"not an SDF file: its root element is <{root.tag}>, not <sdf>")
        return root

    def xml(self, path: Path, what: str) -> etree._Element:
        data = self.store.read(path, what)
        try:
            return etree.fromstring(data, self.parser)
        except etree.XMLSyntaxError as exc:
            raise InputError(path, f"not XML: {exc}") from None

    # ----------------------------------------------------------------- world, models

    def read_world(self, path: Path) -> None:
        self.world = path
        root = self.parse(path, "world file")
        container = root.find("world")
        if container is None:
            if root.find("model") is None:
                raise InputError(path, "an SDF file without a <world> (or a <model>)")
            container = root
        self.children(container, sdf.IDENTITY, "", path, (os.path.normpath(path),))

    def children(
        self,
        el: etree._Element,
        transform: NDArray[np.float64],
        prefix: str,
        source: Path,
        stack: tuple[str, ...],
    ) -> None:
        for child in el:
            if child.tag == "model":
                self.model(child, transform, prefix, source, stack)
            elif child.tag == "include":
                self.include(child, transform, prefix, source, stack)
            elif child.tag == "link" and prefix:
                self.link(child, transform, prefix, source)

    def model(
        self,
        el: etree._Element,
        parent: NDArray[np.float64],
        prefix: str,
        source: Path,
        stack: tuple[str, ...],
        *,
        pose: NDArray[np.float64] | None = None,
        name: str | None = None,
    ) -> None:
        own = name or el.get("name") or "model"
        full = f"{prefix}::{own}" if prefix else own
        local = sdf.pose(el, source, ("", "world", "__model__")) if pose is None else pose
        self.children(el, parent @ local, full, source, stack)

    def include(
        self,
        el: etree._Element,
        parent: NDArray[np.float64],
        prefix: str,
        source: Path,
        stack: tuple[str, ...],
    ) -> None:
        where = sdf.where(el)
        uri = (el.findtext("uri") or "").strip()
        if not uri:
            raise InputError(source, f"{where} has no <uri>")
        if el.find("placement_frame") is not None:
            raise InputError(source, f"{where}: <placement_frame> is not supported")
        target = self.store.resolve(uri, source, f"{where} <uri>")
        path = self.model_file(target, source, where) if self.store.is_dir(target) else target
        key = os.path.normpath(path)
        if key in stack:
            loop = " -> ".join([*stack[stack.index(key) :], key])
            raise InputError(source, f"{where}: {uri!r} includes itself ({loop})")
        if len(stack) > MAX_INCLUDE_DEPTH:
            raise InputError(source, f"{where}: includes nested over {MAX_INCLUDE_DEPTH} deep")
        root = self.parse(path, "model file")
        included = root.find("model")
        if included is None:
            if root.find("light") is not None or root.find("actor") is not None:
                return  # lights and actors have no collisions
            raise InputError(path, f"holds no <model> (included at {source}, {where})")
        pose_el = el.find("pose")
        pose = None if pose_el is None else sdf.pose_of(pose_el, source, ("", "world", "__model__"))
        name = (el.findtext("name") or "").strip() or None
        self.model(included, parent, prefix, path, (*stack, key), pose=pose, name=name)

    def model_file(self, folder: Path, source: Path, where: str) -> Path:
        """The SDF file of a model folder: what its model.config names, else model.sdf."""
        config = folder / "model.config"
        if self.store.is_file(config):
            root = self.xml(config, "model.config")
            best: tuple[tuple[int, ...], str] | None = None
            for sdf in root.iter("sdf"):
                name = (sdf.text or "").strip()
                version = tuple(int(p) for p in sdf.get("version", "0").split(".") if p.isdigit())
                if name and (best is None or version > best[0]):
                    best = (version, name)
            if best is not None:
                return folder / best[1]
        model_sdf = folder / "model.sdf"
        if not self.store.is_file(model_sdf):
            raise InputError(
                source, f"{where}: the model folder {folder} has neither model.config nor model.sdf"
            )
        return model_sdf

    def link(
        self, el: etree._Element, parent: NDArray[np.float64], model: str, source: Path
    ) -> None:
        name = el.get("name") or "link"
        transform = parent @ sdf.pose(el, source, ("", "__model__"))
        for collision in el.iterchildren("collision"):
            self.collision(collision, transform, f"{model}/{name}", name, source)

    # ----------------------------------------------------------------- collisions

    def collision(
        self,
        el: etree._Element,
        parent: NDArray[np.float64],
        label: str,
        link: str,
        source: Path,
    ) -> None:
        label = f"{label}/{el.get('name') or 'collision'}"
        transform = parent @ sdf.pose(el, source, ("", link))
        geometry = el.find("geometry")
        if geometry is None:
            raise InputError(source, f"{sdf.where(el)} has no <geometry>")
        found = [c for c in geometry if isinstance(c.tag, str)]
        kinds = {c.tag for c in found}
        if not found or kinds == {"empty"}:
            self.parts.append(f"{label}: empty, 0 triangles")
            self.part_triangles.append(0)
            self.part_vertices.append(0)
            return
        if kinds == {"polyline"}:
            self.polyline(found, transform, label, source)
            return
        if len(found) > 1:
            raise InputError(source, f"{sdf.where(geometry)} holds more than one shape")
        shape = found[0]
        rotation, translation = transform[:3, :3], transform[:3, 3]
        try:
            if shape.tag == "mesh":
                self.mesh(shape, transform, label, source)
            elif shape.tag == "heightmap":
                self.heightmap(shape, rotation, translation, label, source)
            elif shape.tag == "plane":
                normal = sdf.field(shape, "normal", source, 3)
                v, f, note = shapes.plane(normal, rotation, translation, self.simulator)
                self.add(label, f"plane, {note}", v, f)
            else:
                v, f, what = self.primitive(shape, source)
                self.add(label, what, v @ rotation.T + translation, f)
        except shapes.ShapeError as exc:
            raise InputError(source, f"{sdf.where(shape)}: {exc}") from None

    def primitive(
        self, shape: etree._Element, source: Path
    ) -> tuple[NDArray[np.float64], NDArray[np.int64], str]:
        tag = shape.tag

        def positive(name: str, count: int, zero: bool = False) -> NDArray[np.float64]:
            values = sdf.field(shape, name, source, count)
            if (values < 0).any() or (not zero and (values == 0).any()):
                child = shape.find(name)
                raise InputError(
                    source,
                    f"{sdf.where(shape if child is None else child)} must be "
                    f"{'non-negative' if zero else 'positive'}, got {' '.join(map(_num, values))}",
                )
            return values

        if tag == "box":
            size = positive("size", 3, zero=True)
            v, f, _ = shapes.box(size)
            return v, f, f"box {' x '.join(map(_num, size))} m"
        if tag == "cylinder":
            r, length = positive("radius", 1)[0], positive("length", 1, zero=True)[0]
            v, f, note = shapes.cylinder(r, length)
            return v, f, f"cylinder r {_num(r)} m, length {_num(length)} m, {note}"
        if tag == "capsule":
            r, length = positive("radius", 1)[0], positive("length", 1, zero=True)[0]
            v, f, note = shapes.capsule(r, length)
            return v, f, f"capsule r {_num(r)} m, length {_num(length)} m, {note}"
        if tag == "sphere":
            r = positive("radius", 1)[0]
            v, f, note = shapes.ellipsoid(np.full(3, r))
            return v, f, f"sphere r {_num(r)} m, {note}"
        if tag == "ellipsoid":
            radii = positive("radii", 3)
            v, f, note = shapes.ellipsoid(radii)
            return v, f, f"ellipsoid radii {' '.join(map(_num, radii))} m, {note}"
        raise InputError(source, f"{sdf.where(shape)} is not a geometry read here (only {_SHAPES})")

    def polyline(
        self,
        lines: list[etree._Element],
        transform: NDArray[np.float64],
        label: str,
        source: Path,
    ) -> None:
        rings = []
        heights = []
        for line in lines:
            rings.append(sdf.points(line, source))
            heights.append(float(sdf.field(line, "height", source, 1)[0]))
        height = heights[0]
        if not height > 0:
            raise InputError(
                source, f"{sdf.where(lines[0])}: <height> must be positive, got {_num(height)}"
            )
        try:
            v, f, note = shapes.polyline(rings, height)
        except shapes.ShapeError as exc:
            raise InputError(source, f"{sdf.where(lines[0])}: {exc}") from None
        if len(set(heights)) > 1:
            note += " (their heights differ: Gazebo extrudes all to the first one's)"
        rotation, translation = transform[:3, :3], transform[:3, 3]
        self.add(
            label, f"polyline {note}, height {_num(height)} m", v @ rotation.T + translation, f
        )

    def mesh(
        self, shape: etree._Element, transform: NDArray[np.float64], label: str, source: Path
    ) -> None:
        where = sdf.where(shape)
        uri = (shape.findtext("uri") or "").strip()
        if not uri:
            raise InputError(source, f"{where} has no <uri>")
        if shape.find("submesh") is not None:
            raise InputError(source, f"{where}: <submesh> is not supported (the whole mesh is)")
        scale = sdf.field(shape, "scale", source, 3)
        path = self.store.resolve(uri, source, f"{where} <uri>")
        kind = MESH_FORMATS.get(path.suffix.lower())
        if kind is None:
            raise InputError(
                path, f"mesh format {path.suffix or '(none)'!r} is not read (STL, OBJ, COLLADA)"
            )
        key = os.path.normpath(path)
        if key not in self.meshes:
            data = self.store.read(path, "mesh file")
            try:
                self.meshes[key] = load_mesh(data, kind)
            except MeshError as exc:
                raise InputError(path, str(exc)) from None
        vertices, faces = self.meshes[key]
        local = vertices * scale
        rotation, translation = transform[:3, :3], transform[:3, 3]
        scaled = "" if (scale == 1).all() else f" scaled {' '.join(map(_num, scale))}"
        self.add(label, f"mesh {path.name}{scaled}", local @ rotation.T + translation, faces)

    def heightmap(
        self,
        shape: etree._Element,
        rotation: NDArray[np.float64],
        translation: NDArray[np.float64],
        label: str,
        source: Path,
    ) -> None:
        where = sdf.where(shape)
        uri = (shape.findtext("uri") or "").strip()
        if not uri:
            raise InputError(source, f"{where} has no <uri>")
        size = sdf.field(shape, "size", source, 3)
        problem = hm.size_problem(size)
        if problem is not None:
            raise InputError(source, f"{where} <size>: {problem}")
        pos = sdf.field(shape, "pos", source, 3)
        sampling_el = shape.find("sampling")
        sampling_text = "1" if sampling_el is None else (sampling_el.text or "").strip()
        if not sampling_text.isdigit() or int(sampling_text) < 1:
            raise InputError(source, f"{where} <sampling> must be a positive integer")
        sampling = int(sampling_text)
        path = self.store.resolve(uri, source, f"{where} <uri>")
        first, colour, full = heightmap_image(self.store.read(path, "image file"), path)
        width = first.shape[1]
        used = hm.CLASSIC_SUBSAMPLING if self.simulator == "classic" else sampling
        n = hm.vertex_count(width, used)
        if self.triangle_count + 2 * (n - 1) ** 2 > MAX_TRIANGLES:
            raise InputError(
                source,
                f"{where}: a {width}x{width} image sampled {used}x is {2 * (n - 1) ** 2:,} "
                f"triangles; with the rest, over the budget of {MAX_TRIANGLES:,}",
            )
        try:
            v, f, note = hm.heightmap(
                first,
                colour,
                full,
                size=size,
                pos=pos,
                sampling=sampling,
                simulator=self.simulator,
                rotation=rotation,
                translation=translation,
            )
        except hm.HeightmapError as exc:
            raise InputError(path, str(exc)) from None
        self.add(label, f"heightmap {path.name}, {note}", v, f)

    def add(
        self, label: str, what: str, vertices: NDArray[np.float64], faces: NDArray[np.integer]
    ) -> None:
        self.triangle_count += len(faces)
        if self.triangle_count > MAX_TRIANGLES:
            raise InputError(
                self.world,
                f"over {MAX_TRIANGLES:,} collision triangles (at {label}: {what}); "
                "too large to check",
            )
        self.vertices.append(vertices)
        self.faces.append(faces)
        self.vertex_count += len(vertices)
        self.parts.append(f"{label}: {what}, {len(faces):,} triangles")
        self.part_triangles.append(len(faces))
        self.part_vertices.append(len(vertices))

    def result(self, world: Path) -> WorldGeometry:
        if self.triangle_count == 0:
            raise InputError(
                world,
                "no collision geometry: no model of the world has a <collision> with a shape",
            )
        if len(self.vertices) == 1:
            vertices = self.vertices[0]
            triangles = self.faces[0].astype(np.int32, copy=False)
        else:
            vertices = np.empty((self.vertex_count, 3))
            triangles = np.empty((self.triangle_count, 3), dtype=np.int32)
            v0 = t0 = 0
            while self.vertices:
                v = self.vertices.pop(0)
                f = self.faces.pop(0)
                vertices[v0 : v0 + len(v)] = v
                np.add(f, v0, out=triangles[t0 : t0 + len(f)], casting="unsafe")
                v0 += len(v)
                t0 += len(f)
        return WorldGeometry(
            np.ascontiguousarray(vertices),
            np.ascontiguousarray(triangles),
            tuple(self.parts),
            tuple(self.part_triangles),
            tuple(self.part_vertices),
        )


def _num(value: float) -> str:
    return f"{float(value):g}"
