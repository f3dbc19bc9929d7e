"""Drive bodies through generated worlds with gz-sim's own physics (ign-physics 5, dartsim).

``tests/gazebo/physics_probe.cpp`` loads a world with SDFormat 12 and builds it in the
dartsim plugin the way ign-gazebo 6's Physics system does (``src/systems/physics/
Physics.cc``: ``CreateWorldEntities`` sets the ``<dart><collision_detector>`` before any
model, then ``CreateModelEntities``, ``CreateLinkEntities``, ``CreateCollisionEntities``
(heightmaps through gz-common ``ImageHeightmap`` + ``AttachHeightmapShape``, meshes
through ``MeshManager::Load`` + ``AttachMeshShape``, polylines through
``MeshManager::CreateExtrudedPolyline``), ``CreateJointEntities``), then spawns what a
:class:`Scenario` asks for (free spheres and boxes, a Husky-sized skid-steer robot driven
with ``SetJointVelocityCommand`` every step, or a robot model file driven through the joints
its DiffDrive plugin names), steps with a fixed ``dt`` and reports
load times, shapes built and failed, trajectories, first contacts
(``GetContactsFromLastStepFeature``) and the real-time factor of the step loop.

This module compiles it once per source revision (with
:func:`tests.gazebo_harness.probe_binary`, the routine that builds ``heightmap_probe``),
runs it as a subprocess and parses its JSON into typed results (:func:`simulate`). A
crash inside a dependency (gz-common's polyline triangulation is known to segfault) is a
:class:`SimResult` with ``signal`` set and the stage the probe was in, never silence;
helpers that need the numbers raise :class:`SimulationCrashed`.

What happens where, upstream:

* shapes: gz-physics ``dartsim/src/ShapeFeatures.cc`` (``AttachHeightmapShape``,
  ``AttachMeshShape``), ``dartsim/src/SDFFeatures.cc`` (``ConstructSdfCollision``:
  boxes, spheres, cylinders; a ``<plane>`` is a 2100 m box under the plane),
  ``dartsim/src/CustomHeightmapShape.cc`` (vertex spacing ``size / vertSize``),
  ``dartsim/src/CustomMeshShape.cc``;
* the collision detector: gz-physics ``dartsim/src/WorldFeatures.cc``
  (``SetWorldCollisionDetector``; the empty world starts with DART's ODE detector,
  ``EntityManagementFeatures.cc`` ``ConstructEmptyWorld``); with ``bullet``, DART's
  ``dart/collision/bullet/BulletCollisionDetector.cpp`` turns a height field into a
  ``btHeightfieldTerrainShape`` and a mesh into a ``btGImpactMeshShape``;
* contacts: gz-physics ``dartsim/src/SimulationFeatures.cc``
  (``GetContactsFromLastStep``: DART's last collision result; the point is Bullet's
  ``getPositionWorldOnA``, the depth ``-m_distance1``);
* joint velocity commands: gz-physics ``dartsim/src/JointFeatures.cc``
  (``SetJointVelocityCommand``: DART servo actuator, reset after every step).

Debian packages needed: ``libignition-physics-dev`` and ``libignition-physics-heightmap-dev``
(ign-physics 5 + its dartsim plugin), ``libsdformat-dev``,
``libignition-common-graphics-dev``, ``pkg-config``, ``g++``.
"""

from __future__ import annotations

import hashlib
import json
import math
import signal as signal_module
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from tests.gazebo_harness import ProbeError, SdfParseError, probe_binary

TESTS_DIR = Path(__file__).resolve().parent
PHYSICS_SOURCE = TESTS_DIR / "gazebo" / "physics_probe.cpp"
PHYSICS_PKG_MODULES = (
    "ignition-physics5",
    "ignition-physics5-sdf",
    "ignition-physics5-mesh",
    "ignition-physics5-heightmap",
    "ignition-plugin1-loader",
    "sdformat12",
    "ignition-common4-graphics",
)
PHYSICS_INSTALL_HINT = (
    "apt-get install libignition-physics-dev libignition-physics-heightmap-dev "
    "libsdformat-dev libignition-common-graphics-dev pkg-config g++"
)

