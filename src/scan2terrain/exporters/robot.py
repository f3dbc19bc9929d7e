"""A ready robot for every world folder: ``robot/``, a small four-wheeled differential-drive
(skid-steer) robot with a 2D lidar, as a model folder for gz-sim (SDF 1.9) and Gazebo Classic
(SDF 1.6). Bytes only; the world writer puts them in the folder.

The body is the same in both files (links, collisions, inertias, joints); what differs is how
each simulator drives it and reads its lidar:

* gz-sim: the DiffDrive system (``/cmd_vel`` in, ``/odom`` and ``/tf`` out, absolute topics as
  a ROS bridge expects them) and a ``gpu_lidar`` sensor on ``/scan``, rendered by the Sensors
  system every world_gz.sdf loads (gz-sim 7+ names, which Fortress maps from 6.16 on, as
  ``sdf.GZ_SYSTEMS``);
* Classic: gazebo_ros's ``libgazebo_ros_diff_drive.so`` (two wheel pairs) and a ``ray`` sensor
  with ``libgazebo_ros_ray_sensor.so`` (``/scan``, sensor_msgs/LaserScan), as TurtleBot3's
  Classic model does. Classic's own ROS-free ``libDiffDrivePlugin.so`` takes a gazebo.msgs.Pose
  on a Gazebo-transport topic and turns the wrong way (its left wheel gets ``v + w * sep / 2``),
  so nothing a user runs could drive it. Without ROS the ray sensor still publishes on Gazebo
  transport (``gz topic -l``); only driving needs gazebo_ros.

The model's origin is on the wheels' contact plane under the chassis centre (REP 105's
base_footprint), so a robot spawned at spawn.yaml's pose, whose z is the ground, stands on it.
"""

from __future__ import annotations

import math

from lxml import etree

from scan2terrain.exporters.heightmap import CLASSIC, GZ
from scan2terrain.exporters.sdf import sub_element

ROBOT_DIR = "robot"
MODEL_NAME = "robot"
#: The model file for each simulator, in ``robot/``.
MODEL_FILES = {GZ: "model_gz.sdf", CLASSIC: "model_classic.sdf"}
_SDF_VERSION = {GZ: "1.9", CLASSIC: "1.6"}

# Sizes (metres, kilograms). A TurtleBot3 burger is 0.14 m across on 3.3 cm wheels; this one is
# about twice that, on 6 cm wheels, 4 cm under the chassis, so heightmap ridges and voxel seams
# a few centimetres high do not stop or tip it, and it still fits the spawn's 1 x 1 m robot.
CHASSIS = (0.36, 0.26, 0.10)
CHASSIS_MASS = 4.0
CLEARANCE = 0.04
WHEEL_RADIUS = 0.06
WHEEL_WIDTH = 0.04
WHEEL_MASS = 0.3
WHEEL_X = 0.11  #: axles ahead of and behind the chassis centre
WHEEL_SEPARATION = 0.31  #: between the left and right wheels' mid-planes
LIDAR_HEIGHT = 0.2  #: the scan plane above the ground
LIDAR_RADIUS, LIDAR_LENGTH, LIDAR_MASS = 0.035, 0.04, 0.15
# A 2D lidar like an RPLIDAR A1 / LDS-01: 360 beams 1 degree apart, 0.12..12 m, 5 Hz.
BEAMS = 360
RANGE = (0.12, 12.0)
RATE_HZ = 5
MAX_SPEED = 0.5  #: m/s
MAX_TURN = 2.0  #: rad/s
MAX_ACCELERATION = 1.0  #: m/s^2 (and rad/s^2 turning): no wheelie when a command jumps
#: N m per wheel: four of them (4 N m) cannot lift the chassis off its rear axle (5.35 kg at
#: 0.11 m, 5.8 N m), and still push the robot up a 30 degree slope.
WHEEL_TORQUE = 1.0
WHEEL_TOP_SPEED = 15.0  #: rad/s (0.9 m/s at the rim)

