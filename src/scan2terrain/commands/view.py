"""``scan2terrain view OUT/``: a world folder in the browser, served by viser.

viser (Apache-2.0) is a local web server whose three.js client ships in its wheel, so the page
works offline, from pip, with no Gazebo. What is shown is what the physics gets: each world's
collision triangles read back from its files (:func:`~scan2terrain.readers.world.read_world`,
heightmaps triangulated as gz-physics' dartsim or Classic's ODE lays them out), one mesh per
``<collision>``, under ``/gz`` and ``/classic`` (a folder written for both simulators shows
gz-sim's, with a switch to Classic's where they differ); the spawn pose of that world (a
robot-sized box and a heading arrow); ``trajectory.tum`` when present (the sensor's path); and
the figures of ``fidelity.yaml`` when present. Nothing is written into the folder.

:func:`load_folder` reads (and refuses what is not a world folder, as the other commands refuse
their inputs), :class:`Viewer` serves; the command line's ``view`` runs one until Ctrl-C.
"""

from __future__ import annotations

import math
import socket
import threading
import webbrowser
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import ConfigError, InputError
from scan2terrain.exporters.fidelity import CLASSES, HIT_NOTHING, NOTHING
from scan2terrain.exporters.render3d import ROBOT_BOX, SPAWN_RGB
from scan2terrain.exporters.sdf import is_ground
from scan2terrain.readers.cloudfile import read_cloud
from scan2terrain.readers.tracks import read_tum
from scan2terrain.readers.world import SIMULATORS, Simulator, WorldGeometry, read_world
from scan2terrain.world.folder import WORLD_FILES

if TYPE_CHECKING:
    import viser

#: Beam end points sent to the browser at most (a bag's replay can have millions).
MAX_ENDS = 500_000
GROUND_RGB = (105, 145, 105)
SOLID_RGB = (190, 95, 65)
TERRAIN_RGB = (200, 180, 120)
PATH_RGB = (30, 90, 230)


@dataclass(frozen=True)
class SimScene:
    """One simulator's world in the folder: its collisions and spawn pose."""

    simulator: Simulator
    geometry: WorldGeometry
    #: x, y, z, roll, pitch, yaw in this world's frame (spawn.yaml), or None.
    spawn: tuple[float, ...] | None


@dataclass(frozen=True)
class Folder:
    """A world folder, read for viewing."""

    path: Path
    worlds: tuple[SimScene, ...]
    trajectory: NDArray[np.float64] | None  #: (N, 3) sensor positions, trajectory.tum
    fidelity: dict[str, Any] | None  #: fidelity.yaml as read
    #: fidelity_ends.ply: the replayed beams' end points (N, 3) and their errors (N,), or None
    ends: tuple[NDArray[np.float64], NDArray[np.float32]] | None = None

    @property
    def differ(self) -> bool:
        """Whether the simulators' collision geometry differs (then both are offered)."""
        if len(self.worlds) < 2:
            return False
        a, b = (w.geometry for w in self.worlds[:2])
        return a.vertices.shape != b.vertices.shape or not (
            np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)
        )


def load_folder(path: Path) -> Folder:
    """The worlds, spawn poses, trajectory and fidelity figures of a world folder.

    Raises
    ------
    InputError
        ``path`` is not a folder, holds no world file of ours, or a file in it is broken.
    """
    import yaml

    path = Path(path)
    if not path.is_dir():
        raise InputError(path, "not a folder (view takes a world folder written by scan2terrain)")
    files = [(sim, path / WORLD_FILES[sim]) for sim in SIMULATORS]
    present = [(sim, file) for sim, file in files if file.is_file()]
    if not present:
        raise InputError(
            path, "not a world folder: it holds neither world_gz.sdf nor world_classic.world"
        )
    spawns = _spawns(path / "spawn.yaml", yaml)
    # Both simulators' worlds at once (numpy lets go of the GIL): to know whether they differ.
    with ThreadPoolExecutor(max_workers=len(present)) as pool:
        read = [pool.submit(read_world, file, simulator=sim) for sim, file in present]
        worlds = tuple(
            SimScene(sim, job.result(), spawns.get(sim))
            for (sim, _), job in zip(present, read, strict=True)
        )
    trajectory = _trajectory(path / "trajectory.tum")
    fidelity = None
    if (path / "fidelity.yaml").is_file():
        fidelity = _yaml_mapping(path / "fidelity.yaml", yaml)
    return Folder(path, worlds, trajectory, fidelity, _ends(path / "fidelity_ends.ply"))