# The robot of physics_probe.cpp (Husky-sized): its chassis link frame sits on the
# wheels' contact plane under the chassis centre; the front face is the chassis box face.
ROBOT_LENGTH = 0.99
ROBOT_WIDTH = 0.67
ROBOT_HEIGHT = 0.39
ROBOT_CLEARANCE = 0.08
WHEEL_RADIUS = 0.165
ROBOT_FRONT = ROBOT_LENGTH / 2  # front face, metres ahead of the chassis frame origin

Pose6 = tuple[float, float, float, float, float, float]
Vec3 = tuple[float, float, float]


class SimulationCrashed(RuntimeError):
    """The probe died from a signal; ``str(err)`` names it and the stage it was in."""

    def __init__(self, result: SimResult) -> None:
        self.result = result
        super().__init__(result.crash_summary())


# --------------------------------------------------------------------------- scenario


@dataclass(frozen=True)
class Sphere:
    """A free sphere (solid, uniform) with its centre at ``(x, y, z)``."""

    name: str
    radius: float
    mass: float
    x: float
    y: float
    z: float

    def line(self) -> str:
        values = " ".join(repr(float(v)) for v in (self.radius, self.mass, self.x, self.y, self.z))
        return f"sphere {self.name} {values}"


@dataclass(frozen=True)
class Box:
    """A free box of ``size`` (x, y, z) metres, its centre at ``pose`` (x, y, z, r, p, y)."""

    name: str
    size: Vec3
    mass: float
    pose: Pose6

    def line(self) -> str:
        values = " ".join(repr(float(v)) for v in (*self.size, self.mass, *self.pose))
        return f"box {self.name} {values}"


@dataclass(frozen=True)
class Robot:
    """The skid-steer robot: chassis frame at ``(x, y, z)`` (on the wheels' contact plane),
    heading ``yaw``; ``left``/``right`` wheel rim speeds (m/s) from time ``start`` (s) on,
    wheels braked (0 rad/s) before."""

    name: str
    x: float
    y: float
    z: float = 0.0
    yaw: float = 0.0
    left: float = 0.0
    right: float = 0.0
    start: float = 0.0

    def line(self) -> str:
        values = " ".join(
            repr(float(v))
            for v in (self.x, self.y, self.z, self.yaw, self.left, self.right, self.start)
        )
        return f"robot {self.name} {values}"


@dataclass(frozen=True)
class ModelRobot:
    """A robot model file (SDF, e.g. a world folder's ``robot/model_gz.sdf``) built as gz-sim
    builds a spawned model, its model frame at ``(x, y, z)`` heading ``yaw``, driven as gz-sim's
    DiffDrive system drives it (the joints, wheel radius and separation its DiffDrive plugin
    names): ``linear`` m/s and ``angular`` rad/s from time ``start`` (s) on, braked before. Its
    result tracks the model's first link; ``front_*`` is that link's origin."""

    name: str
    file: Path
    x: float
    y: float
    z: float = 0.0
    yaw: float = 0.0
    linear: float = 0.0
    angular: float = 0.0
    start: float = 0.0

    def line(self) -> str:
        path = str(Path(self.file).resolve())
        if any(c.isspace() for c in path):
            raise ValueError(f"model file path {path!r} must be one word")
        values = " ".join(
            repr(float(v))
            for v in (self.x, self.y, self.z, self.yaw, self.linear, self.angular, self.start)
        )
        return f"model {self.name} {path} {values}"


Body = Sphere | Box | Robot | ModelRobot