#: (name, x, y): front left, front right, rear left, rear right.
WHEELS = (
    ("fl", WHEEL_X, WHEEL_SEPARATION / 2),
    ("fr", WHEEL_X, -WHEEL_SEPARATION / 2),
    ("rl", -WHEEL_X, WHEEL_SEPARATION / 2),
    ("rr", -WHEEL_X, -WHEEL_SEPARATION / 2),
)
LEFT_JOINTS = ("wheel_fl_joint", "wheel_rl_joint")
RIGHT_JOINTS = ("wheel_fr_joint", "wheel_rr_joint")


def robot_files(simulators: list[str] | tuple[str, ...]) -> dict[str, bytes]:
    """``robot/``'s files for ``simulators`` (``gz``, ``classic``): a model.config naming each
    model file, and the model files (none without a simulator). Relative path -> bytes, the
    same bytes every run."""
    sims = [s for s in (GZ, CLASSIC) if s in simulators]
    if not sims:
        return {}
    files = {f"{ROBOT_DIR}/model.config": _model_config(sims)}
    for sim in sims:
        files[f"{ROBOT_DIR}/{MODEL_FILES[sim]}"] = robot_sdf(sim)
    return files


def _num(value: float) -> str:
    return repr(round(float(value), 9) + 0.0)


def _nums(*values: float) -> str:
    return " ".join(_num(v) for v in values)


def _inertial(
    link: etree._Element, mass: float, ixx: float, iyy: float, izz: float, z: float
) -> None:
    inertial = sub_element(link, "inertial")
    sub_element(inertial, "pose", _nums(0, 0, z, 0, 0, 0))
    sub_element(inertial, "mass", _num(mass))
    inertia = sub_element(inertial, "inertia")
    for key, value in (
        ("ixx", ixx),
        ("ixy", 0),
        ("ixz", 0),
        ("iyy", iyy),
        ("iyz", 0),
        ("izz", izz),
    ):
        sub_element(inertia, key, _num(value))


def _shape(
    link: etree._Element, kind: str, name: str, pose: str, geometry: tuple[str, dict[str, str]]
) -> None:
    el = sub_element(link, kind, name=name)
    sub_element(el, "pose", pose)
    geom = sub_element(sub_element(el, "geometry"), geometry[0])
    for key, value in geometry[1].items():
        sub_element(geom, key, value)
    if kind == "visual":
        material = sub_element(el, "material")
        colour = "0.15 0.15 0.15 1" if name.startswith("wheel") else "0.85 0.35 0.1 1"
        sub_element(material, "ambient", colour)
        sub_element(material, "diffuse", colour)


def _both(link: etree._Element, name: str, pose: str, geometry: tuple[str, dict[str, str]]) -> None:
    _shape(link, "collision", f"{name}_collision", pose, geometry)
    _shape(link, "visual", f"{name}_visual", pose, geometry)


def robot_sdf(simulator: str) -> bytes:
    """The robot model for ``simulator`` (``gz``: SDF 1.9, ``classic``: SDF 1.6)."""
    root = etree.Element("sdf", version=_SDF_VERSION[simulator])
    root.append(
        etree.Comment(
            " scan2terrain's ready robot: four-wheeled differential drive, 2D lidar at "
            f"{_num(LIDAR_HEIGHT)} m. Model origin on the wheels' contact plane: spawn it at "
            "spawn.yaml's pose. "
        )
    )
    model = sub_element(root, "model", name=MODEL_NAME)
    sub_element(model, "pose", _nums(0, 0, 0, 0, 0, 0))
    _base(model)
    _wheels(model)
    _lidar(model, simulator)
    if simulator == GZ:
        _gz_drive(model)
    else:
        _classic_drive(model)
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _base(model: etree._Element) -> None:
    sx, sy, sz = CHASSIS
    cz = CLEARANCE + sz / 2
    link = sub_element(model, "link", name="base_link")
    m = CHASSIS_MASS / 12
    _inertial(link, CHASSIS_MASS, m * (sy**2 + sz**2), m * (sx**2 + sz**2), m * (sx**2 + sy**2), cz)
    _both(link, "chassis", _nums(0, 0, cz, 0, 0, 0), ("box", {"size": _nums(sx, sy, sz)}))