def _ends(file: Path) -> tuple[NDArray[np.float64], NDArray[np.float32]] | None:
    """fidelity_ends.ply's points and their ``error``, or None when absent."""
    if not file.is_file():
        return None
    cloud = read_cloud(file, attributes=True)
    error = cloud.attributes.get("error")
    if error is None or len(error) != len(cloud.points):
        raise InputError(file, "has no per-point 'error' (a fidelity_ends.ply names it)")
    return cloud.points, np.asarray(error, dtype=np.float32)


def _yaml_mapping(file: Path, yaml: Any) -> dict[str, Any]:
    try:
        doc = yaml.safe_load(file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(file, f"cannot be read as YAML ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise InputError(file, "not a YAML mapping")
    return doc


def _spawns(file: Path, yaml: Any) -> dict[str, tuple[float, ...]]:
    """Each simulator's spawn pose in spawn.yaml (none when the file is absent)."""
    if not file.is_file():
        return {}
    doc = _yaml_mapping(file, yaml)
    poses: dict[str, tuple[float, ...]] = {}
    for sim in SIMULATORS:
        entry = doc.get(sim)
        if entry is None:
            continue
        pose = entry.get("pose") if isinstance(entry, dict) else None
        if (
            not isinstance(pose, list)
            or len(pose) != 6
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in pose)
            or max(abs(v) for v in pose) > 1e7
        ):
            raise InputError(file, f"{sim}.pose must be six finite numbers, got {pose!r}")
        poses[sim] = tuple(float(v) for v in pose)
    return poses


def _trajectory(file: Path) -> NDArray[np.float64] | None:
    """The positions of trajectory.tum (t x y z qx qy qz qw per line), or None."""
    if not file.is_file():
        return None
    positions: NDArray[np.float64] = read_tum(file).translations
    return positions


class Viewer:
    """A viser server showing a :class:`Folder`; :meth:`stop` ends it.

    ``meshes`` counts the meshes sent (collisions of every simulator shown, the robot box).
    """

    def __init__(self, folder: Folder, *, host: str = "127.0.0.1", port: int = 8080) -> None:
        import viser

        self.folder = folder
        self.server = _server(viser, host, port)
        self.meshes = 0
        self._stopped = threading.Event()
        self._show(self.server)

    @property
    def url(self) -> str:
        host = self.server.get_host()
        shown = "localhost" if host in ("127.0.0.1", "::1", "localhost") else host
        return f"http://{shown}:{self.server.get_port()}"

    def stop(self) -> None:
        self.server.stop()
        self._stopped.set()

    def wait(self) -> None:
        """Until :meth:`stop` (from another thread) or Ctrl-C."""
        self._stopped.wait()

    def _show(self, server: viser.ViserServer) -> None:
        folder = self.folder
        server.scene.set_up_direction("+z")
        # Shadows and the image-based light cost seconds a frame when WebGL renders in software
        # (no GPU: SwiftShader); plain lights keep the first frame quick there.
        server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        server.scene.configure_environment_map(hdri=None)
        server.scene.add_light_hemisphere(
            "/light/sky", sky_color=(255, 255, 255), ground_color=(120, 110, 100), intensity=1.6
        )
        shown = folder.worlds if folder.differ else folder.worlds[:1]
        parts = {scene.simulator: _parts(scene.geometry) for scene in shown}
        handles: dict[str, list[Any]] = {
            scene.simulator: self._world(server, scene, parts[scene.simulator]) for scene in shown
        }
        first = shown[0]
        if first.spawn is not None:
            self._spawn(server, first.spawn)
        if folder.trajectory is not None and len(folder.trajectory) > 1:
            path = folder.trajectory
            segments = np.stack([path[:-1], path[1:]], axis=1).astype(np.float32)
            server.scene.add_line_segments(
                "/trajectory",
                points=segments,
                colors=PATH_RGB,
                thickness=2.0,
                thickness_units="screen",
            )
        if folder.ends is not None:
            self._ends(server, *folder.ends)
        self._panel(server, shown, handles)
        _look_at(server, first.geometry, parts[first.simulator])

    def _world(self, server: viser.ViserServer, scene: SimScene, parts: list[Part]) -> list[Any]:
        g = scene.geometry
        out = []
        for k, (part, rows, first, last) in enumerate(parts):
            name = part.split(":", 1)[0].replace("/", "_")
            colour = _colour(part)
            out.append(
                server.scene.add_mesh_simple(
                    f"/{scene.simulator}/{k:04d}_{name}",
                    vertices=g.vertices[first : last + 1].astype(np.float32),
                    faces=(rows - first).astype(np.uint32),
                    color=colour,
                    flat_shading=True,
                    # Our solids wind outward and our heightmaps upward (preview3d's culling
                    # test): back faces are hidden, and culling them halves a software
                    # renderer's work.
                    side="front",
                    visible=scene.simulator == self.folder.worlds[0].simulator,
                )
            )
            self.meshes += 1
        return out

    def _ends(
        self, server: viser.ViserServer, points: NDArray[np.float64], error: NDArray[np.float32]
    ) -> None:
        """The replayed beams' end points, coloured by error class as fidelity.png is (at most
        :data:`MAX_ENDS` of them, every k-th, for the browser)."""
        step = max(1, -(-len(points) // MAX_ENDS))
        points, error = points[::step], error[::step]
        bounds = np.array([c[0] for c in CLASSES[:-1]])
        colours = np.array([c[2] for c in CLASSES] + [NOTHING[1]], dtype=np.uint8)
        kind = np.where(error == HIT_NOTHING, len(CLASSES), np.searchsorted(bounds, error))
        server.scene.add_point_cloud(
            "/fidelity/ends",
            points=points.astype(np.float32),
            colors=colours[kind],
            point_size=0.03,
            point_shape="circle",
        )

    def _spawn(self, server: viser.ViserServer, pose: tuple[float, ...]) -> None:
        x, y, z, _, _, yaw = pose
        wxyz = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        length, width, height = ROBOT_BOX
        server.scene.add_frame(
            "/spawn", wxyz=wxyz, position=(x, y, z), axes_length=0.8, axes_radius=0.02
        )
        server.scene.add_box(
            "/spawn/robot",
            dimensions=(length, width, height),
            position=(0.0, 0.0, height / 2),
            color=SPAWN_RGB,
        )
        self.meshes += 1

    def _panel(
        self, server: viser.ViserServer, shown: tuple[SimScene, ...], handles: dict[str, list[Any]]
    ) -> None:
        folder = self.folder
        lines = [f"**{folder.path.name}/**"]
        for scene in shown:
            g = scene.geometry
            lines.append(
                f"- {scene.simulator}: {len(g.parts)} collisions, {len(g.triangles):,} triangles"
            )
        if len(folder.worlds) > 1 and not folder.differ:
            lines.append("- gz-sim and Classic collide with the same triangles")
        if folder.fidelity is not None:
            lines += _fidelity_lines(folder.fidelity)
        server.gui.add_markdown("\n".join(lines))
        if len(shown) > 1:
            pick = server.gui.add_dropdown(
                "Simulator",
                options=tuple(s.simulator for s in shown),
                initial_value=shown[0].simulator,
            )

            @pick.on_update
            def _(_: Any) -> None:
                for sim, meshes in handles.items():
                    for mesh in meshes:
                        mesh.visible = sim == pick.value


#: A collision's name, its triangles, and the first and last vertex they use.
Part = tuple[str, NDArray[np.int32], int, int]


def _parts(g: WorldGeometry) -> list[Part]:
    """Each collision's name, triangles and the first and last vertex they use."""
    out = []
    start = vertex = 0
    for part, count, vertices in zip(g.parts, g.part_triangles, g.part_vertices, strict=True):
        out.append((part, g.triangles[start : start + count], vertex, vertex + vertices - 1))
        start += count
        vertex += vertices
    return out


def _fidelity_lines(doc: dict[str, Any]) -> list[str]:
    """fidelity.yaml's overall figures, one line per world replayed in."""
    lines = ["", "**Fidelity** (the recording replayed in the world)"]
    worlds = doc.get("worlds")
    for world, f in (worlds if isinstance(worlds, dict) else {}).items():
        if not isinstance(f, dict):
            continue
        within, median = f.get("within_10cm"), f.get("median")
        shown = [f"{f.get('beams', '?')} beams"]
        if isinstance(within, (int, float)):
            shown.append(f"{within:.1%} within 10 cm")
        if isinstance(median, (int, float)):
            shown.append(f"median error {median * 100:.1f} cm")
        lines.append(f"- {world}: {', '.join(shown)}")
    lines.append("- end points: " + ", ".join(c[1] for c in CLASSES) + ", hit nothing (purple)")
    return lines


def _colour(part: str) -> tuple[int, int, int]:
    if is_ground(part):
        return GROUND_RGB
    if ": heightmap" in part:
        return TERRAIN_RGB
    return SOLID_RGB


def _bounds(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Lowest and highest x, y, z (column by column: ten times numpy's ``min(axis=0)`` on
    millions of rows)."""
    columns = [points[:, k] for k in range(3)]
    return np.array([c.min() for c in columns]), np.array([c.max() for c in columns])


def _look_at(server: viser.ViserServer, g: WorldGeometry, parts: list[Part]) -> None:
    """New clients look from the south-west at what stands on the ground (a small room's
    ground slab is 10 m wider each way), as preview3d.png does."""
    boxes = [
        _bounds(g.vertices[first : last + 1])
        for part, _, first, last in parts
        if last >= first and not is_ground(part)
    ]
    if not boxes:
        boxes = [_bounds(g.vertices)]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    centre = (lo + hi) / 2
    reach = max(float(np.linalg.norm(hi - lo)), 1.0)
    eye = centre + np.array([-0.5, -0.45, 0.65]) * reach
    server.initial_camera.position = eye.astype(np.float64)
    server.initial_camera.look_at = centre.astype(np.float64)
    # A 3 km terrain lies beyond three.js's default far plane of 1 km.
    low, high = _bounds(g.vertices)
    whole = float(np.linalg.norm(high - low))
    server.initial_camera.near = max(0.01, reach * 1e-4)
    server.initial_camera.far = max(1000.0, 4.0 * (whole + reach))


def _server(viser: Any, host: str, port: int) -> Any:
    """A viser server on exactly ``host:port`` (viser would quietly take the next free port)."""
    if not 1 <= port <= 65535:
        raise ConfigError(f"--port must be a TCP port, 1 to 65535, got {port}")

    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            raise InputError(
                f"{host}:{port}",
                f"cannot serve there ({exc.strerror}); pick another --port or --host",
            ) from None
    return viser.ViserServer(host=host, port=port, verbose=False)


def view(out: Path, *, host: str, port: int, browser: bool) -> str:
    """Serve ``out`` until Ctrl-C; the report line for the command line."""
    folder = load_folder(out)
    viewer = Viewer(folder, host=host, port=port)
    print(f"Viewing {out}/ at {viewer.url} ({viewer.meshes} meshes; Ctrl-C stops)", flush=True)
    if browser:
        webbrowser.open(viewer.url)
    try:
        viewer.wait()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return f"Stopped viewing {out}/"