@dataclass
class Scenario:
    """What to spawn and how long to step; written as physics_probe's line format.

    ``dt`` None = the world's ``<max_step_size>``; ``detector`` None = the world's
    ``<dart><collision_detector>``; ``stop_after_contact`` N = stop N steps after every
    body has touched something.
    """

    bodies: list[Body] = field(default_factory=list)
    steps: int = 1000
    dt: float | None = None
    sample_every: int = 0
    stop_after_contact: int | None = None
    detector: str | None = None
    plugin: Path | None = None
    raise_signal: int | None = None

    def to_text(self) -> str:
        lines = [f"steps {self.steps}", f"sample_every {self.sample_every}"]
        if self.dt is not None:
            lines.append(f"dt {self.dt!r}")
        if self.stop_after_contact is not None:
            lines.append(f"stop_after_contact {self.stop_after_contact}")
        if self.detector is not None:
            lines.append(f"detector {self.detector}")
        if self.plugin is not None:
            lines.append(f"plugin {self.plugin}")
        if self.raise_signal is not None:
            lines.append(f"raise_signal {self.raise_signal}")
        names = [b.name for b in self.bodies]
        if len(set(names)) != len(names):
            raise ValueError(f"body names must be unique: {names}")
        for b in self.bodies:
            if not b.name or any(c.isspace() for c in b.name):
                raise ValueError(f"body name {b.name!r} must be one word")
            lines.append(b.line())
        return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class Contact:
    """A body's first penetrating contact (depth > 0), from the step that reported it.

    DART detects at the start of a step, on the poses of the step before: ``pose_before``
    is the link pose the detector saw, ``pose`` the pose after the step. ``point``,
    ``normal`` and ``depth`` are those of the deepest contact point (the point is Bullet's
    point on object A, in the world); ``contacts`` how many penetrating points the body had
    that step, ``other`` the model/collision it touched. Separated pairs within the
    detector's threshold are also reported by DART but do not count (they do not slow a
    falling body).
    """

    step: int
    time: float
    pose: Pose6
    pose_before: Pose6
    point: Vec3
    normal: Vec3
    depth: float
    contacts: int
    other: str


@dataclass(frozen=True)
class BodyResult:
    """One spawned body after the run (poses are its link's, in the world frame).

    ``front_*`` is the robot's front-face centre (the link origin for spheres and boxes);
    ``max_advance`` the largest advance of that point along the initial heading over the
    run; ``samples`` (K, 7): time, x, y, z, roll, pitch, yaw every ``sample_every`` steps.
    """

    name: str
    kind: Literal["sphere", "box", "robot", "model"]
    initial_pose: Pose6
    final_pose: Pose6
    front_initial: Vec3
    front_final: Vec3
    max_advance: float
    min_z: float
    min_z_step: int
    final_linear_speed: float
    final_angular_speed: float
    first_contact: Contact | None
    samples: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class ShapeFailure:
    """A collision the probe could not build (as gz-sim would skip it)."""

    type: str
    model: str
    link: str
    collision: str
    reason: str


@dataclass(frozen=True)
class LoadTimes:
    """Wall seconds of each stage (``build_s``: the world's models in physics)."""

    sdf_parse_s: float
    plugin_load_s: float
    build_s: float
    spawn_s: float
    first_step_s: float
    step_loop_s: float

    @property
    def load_s(self) -> float:
        """Parse + build + first step (what a user waits for before the world runs)."""
        return self.sdf_parse_s + self.build_s + self.first_step_s


@dataclass
class SimResult:
    """A physics_probe run. ``signal`` is set (and the rest empty) when it crashed."""

    world: Path
    returncode: int
    stderr: str
    signal: int | None = None
    collision_detector: str = ""
    world_collision_detector: str = ""
    dt: float = math.nan
    steps_run: int = 0
    sim_time: float = 0.0
    times: LoadTimes | None = None
    rtf: float = math.nan
    shapes_built: int = 0
    shapes_failed: int = 0
    built_by_type: dict[str, int] = field(default_factory=dict)
    failures: list[ShapeFailure] = field(default_factory=list)
    bodies: dict[str, BodyResult] = field(default_factory=dict)

    @property
    def crashed(self) -> bool:
        return self.signal is not None

    def crash_summary(self) -> str:
        if self.signal is None:
            return "not crashed"
        try:
            name = signal_module.Signals(self.signal).name
        except ValueError:
            name = f"signal {self.signal}"
        stage = [ln for ln in self.stderr.splitlines() if ln.startswith("physics_probe: signal")]
        where = stage[-1] if stage else "(no stage reported)"
        return f"physics_probe on {self.world} died of {name} ({self.signal}): {where}"

    def check(self) -> SimResult:
        """This result, or :class:`SimulationCrashed` if the probe crashed."""
        if self.crashed:
            raise SimulationCrashed(self)
        return self

    def body(self, name: str) -> BodyResult:
        return self.check().bodies[name]


