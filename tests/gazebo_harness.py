"""Check generated worlds with Gazebo's own code (SDFormat 12 + gz-common 4).

The C++ program ``tests/gazebo/heightmap_probe.cpp`` parses a world strictly with
``sdf::Root::Load`` and rebuilds every collision heightmap the way gz-physics' dartsim
plugin does (``ImageHeightmap::FillHeightMap``). This module compiles it once per
source revision, runs it, and turns its JSON into :class:`HeightmapProbe` objects
(:func:`probe_world`), or, for worlds of walls, :class:`ShapeProbe` objects for every other
geometry: boxes, planes, meshes as gz-common's mesh loader reads them, and polylines as
gz-common extrudes them for gz-sim (:func:`probe_shapes`).

:func:`terrain_height` then answers "how high is the ground at world (x, y)?" as each
simulator lays the field out. The placement rules, with the upstream files they come
from, are documented next to the code that implements them.

Debian packages needed: ``libsdformat-dev`` (pkg-config ``sdformat12``),
``libignition-common-graphics-dev`` (pkg-config ``ignition-common4-graphics``),
``pkg-config`` and ``g++``. Missing tools raise :class:`RuntimeError`; nothing is
skipped silently.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import math
import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np

TESTS_DIR = Path(__file__).resolve().parent
PROBE_SOURCE = TESTS_DIR / "gazebo" / "heightmap_probe.cpp"
BUILD_ROOT = TESTS_DIR / ".build"
PKG_MODULES = ("sdformat12", "ignition-common4-graphics")
INSTALL_HINT = "apt-get install libsdformat-dev libignition-common-graphics-dev pkg-config g++"

Simulator = Literal["gz", "classic"]

# Gazebo Classic's physics samples every image with subSampling = 2, whatever
# <sampling> says: gazebo-classic gazebo/physics/HeightmapShape.cc,
# HeightmapShape::Init(): "subSampling = 2; vertSize = (width * subSampling) - 1"
# (2*W - 1 = W*s - s + 1 for s = 2). Every version of that file we could read
# hard-codes it; the <sampling> element is read only by SDFormat / rendering.
CLASSIC_SUBSAMPLING = 2


class SdfParseError(Exception):
    """SDFormat 12 rejected the world in strict mode; ``str(err)`` is its stderr."""


class ProbeError(RuntimeError):
    """The probe parsed the world but could not rebuild a heightmap (exit status 2)."""


@dataclass
class HeightmapProbe:
    """One ``<heightmap>`` geometry as SDFormat 12 / gz-common 4 see it.

    ``pose`` is the collision/visual frame in the WORLD frame
    ``(x, y, z, roll, pitch, yaw)``. Collision-only fields are ``None`` for visuals.
    ``sdf_original_version`` is the ``<sdf version>`` written in the file (SDFormat 12
    converts every document to 1.9, which is what ``root.Version()`` reports).
    ``heights`` is ``(vert_size, vert_size)`` float64, row-major exactly as
    ``ImageHeightmap::FillHeightMap(flipY=false)`` fills it: row 0 = image top row,
    column 0 = image left column.
    """

    model: str
    link: str
    kind: Literal["collision", "visual"]
    name: str
    pose: tuple[float, float, float, float, float, float]
    pose_method: str
    uri: str
    sdf_file: str
    path: Path | None
    size: tuple[float, float, float]
    pos: tuple[float, float, float]
    sampling: int
    use_terrain_paging: bool
    textures: int
    blends: int
    sdf_original_version: str = ""
    image_width: int | None = None
    image_height: int | None = None
    image_bpp: int | None = None
    vert_size: int | None = None
    scale: tuple[float, float, float] | None = None
    max_elevation_called: bool | None = None
    max_elevation_reported: float | None = None
    max_elevation: float | None = None
    max_elevation_fallback: bool | None = None
    heights_file: Path | None = None
    heights: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class SubMeshProbe:
    """One submesh of a mesh as gz-common 4's ``MeshManager::Load`` returns it: its triangle
    count and its material's diffuse and ambient colours (RGBA, 0..1; None when the submesh has
    no material). gz-common's COLLADA loader makes one submesh per ``<triangles>`` element,
    with the material that element names."""

    triangles: int
    material: int | None
    diffuse: tuple[float, float, float, float] | None
    ambient: tuple[float, float, float, float] | None


@dataclass
class ShapeProbe:
    """One non-heightmap ``<geometry>`` of a collision or visual, as SDFormat 12 parsed it.

    ``pose`` is the collision/visual frame in the WORLD frame ``(x, y, z, roll, pitch, yaw)``.
    ``type`` is ``box`` (``size`` x, y, z), ``plane`` (``size`` x, y; ``normal``), ``mesh``
    (``uri``, resolved ``path``, ``scale``; ``triangles`` (T, 3, 3) float64 in the mesh frame as
    gz-common 4's ``MeshManager::Load`` returns them, ``mesh_min``/``mesh_max``, and
    ``submeshes``, one :class:`SubMeshProbe` per submesh in order, None unless the mesh loaded;
    ``triangles`` holds the submeshes' triangles in that order), ``polyline``
    (``polylines``: one ``(height, points (N, 2))`` per ``<polyline>`` element of the geometry,
    read from the element tree: SDFormat 12.3 has no Polyline class) or ``other``.

    Polylines are also extruded as gz-sim builds them (gz-common 4's
    ``MeshManager::CreateExtrudedPolyline`` on every ``<polyline>``'s points, at the first one's
    height): ``extrusion`` is ``ok`` (``triangles`` (T, 3, 3) float64 in the geometry's frame,
    ``mesh_min``/``mesh_max``), ``failed`` (gz-common made no mesh: gz-sim has no collision or
    visual for it), ``crashed`` (the triangulation killed the process; ``extrusion_signal``) or
    ``timeout``; ``skipped`` with ``HEIGHTMAP_PROBE_EXTRUDE=0``. The probe extrudes in a forked
    child, so a crash is reported for its geometry and the others are still extruded.
    """

    model: str
    link: str
    kind: Literal["collision", "visual"]
    name: str
    pose: tuple[float, float, float, float, float, float]
    pose_method: str
    type: str
    size: tuple[float, ...] | None = None
    normal: tuple[float, float, float] | None = None
    uri: str | None = None
    path: Path | None = None
    scale: tuple[float, float, float] | None = None
    polylines: list[tuple[float, np.ndarray]] = field(default_factory=list, repr=False)
    mesh_loaded: bool | None = None
    mesh_min: tuple[float, float, float] | None = None
    mesh_max: tuple[float, float, float] | None = None
    triangles: np.ndarray | None = field(default=None, repr=False)
    extrusion: str | None = None
    extrusion_signal: int | None = None
    submeshes: list[SubMeshProbe] | None = field(default=None, repr=False)


# --------------------------------------------------------------------------- build


def _run(cmd: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, check=False)


def _missing(what: str, install_hint: str = INSTALL_HINT) -> RuntimeError:
    return RuntimeError(f"{what}; install the Gazebo test dependencies: {install_hint}")


def probe_binary(
    source_path: Path = PROBE_SOURCE,
    pkg_modules: tuple[str, ...] = PKG_MODULES,
    install_hint: str = INSTALL_HINT,
) -> Path:
    """Compile a probe (default ``heightmap_probe.cpp``) once per sha256 of its source and the
    ``*.hh`` headers beside it; its path.

    The binary ``<stem>`` lives in ``tests/.build/<stem>-<sha256[:16]>/`` (git-ignored),
    built with ``g++ -std=c++17 -O1`` against the ``pkg_modules`` pkg-config modules
    (``install_hint`` names the Debian packages that provide them). A file lock makes
    concurrent pytest workers build it only once. ``tests/physics_harness.py`` builds
    ``physics_probe.cpp`` with this same routine.
    """
    stem = source_path.stem
    # The source and the headers beside it (probe_common.hh, shared by both probes).
    hashed = hashlib.sha256(source_path.read_bytes())
    for header in sorted(source_path.parent.glob("*.hh")):
        hashed.update(header.read_bytes())
    digest = hashed.hexdigest()[:16]
    out_dir = BUILD_ROOT / f"{stem}-{digest}"
    binary = out_dir / stem
    if binary.is_file() and os.access(binary, os.X_OK):
        return binary

    for tool in ("g++", "pkg-config"):
        if shutil.which(tool) is None:
            raise _missing(f"`{tool}` not found on PATH", install_hint)
    exists = _run(["pkg-config", "--exists", *pkg_modules])
    if exists.returncode != 0:
        raise _missing(f"pkg-config cannot find {' / '.join(pkg_modules)}", install_hint)
    flags = _run(["pkg-config", "--cflags", "--libs", *pkg_modules])
    if flags.returncode != 0:
        raise _missing(f"pkg-config failed: {flags.stderr.strip()}", install_hint)

    out_dir.mkdir(parents=True, exist_ok=True)
    with (out_dir / ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if binary.is_file() and os.access(binary, os.X_OK):
            return binary
        tmp = out_dir / f"{stem}.tmp{os.getpid()}"
        cmd = [
            "g++", "-std=c++17", "-O1", "-o", str(tmp), str(source_path),
            *flags.stdout.split(),
        ]  # fmt: skip
        built = _run(cmd)
        if built.returncode != 0:
            tmp.unlink(missing_ok=True)
            raise RuntimeError(
                f"compiling {stem} failed (are the -dev packages complete? "
                f"{install_hint}):\n{' '.join(cmd)}\n{built.stderr}"
            )
        tmp.replace(binary)
    return binary


# --------------------------------------------------------------------------- probe


def _tuple(values: list[Any]) -> tuple[float, ...]:
    return tuple(float("nan") if v is None else float(v) for v in values)


def _xyz(values: list[Any]) -> tuple[float, float, float]:
    x, y, z = _tuple(values)
    return x, y, z


def _rgba(values: list[Any]) -> tuple[float, float, float, float]:
    r, g, b, a = _tuple(values)
    return r, g, b, a


def _pose(values: list[Any]) -> tuple[float, float, float, float, float, float]:
    x, y, z, roll, pitch, yaw = _tuple(values)
    return x, y, z, roll, pitch, yaw


def _to_probe(entry: dict[str, Any], original_version: str) -> HeightmapProbe:
    path = entry.get("path")
    probe = HeightmapProbe(
        model=entry["model"],
        link=entry["link"],
        kind=entry["kind"],
        name=entry["name"],
        pose=_pose(entry["pose"]),
        pose_method=entry["pose_method"],
        uri=entry["uri"],
        sdf_file=entry["sdf_file"],
        path=Path(path) if path else None,
        size=_xyz(entry["size"]),
        pos=_xyz(entry["pos"]),
        sampling=int(entry["sampling"]),
        use_terrain_paging=bool(entry["use_terrain_paging"]),
        textures=int(entry["textures"]),
        blends=int(entry["blends"]),
        sdf_original_version=original_version,
    )
    if probe.kind != "collision":
        return probe
    probe.image_width = int(entry["image_width"])
    probe.image_height = int(entry["image_height"])
    probe.image_bpp = int(entry["image_bpp"])
    probe.vert_size = int(entry["vert_size"])
    probe.scale = _xyz(entry["scale"])
    # ImageHeightmap::MaxElevation() as gz-common returned it; None when the probe did
    # not call it (16-bit images over 129x129: the call is known to fail there and
    # logs one line per pixel). max_elevation is what scale.z was computed from.
    probe.max_elevation_called = bool(entry["max_elevation_called"])
    reported = entry["max_elevation_reported"]
    probe.max_elevation_reported = None if reported is None else float(reported)
    probe.max_elevation = float(entry["max_elevation"])
    probe.max_elevation_fallback = bool(entry["max_elevation_fallback"])
    probe.heights_file = Path(entry["heights_file"])
    raw = np.fromfile(probe.heights_file, dtype="<f4")
    n = probe.vert_size
    if raw.size != n * n:
        raise ProbeError(f"{probe.heights_file}: {raw.size} floats, expected {n}*{n}")
    probe.heights = raw.astype(np.float64).reshape(n, n)
    return probe


def probe_world(world: Path, model_dirs: list[Path], tmp: Path) -> tuple[str, list[HeightmapProbe]]:
    """Parse ``world`` strictly with SDFormat 12 and rebuild its heightmaps.

    ``model_dirs`` are folders holding model folders (what ``model://NAME`` resolves
    against). Height fields are written under ``tmp``. Returns
    ``(sdf_version, probes)`` where ``sdf_version`` is ``root.Version()`` — the
    version SDFormat 12 converted the document to ("1.9"); the file's own version is
    ``probe.sdf_original_version``. Raises :class:`SdfParseError` when SDFormat rejects
    the file, :class:`ProbeError` when an image cannot be resolved or loaded.
    """
    doc = _run_probe(world, model_dirs, tmp)
    original = str(doc.get("sdf_original_version", ""))
    return str(doc["sdf_version"]), [_to_probe(e, original) for e in doc["heightmaps"]]


def probe_shapes(world: Path, model_dirs: list[Path], tmp: Path) -> tuple[str, list[ShapeProbe]]:
    """Parse ``world`` strictly with SDFormat 12 and return its non-heightmap geometries.

    As :func:`probe_world` (same strict parse, same errors; a mesh whose URI does not resolve
    raises :class:`ProbeError`), but returns ``(sdf_version, shapes)``.
    """
    doc = _run_probe(world, model_dirs, tmp)
    return str(doc["sdf_version"]), [_to_shape(e) for e in doc.get("shapes", [])]


def probe_spherical(world: Path, model_dirs: list[Path], tmp: Path) -> dict[str, Any] | None:
    """The first world's ``<spherical_coordinates>`` as SDFormat and gz-math read them (None
    without one): ``latitude_deg``, ``longitude_deg``, ``elevation``, ``heading_deg``, and
    ``points``: rows (x, y, z, latitude, longitude, elevation) of world points as gz-sim places
    them on the earth (gz-math's PositionTransform from the heading-adjusted world frame)."""
    doc = _run_probe(world, model_dirs, tmp)
    found: dict[str, Any] | None = doc.get("spherical")
    return found


def _to_shape(entry: dict[str, Any]) -> ShapeProbe:
    shape = ShapeProbe(
        model=entry["model"],
        link=entry["link"],
        kind=entry["kind"],
        name=entry["name"],
        pose=_pose(entry["pose"]),
        pose_method=entry["pose_method"],
        type=entry["type"],
    )
    if "size" in entry:
        shape.size = _tuple(entry["size"])
    if "normal" in entry:
        shape.normal = _xyz(entry["normal"])
    if shape.type == "mesh":
        shape.uri = entry["uri"]
        shape.path = Path(entry["path"]) if entry.get("path") else None
        shape.scale = _xyz(entry["scale"])
        shape.mesh_loaded = bool(entry.get("mesh_loaded", False))
        if shape.mesh_loaded:
            shape.mesh_min = _xyz(entry["mesh_min"])
            shape.mesh_max = _xyz(entry["mesh_max"])
            raw = np.fromfile(entry["triangles_file"], dtype="<f8")
            shape.triangles = raw.reshape(-1, 3, 3)
            shape.submeshes = [_to_submesh(s) for s in entry.get("submeshes", [])]
    for line in entry.get("polylines", []):
        points = np.asarray(line["points"], dtype=np.float64).reshape(-1, 2)
        shape.polylines.append((float(line["height"]), points))
    if shape.type == "polyline":
        shape.extrusion = str(entry["extrusion"])
        if shape.extrusion in ("crashed", "timeout"):
            shape.extrusion_signal = int(entry["extrusion_signal"])
        if shape.extrusion == "ok":
            shape.mesh_min = _xyz(entry["mesh_min"])
            shape.mesh_max = _xyz(entry["mesh_max"])
            raw = np.fromfile(entry["triangles_file"], dtype="<f8")
            shape.triangles = raw.reshape(-1, 3, 3)
    return shape


def _to_submesh(entry: dict[str, Any]) -> SubMeshProbe:
    def colour(key: str) -> tuple[float, float, float, float] | None:
        value = entry.get(key)
        return None if value is None else _rgba(value)

    material = entry.get("material")
    return SubMeshProbe(
        triangles=int(entry["triangles"]),
        material=None if material is None else int(material),
        diffuse=colour("diffuse"),
        ambient=colour("ambient"),
    )


def _run_probe(world: Path, model_dirs: list[Path], tmp: Path) -> dict[str, Any]:
    """Run the probe on ``world``; its JSON document."""
    binary = probe_binary()
    out_dir = Path(tmp) / f"probe-{hashlib.sha256(str(world).encode()).hexdigest()[:8]}"
    out_dir.mkdir(parents=True, exist_ok=True)
    cmd = [str(binary), str(Path(world).resolve()), str(out_dir)]
    cmd += [str(Path(d).resolve()) for d in model_dirs]
    result = _run(cmd)
    if result.returncode == 1:
        raise SdfParseError(result.stderr)
    if result.returncode != 0:
        raise ProbeError(
            f"heightmap_probe exited {result.returncode}:\n{result.stderr}\n{result.stdout}"
        )
    doc: dict[str, Any] = json.loads(result.stdout)
    return doc


# --------------------------------------------------------------------------- height


def _bilinear(heights: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Bilinear interpolation in a (V, V) grid; NaN outside [0, V-1]^2.

    DART (Bullet/ODE detectors) and ODE triangulate each cell, so the real surface
    is piecewise linear; at vertices and along grid lines bilinear gives the same value.
    """
    n = heights.shape[0]
    eps = 1e-9 * n
    inside = (row >= -eps) & (row <= n - 1 + eps) & (col >= -eps) & (col <= n - 1 + eps)
    r = np.clip(row, 0.0, n - 1.0)
    c = np.clip(col, 0.0, n - 1.0)
    r0 = np.clip(np.floor(r).astype(np.intp), 0, max(n - 2, 0))
    c0 = np.clip(np.floor(c).astype(np.intp), 0, max(n - 2, 0))
    r1 = np.minimum(r0 + 1, n - 1)
    c1 = np.minimum(c0 + 1, n - 1)
    fr = r - r0
    fc = c - c0
    top = heights[r0, c0] * (1 - fc) + heights[r0, c1] * fc
    bottom = heights[r1, c0] * (1 - fc) + heights[r1, c1] * fc
    value = top * (1 - fr) + bottom * fr
    return np.where(inside, value, np.nan)


def _yaw_only(pose: tuple[float, ...], what: str) -> float:
    roll, pitch, yaw = pose[3], pose[4], pose[5]
    if abs(roll) > 1e-9 or abs(pitch) > 1e-9:
        raise ValueError(f"{what}: roll/pitch {roll}, {pitch} != 0; not a height function")
    return yaw


@overload
def terrain_height(probe: HeightmapProbe, x: float, y: float, simulator: Simulator) -> float: ...
@overload
def terrain_height(
    probe: HeightmapProbe, x: np.ndarray, y: np.ndarray, simulator: Simulator
) -> np.ndarray: ...
def terrain_height(
    probe: HeightmapProbe, x: Any, y: Any, simulator: Simulator
) -> np.ndarray | float:
    """Ground height at WORLD point(s) (x, y) as ``simulator`` places the field.

    Vectorised over numpy arrays (an array for arrays of points, a float for one point);
    NaN outside the field. Only collision probes carry heights (physics only uses the
    collision).
    """
    if probe.kind != "collision" or probe.heights is None or probe.vert_size is None:
        raise ValueError(f"{probe.model}/{probe.name}: not a collision probe with heights")
    xs = np.asarray(x, dtype=np.float64)
    ys = np.asarray(y, dtype=np.float64)
    n = probe.vert_size
    half = (n - 1) / 2.0
    px, py, pz = probe.pose[0], probe.pose[1], probe.pose[2]

    if simulator == "gz":
        # gz-sim + gz-physics dartsim (the only gz-sim engine with heightmap collision).
        # * gz-sim src/systems/physics/Physics.cc attaches the shape with the
        #   COLLISION pose and heightmap Size()/Sampling(); <pos> is not passed
        #   (gz-sim #1295, #1803).
        # * gz-physics dartsim/src/ShapeFeatures.cc AttachHeightmapShape():
        #   sn->setRelativeTransform(_pose), i.e. the shape frame IS the collision frame.
        # * gz-physics dartsim/src/CustomHeightmapShape.cc: vertSize = W*s - s + 1,
        #   setScale(size.x / vertSize, size.y / vertSize, 1), heights from
        #   FillHeightMap(flipY=false): the vertex spacing is size/vertSize (NOT
        #   size/(vertSize-1)), so the field spans size*(V-1)/V, slightly less than size.
        # * DART dart/dynamics/HeightmapShape.hpp: "width goes in x direction and depth
        #   in -y ... images are read from top row to bottom row";
        #   dart/collision/bullet/BulletCollisionDetector.cpp
        #   createBulletCollisionShapeFromHeightmap(): flipY() then
        #   btHeightfieldTerrainShape, which Bullet centres on its AABB centre (x, y),
        #   and a z shift so heights stay absolute in the shape frame.
        # => vertex (r, c) at local x = (c - (V-1)/2)*dx, y = ((V-1)/2 - r)*dy,
        #    z = heights[r, c]; then the collision's world pose (x, y, z, yaw).
        yaw = _yaw_only(probe.pose, f"{probe.model}/{probe.name}")
        dx = probe.size[0] / n
        dy = probe.size[1] / n
        cy, sy = math.cos(yaw), math.sin(yaw)
        ex, ey = xs - px, ys - py
        u = cy * ex + sy * ey
        v = -sy * ex + cy * ey
        col = u / dx + half
        row = half - v / dy
        out = pz + _bilinear(probe.heights, row, col)
    elif simulator == "classic":
        # Gazebo Classic 11 with ODE (the only Classic engine that works with heightmaps).
        # * gazebo/physics/HeightmapShape.cc HeightmapShape::Init(): subSampling = 2
        #   (hard-coded), vertSize = W*2 - 1, scale.z = |size.z| / MaxElevation(),
        #   heights from gazebo/common/ImageHeightmap.cc FillHeightMap(), which reads
        #   the FIRST BYTE of each pixel / 255 (8-bit only) — same result as gz-common 4
        #   for 8-bit greyscale images, so the probe's heights are reused here.
        # * gazebo/physics/ode/ODEHeightmapShape.cc Init():
        #   dGeomHeightfieldDataBuildSingle(heights, width = size.x, depth = size.y,
        #   widthSamples = depthSamples = vertSize, scale 1.0, offset = <pos>.z, ...);
        #   SetCollision(dCreateHeightfield(0, data, 1), placeable = false) so Gazebo
        #   never moves the geom: it stays at the WORLD ORIGIN whatever the model /
        #   link / collision position (gazebo-classic #2167) and <pos> x/y are ignored
        #   (only <pos> z is used, as the ODE height offset). Its rotation IS set once:
        #   dGeomSetQuaternion(collision world rotation * Rx(90 deg)).
        # * ODE heightfield.cpp (gazebo-classic deps/opende/src/heightfield.cpp):
        #   m_fSampleWidth = width / (widthSamples - 1) and, without
        #   DHEIGHTFIELD_CORNER_ORIGIN, the grid is centred: local x = i*dx - width/2,
        #   local z = j*dz - depth/2, height = data[i + j*widthSamples]*scale + offset.
        #   Rx(+90 deg) maps local (x, up, z) to world (x, -z, up): row j grows to -y.
        # => vertex (r, c) at x = (c - (V-1)/2)*dx, y = ((V-1)/2 - r)*dy with
        #    dx = size.x/(V-1), rotated by the collision's world yaw about the world
        #    origin, z = heights[r, c] + <pos>.z.
        if probe.sampling != CLASSIC_SUBSAMPLING:
            raise ValueError(
                f"{probe.model}/{probe.name}: Gazebo Classic physics always samples with "
                f"{CLASSIC_SUBSAMPLING} (gazebo/physics/HeightmapShape.cc) but the probe "
                f"used <sampling>{probe.sampling}; use sampling {CLASSIC_SUBSAMPLING}"
            )
        if probe.image_bpp != 8:
            raise ValueError(
                f"{probe.model}/{probe.name}: Gazebo Classic reads only the first byte of "
                f"each pixel (gazebo/common/ImageHeightmap.cc); a {probe.image_bpp}-bit "
                "image does not give the heights gz-common computed"
            )
        yaw = _yaw_only(probe.pose, f"{probe.model}/{probe.name}")
        dx = probe.size[0] / (n - 1)
        dy = probe.size[1] / (n - 1)
        cy, sy = math.cos(yaw), math.sin(yaw)
        u = cy * xs + sy * ys
        v = -sy * xs + cy * ys
        col = u / dx + half
        row = half - v / dy
        out = probe.pos[2] + _bilinear(probe.heights, row, col)
    else:
        raise ValueError(f"unknown simulator {simulator!r}; expected 'gz' or 'classic'")

    if out.ndim == 0:
        return float(out)
    return out


def vertex_world_xy(
    probe: HeightmapProbe, row: Any, col: Any, simulator: Simulator
) -> tuple[np.ndarray, np.ndarray]:
    """World (x, y) of height-field vertex (row, col) — the inverse of terrain_height."""
    if probe.vert_size is None:
        raise ValueError("not a collision probe")
    n = probe.vert_size
    half = (n - 1) / 2.0
    r = np.asarray(row, dtype=np.float64)
    c = np.asarray(col, dtype=np.float64)
    yaw = _yaw_only(probe.pose, f"{probe.model}/{probe.name}")
    if simulator == "gz":
        dx, dy = probe.size[0] / n, probe.size[1] / n
        ox, oy = probe.pose[0], probe.pose[1]
    elif simulator == "classic":
        dx, dy = probe.size[0] / (n - 1), probe.size[1] / (n - 1)
        ox, oy = 0.0, 0.0
    else:
        raise ValueError(f"unknown simulator {simulator!r}")
    lx = (c - half) * dx
    ly = (half - r) * dy
    cy, sy = math.cos(yaw), math.sin(yaw)
    return ox + cy * lx - sy * ly, oy + sy * lx + cy * ly