def _wheels(model: etree._Element) -> None:
    axle = 0.5 * WHEEL_MASS * WHEEL_RADIUS**2
    other = WHEEL_MASS * (3 * WHEEL_RADIUS**2 + WHEEL_WIDTH**2) / 12
    cylinder = ("cylinder", {"radius": _num(WHEEL_RADIUS), "length": _num(WHEEL_WIDTH)})
    for name, x, y in WHEELS:
        link = sub_element(model, "link", name=f"wheel_{name}")
        sub_element(link, "pose", _nums(x, y, WHEEL_RADIUS, 0, 0, 0))
        _inertial(link, WHEEL_MASS, other, axle, other, 0.0)
        # Seen, a cylinder touching a heightmap through Bullet (gz-sim's detector in our
        # worlds) catches on the field's triangles and stops the robot in its first 10 cm; a
        # sphere of the wheel's radius rolls over them (ODE's cylinder contacts on meshes are poor
        # too). So the wheel collides as a sphere and looks like a cylinder, whose axis, its
        # z, is rolled a quarter turn onto y, the axle.
        sphere = ("sphere", {"radius": _num(WHEEL_RADIUS)})
        _shape(link, "collision", f"wheel_{name}_collision", _nums(0, 0, 0, 0, 0, 0), sphere)
        _shape(link, "visual", f"wheel_{name}_visual", _nums(0, 0, 0, math.pi / 2, 0, 0), cylinder)
        joint = sub_element(model, "joint", name=f"wheel_{name}_joint", type="revolute")
        sub_element(joint, "parent", "base_link")
        sub_element(joint, "child", f"wheel_{name}")
        axis = sub_element(joint, "axis")
        sub_element(axis, "xyz", "0 1 0")  # positive turns roll the robot forward
        limit = sub_element(axis, "limit")
        sub_element(limit, "lower", "-1e16")
        sub_element(limit, "upper", "1e16")
        sub_element(limit, "effort", _num(WHEEL_TORQUE))
        sub_element(limit, "velocity", _num(WHEEL_TOP_SPEED))


def _lidar(model: etree._Element, simulator: str) -> None:
    top = CLEARANCE + CHASSIS[2]
    link = sub_element(model, "link", name="base_scan")
    sub_element(link, "pose", _nums(0, 0, LIDAR_HEIGHT, 0, 0, 0))
    i_r = LIDAR_MASS * (3 * LIDAR_RADIUS**2 + LIDAR_LENGTH**2) / 12
    _inertial(link, LIDAR_MASS, i_r, i_r, 0.5 * LIDAR_MASS * LIDAR_RADIUS**2, 0.0)
    # The housing stands on the chassis; the scan plane is its middle.
    z = top + LIDAR_LENGTH / 2 - LIDAR_HEIGHT
    _both(
        link,
        "lidar",
        _nums(0, 0, z, 0, 0, 0),
        ("cylinder", {"radius": _num(LIDAR_RADIUS), "length": _num(LIDAR_LENGTH)}),
    )
    sensor = sub_element(
        link, "sensor", name="lidar", type="gpu_lidar" if simulator == GZ else "ray"
    )
    sub_element(sensor, "pose", _nums(0, 0, 0, 0, 0, 0))
    sub_element(sensor, "always_on", "true")
    sub_element(sensor, "visualize", "true")
    sub_element(sensor, "update_rate", str(RATE_HZ))
    if simulator == GZ:
        sub_element(sensor, "topic", "/scan")
    ray = sub_element(sensor, "lidar" if simulator == GZ else "ray")
    horizontal = sub_element(sub_element(ray, "scan"), "horizontal")
    sub_element(horizontal, "samples", str(BEAMS))
    sub_element(horizontal, "resolution", "1")
    sub_element(horizontal, "min_angle", "0")
    sub_element(horizontal, "max_angle", _num(2 * math.pi * (BEAMS - 1) / BEAMS))
    rng = sub_element(ray, "range")
    sub_element(rng, "min", _num(RANGE[0]))
    sub_element(rng, "max", _num(RANGE[1]))
    sub_element(rng, "resolution", "0.01")
    noise = sub_element(ray, "noise")
    sub_element(noise, "type", "gaussian")
    sub_element(noise, "mean", "0")
    sub_element(noise, "stddev", "0.01")
    if simulator == CLASSIC:
        plugin = sub_element(sensor, "plugin", name="scan", filename="libgazebo_ros_ray_sensor.so")
        sub_element(sub_element(plugin, "ros"), "remapping", "~/out:=scan")
        sub_element(plugin, "output_type", "sensor_msgs/LaserScan")
        sub_element(plugin, "frame_name", "base_scan")
    joint = sub_element(model, "joint", name="base_scan_joint", type="fixed")
    sub_element(joint, "parent", "base_link")
    sub_element(joint, "child", "base_scan")