def _pose(values: list[Any]) -> Pose6:
    x, y, z, r, p, w = (math.nan if v is None else float(v) for v in values)
    return (x, y, z, r, p, w)


def _vec(values: list[Any]) -> Vec3:
    x, y, z = (math.nan if v is None else float(v) for v in values)
    return (x, y, z)


def _num(value: Any) -> float:
    return math.nan if value is None else float(value)


def _to_body(entry: dict[str, Any]) -> BodyResult:
    contact = entry["first_contact"]
    first = None
    if contact is not None:
        first = Contact(
            step=int(contact["step"]),
            time=float(contact["time"]),
            pose=_pose(contact["pose"]),
            pose_before=_pose(contact["pose_before"]),
            point=_vec(contact["point"]),
            normal=_vec(contact["normal"]),
            depth=_num(contact["depth"]),
            contacts=int(contact["contacts"]),
            other=str(contact["other"]),
        )
    samples = np.asarray(entry["samples"], dtype=np.float64).reshape(-1, 7)
    return BodyResult(
        name=entry["name"],
        kind=entry["kind"],
        initial_pose=_pose(entry["initial_pose"]),
        final_pose=_pose(entry["final_pose"]),
        front_initial=_vec(entry["front_initial"]),
        front_final=_vec(entry["front_final"]),
        max_advance=_num(entry["max_advance"]),
        min_z=_num(entry["min_z"]),
        min_z_step=int(entry["min_z_step"]),
        final_linear_speed=_num(entry["final_linear_speed"]),
        final_angular_speed=_num(entry["final_angular_speed"]),
        first_contact=first,
        samples=samples,
    )


def _to_result(world: Path, rc: int, stderr: str, doc: dict[str, Any]) -> SimResult:
    t = doc["times"]
    return SimResult(
        world=world,
        returncode=rc,
        stderr=stderr,
        collision_detector=doc["collision_detector"],
        world_collision_detector=doc["world_collision_detector"],
        dt=float(doc["dt"]),
        steps_run=int(doc["steps_run"]),
        sim_time=float(doc["sim_time"]),
        times=LoadTimes(
            sdf_parse_s=_num(t["sdf_parse_s"]),
            plugin_load_s=_num(t["plugin_load_s"]),
            build_s=_num(t["build_s"]),
            spawn_s=_num(t["spawn_s"]),
            first_step_s=_num(t["first_step_s"]),
            step_loop_s=_num(t["step_loop_s"]),
        ),
        rtf=_num(doc["rtf"]),
        shapes_built=int(doc["shapes_built"]),
        shapes_failed=int(doc["shapes_failed"]),
        built_by_type={str(k): int(v) for k, v in doc["built_by_type"].items()},
        failures=[ShapeFailure(**f) for f in doc["failures"]],
        bodies={b["name"]: _to_body(b) for b in doc["bodies"]},
    )


# --------------------------------------------------------------------------- run


def physics_binary() -> Path:
    """Compile ``physics_probe.cpp`` (once per source sha256) and return its path."""
    return probe_binary(PHYSICS_SOURCE, PHYSICS_PKG_MODULES, PHYSICS_INSTALL_HINT)


def simulate(
    world: Path,
    model_dirs: Sequence[Path],
    scenario: Scenario,
    tmp: Path,
    *,
    timeout: float = 900.0,
) -> SimResult:
    """Build ``world`` in dartsim as gz-sim does, run ``scenario``, return the result.

    ``model_dirs`` are folders holding model folders (``model://NAME`` resolves against
    them). Scenario and JSON files go under ``tmp``. Raises :class:`SdfParseError` when
    SDFormat rejects the world, :class:`ProbeError` for a bad scenario or a missing plugin;
    a crash is returned (``result.signal``), see :meth:`SimResult.check`.
    """
    binary = physics_binary()
    world = Path(world).resolve()
    text = scenario.to_text()
    key = hashlib.sha256(f"{world}\n{text}".encode()).hexdigest()[:12]
    run_dir = Path(tmp) / f"physics-{key}"
    run_dir.mkdir(parents=True, exist_ok=True)
    scenario_file = run_dir / "scenario.txt"
    scenario_file.write_text(text)
    out_json = run_dir / "result.json"
    out_json.unlink(missing_ok=True)
    cmd = [str(binary), str(world), str(scenario_file), str(out_json)]
    cmd += [str(Path(d).resolve()) for d in model_dirs]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    if proc.returncode < 0:
        return SimResult(
            world=world, returncode=proc.returncode, stderr=proc.stderr, signal=-proc.returncode
        )
    if proc.returncode == 1:
        raise SdfParseError(proc.stderr)
    if proc.returncode != 0:
        raise ProbeError(f"physics_probe exited {proc.returncode}:\n{proc.stderr}")
    doc: dict[str, Any] = json.loads(out_json.read_text())
    return _to_result(world, proc.returncode, proc.stderr, doc)


# --------------------------------------------------------------------------- helpers


@dataclass(frozen=True)
class ProbeDrop:
    """One probe dropped at ``(x, y)``.

    ``height`` is the height of what it first touched: the centre height the detector saw
    at the first penetrating contact (``pose_before``) raised by the penetration depth
    (exact for a flat surface under a vertical fall), minus the radius (sphere) or half
    height (box). With ``refine`` it comes from a second drop from 1 cm above the first
    pass's height (a slow touch: 0.44 m/s, 0.44 mm a step). None if it never touched.
    ``coarse_height`` is the first pass's. ``drift`` is how far the first-pass probe moved
    horizontally by the end of its run (one that rolled off a knife edge drifts),
    ``final_z`` / ``min_z`` its last and lowest centre z, ``other`` what it first touched
    (model/collision).
    """

    x: float
    y: float
    height: float | None
    coarse_height: float | None
    first_contact: Contact | None
    drift: float
    final_z: float
    min_z: float
    other: str | None


def _probe_bodies(
    points: Sequence[tuple[float, float]],
    zs: Sequence[float],
    radius: float,
    mass: float,
    box: Vec3 | None,
) -> list[Body]:
    bodies: list[Body] = []
    for i, ((x, y), z) in enumerate(zip(points, zs, strict=True)):
        if box is None:
            bodies.append(Sphere(f"probe{i}", radius, mass, x, y, z))
        else:
            bodies.append(Box(f"probe{i}", box, mass, (x, y, z, 0.0, 0.0, 0.0)))
    return bodies


def drop_probes(
    world: Path,
    model_dirs: Sequence[Path],
    points: Sequence[tuple[float, float]],
    tmp: Path,
    *,
    z: float,
    radius: float = 0.05,
    mass: float = 0.5,
    box: Vec3 | None = None,
    refine: bool = True,
    settle_steps: int = 300,
    max_steps: int = 3000,
    detector: str | None = None,
) -> list[ProbeDrop]:
    """Drop a sphere (or a box of size ``box``) with its centre at ``z`` over each point.

    All probes fall in one run (keep the points > 2 radii apart); a run stops
    ``settle_steps`` after the last first contact. With ``refine`` the probes that touched
    are dropped again from 1 cm above what they touched (see :class:`ProbeDrop`). Returns
    one :class:`ProbeDrop` per point, in order; raises :class:`SimulationCrashed` if the
    probe crashed.
    """
    half = radius if box is None else box[2] / 2

    def run(zs: Sequence[float]) -> SimResult:
        bodies = _probe_bodies(points, zs, radius, mass, box)
        scenario = Scenario(
            bodies=bodies, steps=max_steps, stop_after_contact=settle_steps, detector=detector
        )
        return simulate(world, model_dirs, scenario, tmp).check()

    first = run([z] * len(points))
    coarse: list[float | None] = []
    for i in range(len(points)):
        c = first.bodies[f"probe{i}"].first_contact
        coarse.append(None if c is None else c.pose_before[2] + c.depth - half)
    fine = list(coarse)
    if refine and any(h is not None for h in coarse):
        second = run([z if h is None else h + half + 0.01 for h in coarse])
        for i, h in enumerate(coarse):
            c = second.bodies[f"probe{i}"].first_contact
            if h is not None:
                fine[i] = None if c is None else c.pose_before[2] + c.depth - half
    drops = []
    for i, (x, y) in enumerate(points):
        b = first.bodies[f"probe{i}"]
        c = b.first_contact
        drops.append(
            ProbeDrop(
                x=x,
                y=y,
                height=fine[i],
                coarse_height=coarse[i],
                first_contact=c,
                drift=math.hypot(b.final_pose[0] - x, b.final_pose[1] - y),
                final_z=b.final_pose[2],
                min_z=b.min_z,
                other=None if c is None else c.other,
            )
        )
    return drops