def _gz_drive(model: etree._Element) -> None:
    plugin = sub_element(
        model, "plugin", filename="gz-sim-diff-drive-system", name="gz::sim::systems::DiffDrive"
    )
    for joint in LEFT_JOINTS:
        sub_element(plugin, "left_joint", joint)
    for joint in RIGHT_JOINTS:
        sub_element(plugin, "right_joint", joint)
    sub_element(plugin, "wheel_separation", _num(WHEEL_SEPARATION))
    sub_element(plugin, "wheel_radius", _num(WHEEL_RADIUS))
    sub_element(plugin, "max_linear_velocity", _num(MAX_SPEED))
    sub_element(plugin, "min_linear_velocity", _num(-MAX_SPEED))
    sub_element(plugin, "max_angular_velocity", _num(MAX_TURN))
    sub_element(plugin, "min_angular_velocity", _num(-MAX_TURN))
    sub_element(plugin, "max_linear_acceleration", _num(MAX_ACCELERATION))
    sub_element(plugin, "min_linear_acceleration", _num(-MAX_ACCELERATION))
    sub_element(plugin, "max_angular_acceleration", _num(MAX_ACCELERATION))
    sub_element(plugin, "min_angular_acceleration", _num(-MAX_ACCELERATION))
    sub_element(plugin, "topic", "/cmd_vel")
    sub_element(plugin, "odom_topic", "/odom")
    sub_element(plugin, "tf_topic", "/tf")
    sub_element(plugin, "frame_id", "odom")
    sub_element(plugin, "child_frame_id", "base_link")
    sub_element(plugin, "odom_publish_frequency", "30")


def _classic_drive(model: etree._Element) -> None:
    plugin = sub_element(model, "plugin", name="diff_drive", filename="libgazebo_ros_diff_drive.so")
    sub_element(plugin, "num_wheel_pairs", "2")
    for left, right in zip(LEFT_JOINTS, RIGHT_JOINTS, strict=True):
        sub_element(plugin, "left_joint", left)
        sub_element(plugin, "right_joint", right)
        sub_element(plugin, "wheel_separation", _num(WHEEL_SEPARATION))
        sub_element(plugin, "wheel_diameter", _num(2 * WHEEL_RADIUS))
    sub_element(plugin, "max_wheel_torque", _num(WHEEL_TORQUE))
    # rad/s^2 at the wheel: MAX_ACCELERATION at the rim.
    sub_element(plugin, "max_wheel_acceleration", _num(MAX_ACCELERATION / WHEEL_RADIUS))
    sub_element(plugin, "publish_odom", "true")
    sub_element(plugin, "publish_odom_tf", "true")
    sub_element(plugin, "publish_wheel_tf", "false")
    sub_element(plugin, "odometry_frame", "odom")
    sub_element(plugin, "robot_base_frame", "base_link")


def _model_config(sims: list[str]) -> bytes:
    """model.config: gz-sim and Classic each pick the newest model file they read (1.9, 1.6),
    so ``model://robot`` works in both with the folder holding robot/ on the resource path."""
    root = etree.Element("model")
    sub_element(root, "name", MODEL_NAME)
    sub_element(root, "version", "1.0")
    for sim in sims:
        sub_element(root, "sdf", MODEL_FILES[sim], version=_SDF_VERSION[sim])
    sub_element(root, "description", "scan2terrain's ready robot: differential drive, 2D lidar.")
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