@dataclass(frozen=True)
class WallStop:
    """Where the robot's front face ended after driving along its heading.

    ``front`` is the front-face centre at the end (world x, y, z), ``front_initial`` at the
    spawn; ``advance`` how far it
    moved along the initial heading, ``max_advance`` the farthest it ever got (a robot
    that bounced back has ``max_advance > advance``); ``speed`` the final chassis speed.
    """

    front: Vec3
    front_initial: Vec3
    advance: float
    max_advance: float
    speed: float
    final_pose: Pose6
    result: SimResult = field(repr=False)


def drive_robot(
    world: Path,
    model_dirs: Sequence[Path],
    pose: tuple[float, float, float],
    tmp: Path,
    *,
    z: float = 0.0,
    speed: float = 0.5,
    distance: float = 3.0,
    settle: float = 0.3,
    extra: float = 1.5,
    detector: str | None = None,
) -> WallStop:
    """Spawn the robot at ``pose`` (x, y, yaw; chassis frame on the contact plane at ``z``),
    let it settle ``settle`` s, then drive both sides at ``speed`` m/s for the time it needs
    to cover ``distance`` m plus ``extra`` s, and report where its front face stopped.
    """
    x, y, yaw = pose
    duration = settle + distance / speed + extra
    robot = Robot("robot", x, y, z, yaw, speed, speed, settle)
    dt = 0.001
    scenario = Scenario(
        bodies=[robot], dt=dt, steps=max(1, round(duration / dt)), detector=detector
    )
    result = simulate(world, model_dirs, scenario, tmp).check()
    b = result.bodies["robot"]
    heading = np.array([math.cos(yaw), math.sin(yaw)])
    moved = np.array(b.front_final[:2]) - np.array(b.front_initial[:2])
    return WallStop(
        front=b.front_final,
        front_initial=b.front_initial,
        advance=float(moved @ heading),
        max_advance=b.max_advance,
        speed=b.final_linear_speed,
        final_pose=b.final_pose,
        result=result,
    )


@dataclass(frozen=True)
class RobotRest:
    """The robot after ``duration`` s braked where it was spawned."""

    final_pose: Pose6
    roll: float
    pitch: float
    speed: float
    min_z: float
    result: SimResult = field(repr=False)


def spawn_robot(
    world: Path,
    model_dirs: Sequence[Path],
    pose: tuple[float, float, float],
    tmp: Path,
    *,
    z: float = 0.0,
    duration: float = 1.0,
    detector: str | None = None,
) -> RobotRest:
    """Spawn the robot at ``pose`` (x, y, yaw) with its chassis frame at ``z``, wheels
    braked, step ``duration`` s; its final pose, roll, pitch and speed."""
    x, y, yaw = pose
    robot = Robot("robot", x, y, z, yaw)
    scenario = Scenario(
        bodies=[robot], dt=0.001, steps=max(1, round(duration / 0.001)), detector=detector
    )
    result = simulate(world, model_dirs, scenario, tmp).check()
    b = result.bodies["robot"]
    return RobotRest(
        final_pose=b.final_pose,
        roll=b.final_pose[3],
        pitch=b.final_pose[4],
        speed=b.final_linear_speed,
        min_z=b.min_z,
        result=result,
    )
