// physics_probe: build a world in ign-physics 5 (dartsim) the way ign-gazebo 6's
// Physics system does, spawn probe bodies and a skid-steer robot, step, and
// report what happened as JSON.
//
// Usage: physics_probe WORLD_FILE SCENARIO_FILE OUT_JSON [MODEL_DIR ...]
//
// MODEL_DIRs are folders holding model folders: model://NAME/... resolves to
// MODEL_DIR/NAME/... (first match), as heightmap_probe.cpp does.
// The JSON document goes to OUT_JSON (stdout is left to the libraries' chatter).
// Exit status: 0 ok, 1 SDF parse error, 2 usage / scenario / plugin error.
// A crash inside a dependency (e.g. gz-common's polyline triangulation) kills
// the process with its signal; a handler first prints the stage it was in on
// stderr ("physics_probe: signal N during: ...").
//
// ---------------------------------------------------------------- scenario
// A text file, one directive per line; '#' starts a comment; blank lines are
// ignored; numbers are SI units (m, kg, s, rad). Later directives override
// earlier ones; bodies are spawned in file order.
//
//   dt SECONDS              step size (default: the world's <max_step_size>,
//                           else 0.001)
//   steps N                 number of steps (default 1000)
//   sample_every K          trajectory sample every K steps (default 0: none)
//   stop_after_contact N    stop N steps after every body has touched
//                           something (default -1: never stop early)
//   detector NAME           collision detector instead of the world's
//                           <physics><dart><collision_detector> (bullet, ode,
//                           fcl, dart)
//   plugin PATH             dartsim plugin .so (default: the plugin gz-sim
//                           finds, libignition-physics-dartsim-plugin.so in
//                           IGNITION_PHYSICS_ENGINE_INSTALL_DIR)
//   raise_signal N          raise signal N once everything is built (tests
//                           the crash reporting of tests/physics_harness.py)
//   sphere NAME RADIUS MASS X Y Z
//   box NAME SX SY SZ MASS X Y Z ROLL PITCH YAW
//   robot NAME X Y Z YAW LEFT RIGHT START
//                           the Husky-sized skid-steer robot below; (X, Y, Z)
//                           is the point on the wheels' contact plane under
//                           the chassis centre; LEFT / RIGHT are wheel rim
//                           speeds in m/s (angular speed = speed / radius),
//                           commanded from time START on (before: 0 rad/s,
//                           i.e. braked), every step, with
//                           SetJointVelocityCommand.
//   model NAME FILE X Y Z YAW LINEAR ANGULAR START
//                           a robot model file (SDF), parsed with SDFormat
//                           and built as gz-sim builds a spawned model (the
//                           same path as the world's models), its model frame
//                           at (X, Y, Z, yaw YAW); driven as gz-sim's
//                           DiffDrive system drives it: the model's
//                           <plugin> named *DiffDrive gives <left_joint>s,
//                           <right_joint>s, <wheel_radius> and
//                           <wheel_separation>, and from time START on
//                           (braked before) each side's joints get the
//                           velocity command (LINEAR -+ ANGULAR * separation
//                           / 2) / radius (rad/s) every step, the speeds
//                           ramped at most <max_linear_acceleration> and
//                           <max_angular_acceleration> a second (as its
//                           SpeedLimiter; none: a step). The tracked
//                           link is the model's first link; "front" is its
//                           origin.
//
// The robot: link "chassis" (frame origin on the contact plane, under the
// chassis centre), a box 0.99 x 0.67 x 0.39 m, 46 kg, its bottom 0.08 m above
// the contact plane; four links "wheel_{fl,fr,rl,rr}", cylinders radius 0.165 m,
// width 0.1 m, 2.6 kg, axles at x = +-0.256, y = +-0.2854, z = 0.165, on
// revolute joints about +y (positive = forward). The front face is the
// chassis box face at x = +0.495 in the chassis frame; "front" in the JSON is
// the centre of that face, in the world frame.
//
// ---------------------------------------------------------------- output
// One JSON object: world_file, world_name, plugin, world_collision_detector
// (from the SDF), requested_collision_detector, collision_detector (what the
// engine reports after setting it), solver, dt, steps_requested, steps_run,
// sim_time; times {sdf_parse_s, plugin_load_s, build_s (the world's models),
// spawn_s (scenario bodies), first_step_s, step_loop_s (steps 2..N)}; rtf =
// (steps_run - 1) dt / step_loop_s; shapes_built, shapes_failed,
// built_by_type {type: n}, failures [{type, model, link, collision, reason}];
// bodies [{name, kind, initial_pose, final_pose ([x, y, z, roll, pitch, yaw]
// of the body's link), front_initial, front_final (the robot's front-face
// centre; the link origin otherwise), max_advance (farthest advance of that
// point along the initial heading), min_z, min_z_step, final_linear_speed,
// final_angular_speed, first_contact (null or {step, time, pose, pose_before,
// point, normal, depth, contacts, other}), samples [[t, x, y, z, r, p, y]]}].
//
// ---------------------------------------------------------------- upstream
// The world is built as ign-gazebo 6 src/systems/physics/Physics.cc does:
//   * plugin: ignition::plugin::Loader on the dartsim .so (Physics::Configure);
//   * CreateWorldEntities: ConstructWorld(sdf::World with name + gravity only),
//     then SetCollisionDetector(<dart><collision_detector>) and SetSolver
//     (<dart><solver><solver_type>) BEFORE any model (the component is read by
//     SdfEntityCreator.cc from the element tree);
//   * CreateModelEntities: ConstructModel(sdf::Model with name, pose, static);
//   * CreateLinkEntities: ConstructLink(sdf::Link with name, pose, inertial);
//   * CreateCollisionEntities: meshes via MeshManager::Load +
//     AttachMeshShape(name, mesh, pose, scale); heightmaps via
//     ImageHeightmap::Load + AttachHeightmapShape(name, data, collision pose,
//     <size>, <sampling>); polylines via MeshManager::CreateExtrudedPolyline
//     (all <polyline>s of one geometry, height of the first) +
//     AttachMeshShape; everything else via ConstructCollision; then
//     SetCollisionFilterMask(<surface><contact><collide_bitmask>);
//   * CreateJointEntities: ConstructJoint(sdf::Joint with name, type, pose,
//     thread pitch, parent / child names, axes);
//   * Step: ForwardStep with the step size as input.
// Poses are resolved as SdfEntityCreator.cc stores them: model relative to
// the world, link relative to the model, collision relative to the link, joint
// relative to its child link. SDFormat 12.3 has no polyline DOM class, so the
// <polyline> elements are read from the element tree. Nested models are not
// built (counted as failed shapes, reason given). Scenario bodies are built
// through the same path after the world (as a robot spawned after load).
// Contacts come from GetContactsFromLastStepFeature, queried only while some
// body has not touched anything yet (a robot touches the ground at once); a
// first contact is the first PENETRATING one (depth > 0): DART's detectors
// also report separated pairs within their threshold (Bullet: ~2% of a
// sphere's radius), which do not slow a falling probe.

#include <sdf/Box.hh>
#include <sdf/Collision.hh>
#include <sdf/Element.hh>
#include <sdf/Error.hh>
#include <sdf/Geometry.hh>
#include <sdf/Heightmap.hh>
#include <sdf/Joint.hh>
#include <sdf/JointAxis.hh>
#include <sdf/Link.hh>
#include <sdf/Mesh.hh>
#include <sdf/Model.hh>
#include <sdf/ParserConfig.hh>
#include <sdf/Physics.hh>
#include <sdf/Root.hh>
#include <sdf/SemanticPose.hh>
#include <sdf/Surface.hh>
#include <sdf/World.hh>

#include <ignition/common/Console.hh>
#include <ignition/common/ImageHeightmap.hh>
#include <ignition/common/Mesh.hh>
#include <ignition/common/MeshManager.hh>
#include <ignition/common/Uuid.hh>
#include <ignition/math/Pose3.hh>
#include <ignition/math/Vector2.hh>
#include <ignition/math/Vector3.hh>
#include <ignition/math/eigen3/Conversions.hh>
#include <ignition/physics/FeatureList.hh>
#include <ignition/physics/FeaturePolicy.hh>
#include <ignition/physics/ForwardStep.hh>
#include <ignition/physics/FrameSemantics.hh>
#include <ignition/physics/FreeGroup.hh>
#include <ignition/physics/GetContacts.hh>
#include <ignition/physics/Joint.hh>
#include <ignition/physics/RequestEngine.hh>
#include <ignition/physics/Shape.hh>
#include <ignition/physics/World.hh>
#include <ignition/physics/config.hh>
#include <ignition/physics/heightmap/HeightmapShape.hh>
#include <ignition/physics/mesh/MeshShape.hh>
#include <ignition/physics/sdf/ConstructCollision.hh>
#include <ignition/physics/sdf/ConstructJoint.hh>
#include <ignition/physics/sdf/ConstructLink.hh>
#include <ignition/physics/sdf/ConstructModel.hh>
#include <ignition/physics/sdf/ConstructWorld.hh>
#include <ignition/plugin/Loader.hh>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <signal.h>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "probe_common.hh"

using probe::FindInModelDirs;
using probe::g_modelDirs;
using probe::Num;
using probe::ResolveUri;
using probe::Str;

namespace fs = std::filesystem;
namespace physics = ignition::physics;
using ignition::math::Pose3d;
using ignition::math::Vector3d;
using Clock = std::chrono::steady_clock;

namespace
{

/////////////////////////////////////////////////
// Crash reporting: the stage is kept in a fixed buffer so that the signal
// handler only needs write(2).
char g_stage[1024] = "start";

void SetStage(const std::string &_stage)
{
  std::snprintf(g_stage, sizeof(g_stage), "%s", _stage.c_str());
}

extern "C" void OnFatalSignal(int _sig)
{
  char buf[1200];
  const int n = std::snprintf(buf, sizeof(buf),
      "physics_probe: signal %d during: %s\n", _sig, g_stage);
  if (n > 0)
  {
    const ssize_t ignored = write(STDERR_FILENO, buf,
        static_cast<std::size_t>(std::min(n, static_cast<int>(sizeof(buf)))));
    (void)ignored;
  }
  // SA_RESETHAND restored the default action: raising again ends the process
  // with this signal.
  std::raise(_sig);
}

/////////////////////////////////////////////////
std::string Vec(const Eigen::Vector3d &_v)
{
  return "[" + Num(_v.x()) + ", " + Num(_v.y()) + ", " + Num(_v.z()) + "]";
}

/////////////////////////////////////////////////
/// [x, y, z, roll, pitch, yaw] of a world transform.
std::string PoseJson(const Eigen::Isometry3d &_tf)
{
  const Pose3d p = ignition::math::eigen3::convert(_tf);
  const Vector3d rpy = p.Rot().Euler();
  return "[" + Num(p.Pos().X()) + ", " + Num(p.Pos().Y()) + ", " +
      Num(p.Pos().Z()) + ", " + Num(rpy.X()) + ", " + Num(rpy.Y()) + ", " +
      Num(rpy.Z()) + "]";
}

/////////////////////////////////////////////////
// The features Physics.cc requests (MinimumFeatureList, CollisionFeatureList,
// ContactFeatureList, MeshFeatureList, HeightmapFeatureList,
// CollisionMaskFeatureList, CollisionDetectorFeatureList, SolverFeatureList,
// JointFeatureList, JointVelocityCommandFeatureList), in one list.
struct ProbeFeatures : physics::FeatureList<
    physics::FindFreeGroupFeature,
    physics::SetFreeGroupWorldPose,
    physics::FreeGroupFrameSemantics,
    physics::LinkFrameSemantics,
    physics::ForwardStep,
    physics::sdf::ConstructSdfWorld,
    physics::sdf::ConstructSdfModel,
    physics::sdf::ConstructSdfLink,
    physics::sdf::ConstructSdfCollision,
    physics::sdf::ConstructSdfJoint,
    physics::GetContactsFromLastStepFeature,
    physics::CollisionFilterMaskFeature,
    physics::mesh::AttachMeshShapeFeature,
    physics::heightmap::AttachHeightmapShapeFeature,
    physics::CollisionDetector,
    physics::Solver,
    physics::GetBasicJointState,
    physics::SetJointVelocityCommandFeature> {};

using Policy = physics::FeaturePolicy3d;
using EnginePtr = physics::EnginePtr<Policy, ProbeFeatures>;
using WorldPtr = physics::WorldPtr<Policy, ProbeFeatures>;
using ModelPtr = physics::ModelPtr<Policy, ProbeFeatures>;
using LinkPtr = physics::LinkPtr<Policy, ProbeFeatures>;
using ShapePtr = physics::ShapePtr<Policy, ProbeFeatures>;
using JointPtr = physics::JointPtr<Policy, ProbeFeatures>;
using ContactPoint =
    physics::GetContactsFromLastStepFeature::World<Policy, ProbeFeatures>::ContactPoint;
using ExtraContactData = physics::GetContactsFromLastStepFeature::World<
    Policy, ProbeFeatures>::ExtraContactData;

/////////////////////////////////////////////////
// Scenario

enum class BodyKind { SPHERE, BOX, ROBOT, MODEL };

struct BodySpec
{
  BodyKind kind{BodyKind::SPHERE};
  std::string name;
  double radius{0.0};
  Eigen::Vector3d size{0, 0, 0};
  double mass{1.0};
  Pose3d pose;
  double left{0.0};
  double right{0.0};
  double start{0.0};
  std::string file;  // MODEL: the SDF model file
  double linear{0.0};  // MODEL: m/s
  double angular{0.0};  // MODEL: rad/s
};

struct Scenario
{
  double dt{-1.0};
  long steps{1000};
  long sampleEvery{0};
  long stopAfterContact{-1};
  std::string detector;
  std::string plugin;
  int raiseSignal{0};
  std::vector<BodySpec> bodies;
};

bool ParseScenario(const std::string &_file, Scenario &_out, std::string &_err)
{
  std::ifstream in(_file);
  if (!in)
  {
    _err = "cannot read scenario " + _file;
    return false;
  }
  std::string line;
  int lineNo = 0;
  while (std::getline(in, line))
  {
    ++lineNo;
    const auto hash = line.find('#');
    if (hash != std::string::npos)
      line = line.substr(0, hash);
    std::istringstream ss(line);
    std::string key;
    if (!(ss >> key))
      continue;
    const std::string where = _file + ":" + std::to_string(lineNo) + ": ";
    bool ok = true;
    if (key == "dt")
      ok = static_cast<bool>(ss >> _out.dt) && _out.dt > 0;
    else if (key == "steps")
      ok = static_cast<bool>(ss >> _out.steps) && _out.steps >= 1;
    else if (key == "sample_every")
      ok = static_cast<bool>(ss >> _out.sampleEvery) && _out.sampleEvery >= 0;
    else if (key == "stop_after_contact")
      ok = static_cast<bool>(ss >> _out.stopAfterContact);
    else if (key == "detector")
      ok = static_cast<bool>(ss >> _out.detector);
    else if (key == "plugin")
      ok = static_cast<bool>(ss >> _out.plugin);
    else if (key == "raise_signal")
      ok = static_cast<bool>(ss >> _out.raiseSignal) && _out.raiseSignal > 0;
    else if (key == "sphere")
    {
      BodySpec b;
      b.kind = BodyKind::SPHERE;
      double x, y, z;
      ok = static_cast<bool>(ss >> b.name >> b.radius >> b.mass >> x >> y >> z)
          && b.radius > 0 && b.mass > 0;
      b.pose = Pose3d(x, y, z, 0, 0, 0);
      _out.bodies.push_back(b);
    }
    else if (key == "box")
    {
      BodySpec b;
      b.kind = BodyKind::BOX;
      double sx, sy, sz, x, y, z, r, p, yaw;
      ok = static_cast<bool>(ss >> b.name >> sx >> sy >> sz >> b.mass >> x >> y
          >> z >> r >> p >> yaw) && sx > 0 && sy > 0 && sz > 0 && b.mass > 0;
      b.size = Eigen::Vector3d(sx, sy, sz);
      b.pose = Pose3d(x, y, z, r, p, yaw);
      _out.bodies.push_back(b);
    }
    else if (key == "robot")
    {
      BodySpec b;
      b.kind = BodyKind::ROBOT;
      double x, y, z, yaw;
      ok = static_cast<bool>(ss >> b.name >> x >> y >> z >> yaw >> b.left
          >> b.right >> b.start);
      b.pose = Pose3d(x, y, z, 0, 0, yaw);
      _out.bodies.push_back(b);
    }
    else if (key == "model")
    {
      BodySpec b;
      b.kind = BodyKind::MODEL;
      double x, y, z, yaw;
      ok = static_cast<bool>(ss >> b.name >> b.file >> x >> y >> z >> yaw
          >> b.linear >> b.angular >> b.start);
      b.pose = Pose3d(x, y, z, 0, 0, yaw);
      _out.bodies.push_back(b);
    }
    else
    {
      _err = where + "unknown directive '" + key + "'";
      return false;
    }
    std::string extra;
    if (!ok || (ss >> extra))
    {
      _err = where + "bad '" + key + "' line: " + line;
      return false;
    }
  }
  for (std::size_t i = 0; i < _out.bodies.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (_out.bodies[i].name == _out.bodies[j].name)
      {
        _err = "duplicate body name '" + _out.bodies[i].name + "'";
        return false;
      }
  return true;
}

/////////////////////////////////////////////////
// The robot (see the header).
const double kChassisX = 0.99, kChassisY = 0.67, kChassisZ = 0.39;
const double kChassisMass = 46.0;
const double kClearance = 0.08;
const double kWheelR = 0.165, kWheelW = 0.1, kWheelMass = 2.6;
const double kWheelX = 0.256, kWheelY = 0.2854;
const double kChassisCz = kClearance + kChassisZ / 2;

std::string F(double _v)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.17g", _v);
  return buf;
}

std::string PoseSdf(const Pose3d &_p)
{
  const Vector3d rpy = _p.Rot().Euler();
  return "<pose>" + F(_p.Pos().X()) + " " + F(_p.Pos().Y()) + " " +
      F(_p.Pos().Z()) + " " + F(rpy.X()) + " " + F(rpy.Y()) + " " +
      F(rpy.Z()) + "</pose>";
}

std::string InertialSdf(double _m, double _ixx, double _iyy, double _izz,
    const std::string &_pose = "")
{
  return "<inertial>" + _pose + "<mass>" + F(_m) + "</mass><inertia><ixx>" +
      F(_ixx) + "</ixx><ixy>0</ixy><ixz>0</ixz><iyy>" + F(_iyy) +
      "</iyy><iyz>0</iyz><izz>" + F(_izz) + "</izz></inertia></inertial>";
}

std::string BodySdf(const BodySpec &_b)
{
  std::ostringstream s;
  s << "<?xml version='1.0'?><sdf version='1.9'><model name='" << _b.name
    << "'>" << PoseSdf(_b.pose);
  if (_b.kind == BodyKind::SPHERE)
  {
    const double i = 0.4 * _b.mass * _b.radius * _b.radius;
    s << "<link name='link'>" << InertialSdf(_b.mass, i, i, i)
      << "<collision name='collision'><geometry><sphere><radius>"
      << F(_b.radius) << "</radius></sphere></geometry></collision></link>";
  }
  else if (_b.kind == BodyKind::BOX)
  {
    const double x2 = _b.size.x() * _b.size.x();
    const double y2 = _b.size.y() * _b.size.y();
    const double z2 = _b.size.z() * _b.size.z();
    const double m = _b.mass / 12.0;
    s << "<link name='link'>"
      << InertialSdf(_b.mass, m * (y2 + z2), m * (x2 + z2), m * (x2 + y2))
      << "<collision name='collision'><geometry><box><size>"
      << F(_b.size.x()) << " " << F(_b.size.y()) << " " << F(_b.size.z())
      << "</size></box></geometry></collision></link>";
  }
  else
  {
    const double x2 = kChassisX * kChassisX, y2 = kChassisY * kChassisY,
        z2 = kChassisZ * kChassisZ, m = kChassisMass / 12.0;
    s << "<link name='chassis'>"
      << InertialSdf(kChassisMass, m * (y2 + z2), m * (x2 + z2), m * (x2 + y2),
             "<pose>0 0 " + F(kChassisCz) + " 0 0 0</pose>")
      << "<collision name='chassis_collision'><pose>0 0 " << F(kChassisCz)
      << " 0 0 0</pose><geometry><box><size>" << F(kChassisX) << " "
      << F(kChassisY) << " " << F(kChassisZ)
      << "</size></box></geometry></collision></link>";
    const double iAxle = 0.5 * kWheelMass * kWheelR * kWheelR;
    const double iOther =
        kWheelMass * (3 * kWheelR * kWheelR + kWheelW * kWheelW) / 12.0;
    const char *names[4] = {"fl", "fr", "rl", "rr"};
    const double xs[4] = {kWheelX, kWheelX, -kWheelX, -kWheelX};
    const double ys[4] = {kWheelY, -kWheelY, kWheelY, -kWheelY};
    for (int w = 0; w < 4; ++w)
    {
      const std::string link = std::string("wheel_") + names[w];
      s << "<link name='" << link << "'><pose>" << F(xs[w]) << " " << F(ys[w])
        << " " << F(kWheelR) << " 0 0 0</pose>"
        << InertialSdf(kWheelMass, iOther, iAxle, iOther)
        << "<collision name='" << link << "_collision'>"
        << "<pose>0 0 0 1.5707963267948966 0 0</pose><geometry><cylinder>"
        << "<radius>" << F(kWheelR) << "</radius><length>" << F(kWheelW)
        << "</length></cylinder></geometry></collision></link>"
        << "<joint name='" << link << "_joint' type='revolute'><parent>chassis"
        << "</parent><child>" << link << "</child><axis><xyz>0 1 0</xyz>"
        << "</axis></joint>";
    }
  }
  s << "</model></sdf>";
  return s.str();
}

/////////////////////////////////////////////////
// Building

struct ShapeOwner
{
  std::string model;
  std::string link;
  std::string collision;
  int body{-1};  // index into g_bodies, -1 for world shapes
};

struct Failure
{
  std::string type;
  std::string model;
  std::string link;
  std::string collision;
  std::string reason;
};

std::map<std::size_t, ShapeOwner> g_shapeOwners;
std::vector<Failure> g_failures;
std::map<std::string, int> g_builtByType;
int g_built = 0;

std::string GeometryName(const sdf::Geometry &_geom)
{
  switch (_geom.Type())
  {
    case sdf::GeometryType::BOX: return "box";
    case sdf::GeometryType::CYLINDER: return "cylinder";
    case sdf::GeometryType::PLANE: return "plane";
    case sdf::GeometryType::SPHERE: return "sphere";
    case sdf::GeometryType::MESH: return "mesh";
    case sdf::GeometryType::HEIGHTMAP: return "heightmap";
    case sdf::GeometryType::CAPSULE: return "capsule";
    case sdf::GeometryType::ELLIPSOID: return "ellipsoid";
    default:
      if (_geom.Element() && _geom.Element()->HasElement("polyline"))
        return "polyline";
      return "empty";
  }
}

template <typename T>
Pose3d ResolvedPose(const T &_elem)
{
  // SdfEntityCreator.cc ResolveSdfPose: relative to the default frame (parent),
  // the raw pose when resolution fails.
  Pose3d p;
  if (!_elem.SemanticPose().Resolve(p).empty())
    p = _elem.RawPose();
  return p;
}

/// One collision of a link, as PhysicsPrivate::CreateCollisionEntities.
void BuildCollision(LinkPtr &_link, const sdf::Collision &_coll,
    const std::string &_model, const std::string &_linkName, int _body)
{
  const sdf::Geometry *geom = _coll.Geom();
  Failure fail{geom ? GeometryName(*geom) : "none", _model, _linkName,
      _coll.Name(), ""};
  if (geom == nullptr)
  {
    fail.reason = "collision has no geometry";
    g_failures.push_back(fail);
    return;
  }
  SetStage("building " + fail.type + " collision " + _model + "/" + _linkName +
      "/" + _coll.Name());

  const Pose3d pose = ResolvedPose(_coll);
  const Eigen::Isometry3d poseE = ignition::math::eigen3::convert(pose);
  sdf::Collision collision = _coll;
  collision.SetRawPose(pose);
  collision.SetPoseRelativeTo("");
  const uint16_t collideBitmask =
      collision.Surface() ? collision.Surface()->Contact()->CollideBitmask()
                          : static_cast<uint16_t>(0xFF);

  ShapePtr shape;
  try
  {
    if (geom->Type() == sdf::GeometryType::MESH)
    {
      const sdf::Mesh *meshSdf = geom->MeshShape();
      const std::string path = meshSdf ?
          ResolveUri(meshSdf->Uri(), meshSdf->FilePath()) : std::string();
      if (path.empty())
      {
        fail.reason = "cannot resolve mesh uri [" +
            (meshSdf ? meshSdf->Uri() : std::string()) + "]";
        g_failures.push_back(fail);
        return;
      }
      const ignition::common::Mesh *mesh =
          ignition::common::MeshManager::Instance()->Load(path);
      if (mesh == nullptr)
      {
        fail.reason = "MeshManager::Load failed for [" + path + "]";
        g_failures.push_back(fail);
        return;
      }
      shape = _link->AttachMeshShape(_coll.Name(), *mesh, poseE,
          ignition::math::eigen3::convert(meshSdf->Scale()));
    }
    else if (geom->Type() == sdf::GeometryType::HEIGHTMAP)
    {
      const sdf::Heightmap *hm = geom->HeightmapShape();
      const std::string path = hm ?
          ResolveUri(hm->Uri(), hm->FilePath()) : std::string();
      if (path.empty())
      {
        fail.reason = "cannot resolve heightmap uri [" +
            (hm ? hm->Uri() : std::string()) + "]";
        g_failures.push_back(fail);
        return;
      }
      ignition::common::ImageHeightmap data;
      if (data.Load(path) < 0)
      {
        fail.reason = "ImageHeightmap::Load failed for [" + path + "]";
        g_failures.push_back(fail);
        return;
      }
      shape = _link->AttachHeightmapShape(_coll.Name(), data, poseE,
          ignition::math::eigen3::convert(hm->Size()),
          static_cast<int>(hm->Sampling()));
    }
    else if (fail.type == "polyline")
    {
      std::vector<std::vector<ignition::math::Vector2d>> vertices;
      double height = 1.0;
      bool first = true;
      const sdf::ElementPtr elem = geom->Element();
      for (sdf::ElementPtr line = elem->GetElement("polyline"); line;
           line = line->GetNextElement("polyline"))
      {
        if (first)
          height = line->Get<double>("height");
        first = false;
        std::vector<ignition::math::Vector2d> points;
        if (line->HasElement("point"))
        {
          for (sdf::ElementPtr pt = line->GetElement("point"); pt;
               pt = pt->GetNextElement("point"))
            points.push_back(pt->Get<ignition::math::Vector2d>());
        }
        vertices.push_back(points);
      }
      const std::string name =
          "POLYLINE_" + ignition::common::Uuid().String();
      auto *meshManager = ignition::common::MeshManager::Instance();
      meshManager->CreateExtrudedPolyline(name, vertices, height);
      const ignition::common::Mesh *mesh = meshManager->MeshByName(name);
      if (mesh == nullptr)
      {
        fail.reason = "CreateExtrudedPolyline made no mesh";
        g_failures.push_back(fail);
        return;
      }
      shape = _link->AttachMeshShape(_coll.Name(), *mesh, poseE);
    }
    else
    {
      shape = _link->ConstructCollision(collision);
    }
  }
  catch (const std::exception &_e)
  {
    fail.reason = std::string("exception: ") + _e.what();
    g_failures.push_back(fail);
    return;
  }

  if (!shape)
  {
    fail.reason = "the engine returned no shape (unsupported geometry?)";
    g_failures.push_back(fail);
    return;
  }
  shape->SetCollisionFilterMask(collideBitmask);
  g_shapeOwners[shape->EntityID()] =
      ShapeOwner{_model, _linkName, _coll.Name(), _body};
  ++g_built;
  ++g_builtByType[fail.type];
}

struct BuiltModel
{
  ModelPtr model;
  std::map<std::string, LinkPtr> links;
  std::map<std::string, JointPtr> joints;
};

/// Collisions of a nested model cannot be built: report them.
void FailNested(const sdf::Model &_model, const std::string &_prefix)
{
  const std::string name = _prefix + "::" + _model.Name();
  for (uint64_t li = 0; li < _model.LinkCount(); ++li)
  {
    const sdf::Link *link = _model.LinkByIndex(li);
    for (uint64_t ci = 0; ci < link->CollisionCount(); ++ci)
    {
      const sdf::Collision *c = link->CollisionByIndex(ci);
      g_failures.push_back(Failure{c->Geom() ? GeometryName(*c->Geom()) : "none",
          name, link->Name(), c->Name(),
          "nested models are not built by physics_probe"});
    }
  }
  for (uint64_t mi = 0; mi < _model.ModelCount(); ++mi)
    FailNested(*_model.ModelByIndex(mi), name);
}

/// Models, then links, then collisions, then joints, as
/// PhysicsPrivate::CreatePhysicsEntities orders them.
std::vector<BuiltModel> BuildModels(WorldPtr &_world,
    const std::vector<const sdf::Model *> &_models,
    const std::vector<Pose3d> &_poses, const std::vector<int> &_bodyIndex)
{
  std::vector<BuiltModel> built(_models.size());
  for (std::size_t i = 0; i < _models.size(); ++i)
  {
    const sdf::Model &src = *_models[i];
    SetStage("constructing model " + src.Name());
    sdf::Model model;
    model.SetName(src.Name());
    model.SetRawPose(_poses[i]);
    model.SetStatic(src.Static());
    model.SetSelfCollide(src.SelfCollide());
    built[i].model = _world->ConstructModel(model);
    for (uint64_t mi = 0; mi < src.ModelCount(); ++mi)
      FailNested(*src.ModelByIndex(mi), src.Name());
  }
  for (std::size_t i = 0; i < _models.size(); ++i)
  {
    const sdf::Model &src = *_models[i];
    for (uint64_t li = 0; li < src.LinkCount(); ++li)
    {
      const sdf::Link *srcLink = src.LinkByIndex(li);
      SetStage("constructing link " + src.Name() + "/" + srcLink->Name());
      sdf::Link link;
      link.SetName(srcLink->Name());
      link.SetRawPose(ResolvedPose(*srcLink));
      link.SetInertial(srcLink->Inertial());
      // (gz-sim also passes <gravity>; SDFormat 12.3's Link has no accessor
      // for it, and every link here keeps gravity on.)
      built[i].links[srcLink->Name()] = built[i].model->ConstructLink(link);
    }
  }
  for (std::size_t i = 0; i < _models.size(); ++i)
  {
    const sdf::Model &src = *_models[i];
    for (uint64_t li = 0; li < src.LinkCount(); ++li)
    {
      const sdf::Link *srcLink = src.LinkByIndex(li);
      LinkPtr &link = built[i].links[srcLink->Name()];
      for (uint64_t ci = 0; ci < srcLink->CollisionCount(); ++ci)
      {
        BuildCollision(link, *srcLink->CollisionByIndex(ci), src.Name(),
            srcLink->Name(), _bodyIndex[i]);
      }
    }
  }
  for (std::size_t i = 0; i < _models.size(); ++i)
  {
    const sdf::Model &src = *_models[i];
    for (uint64_t ji = 0; ji < src.JointCount(); ++ji)
    {
      const sdf::Joint *srcJoint = src.JointByIndex(ji);
      SetStage("constructing joint " + src.Name() + "/" + srcJoint->Name());
      sdf::Joint joint;
      joint.SetName(srcJoint->Name());
      joint.SetType(srcJoint->Type());
      joint.SetRawPose(ResolvedPose(*srcJoint));
      joint.SetThreadPitch(srcJoint->ThreadPitch());
      joint.SetParentLinkName(srcJoint->ParentLinkName());
      joint.SetChildLinkName(srcJoint->ChildLinkName());
      if (srcJoint->Axis(0))
        joint.SetAxis(0, *srcJoint->Axis(0));
      if (srcJoint->Axis(1))
        joint.SetAxis(1, *srcJoint->Axis(1));
      JointPtr j = built[i].model->ConstructJoint(joint);
      if (j)
        built[i].joints[srcJoint->Name()] = j;
    }
  }
  return built;
}

/////////////////////////////////////////////////
// Running

struct Sample
{
  double t;
  Eigen::Isometry3d pose;
};

struct Body
{
  BodySpec spec;
  LinkPtr link;
  std::vector<JointPtr> leftJoints;
  std::vector<JointPtr> rightJoints;
  double leftRate{0.0};  // rad/s commanded from spec.start on
  double rightRate{0.0};
  // MODEL: the DiffDrive plugin's wheels and limits, and the speeds it
  // commands now (ramped to spec.linear / spec.angular).
  double radius{1.0};
  double separation{0.0};
  double linearAccel{std::numeric_limits<double>::infinity()};
  double angularAccel{std::numeric_limits<double>::infinity()};
  double linear{0.0};
  double angular{0.0};
  Eigen::Isometry3d initial{Eigen::Isometry3d::Identity()};
  Eigen::Vector3d front{0, 0, 0};  // front point in the link frame
  double minZ{std::numeric_limits<double>::infinity()};
  long minZStep{-1};
  double maxAdvance{-std::numeric_limits<double>::infinity()};
  long contactStep{-1};
  double contactTime{0.0};
  Eigen::Isometry3d current{Eigen::Isometry3d::Identity()};  // after last step
  Eigen::Isometry3d contactPose{Eigen::Isometry3d::Identity()};
  Eigen::Isometry3d contactPoseBefore{Eigen::Isometry3d::Identity()};
  Eigen::Vector3d contactPoint{0, 0, 0};
  Eigen::Vector3d contactNormal{0, 0, 0};
  double contactDepth{0.0};
  int contactCount{0};
  std::string contactOther;
  std::vector<Sample> samples;
};

std::vector<Body> g_bodies;

Eigen::Isometry3d LinkPose(const LinkPtr &_link)
{
  return _link->FrameDataRelativeToWorld().pose;
}

void Track(Body &_b, long _step)
{
  const Eigen::Isometry3d tf = LinkPose(_b.link);
  _b.current = tf;
  const double z = tf.translation().z();
  if (z < _b.minZ)
  {
    _b.minZ = z;
    _b.minZStep = _step;
  }
  const Eigen::Vector3d heading = _b.initial.linear().col(0);
  const Eigen::Vector3d advance =
      tf * _b.front - _b.initial * _b.front;
  _b.maxAdvance = std::max(_b.maxAdvance, advance.dot(heading));
}

/// A MODEL body: its first link tracked, its wheel joints and their rates
/// from the DiffDrive plugin's elements, as gz-sim's DiffDrive system reads
/// them (DiffDrive.cc Configure: every <left_joint> / <right_joint>,
/// <wheel_separation>, <wheel_radius>; PreUpdate: each side's joints get
/// (linear -+ angular * separation / 2) / radius).
bool DriveModel(const sdf::Model &_model, BuiltModel &_built, Body &_b,
    std::string &_err)
{
  if (_model.LinkCount() == 0)
  {
    _err = "the model has no link";
    return false;
  }
  _b.link = _built.links[_model.LinkByIndex(0)->Name()];
  _b.front = Eigen::Vector3d::Zero();
  const sdf::ElementPtr elem = _model.Element();
  sdf::ElementPtr plugin = elem->HasElement("plugin") ?
      elem->GetElement("plugin") : sdf::ElementPtr();
  for (; plugin; plugin = plugin->GetNextElement("plugin"))
  {
    const std::string name = plugin->Get<std::string>("name");
    if (name.size() >= 9 && name.compare(name.size() - 9, 9, "DiffDrive") == 0)
      break;
  }
  if (!plugin)
  {
    _err = "no <plugin> named *DiffDrive";
    return false;
  }
  auto joints = [&](const std::string &_tag, std::vector<JointPtr> &_out)
  {
    if (!plugin->HasElement(_tag))
      return false;
    for (sdf::ElementPtr e = plugin->GetElement(_tag); e;
         e = e->GetNextElement(_tag))
    {
      const std::string jn = e->Get<std::string>();
      const auto it = _built.joints.find(jn);
      if (it == _built.joints.end() || !it->second)
      {
        _err = "DiffDrive names joint '" + jn + "', which was not built";
        return false;
      }
      _out.push_back(it->second);
    }
    return true;
  };
  if (!joints("left_joint", _b.leftJoints) ||
      !joints("right_joint", _b.rightJoints))
  {
    if (_err.empty())
      _err = "DiffDrive has no <left_joint> or <right_joint>";
    return false;
  }
  if (!plugin->HasElement("wheel_radius") ||
      !plugin->HasElement("wheel_separation"))
  {
    _err = "DiffDrive has no <wheel_radius> or <wheel_separation>";
    return false;
  }
  const double radius = plugin->Get<double>("wheel_radius");
  const double separation = plugin->Get<double>("wheel_separation");
  if (!(radius > 0) || !(separation > 0))
  {
    _err = "DiffDrive's <wheel_radius> and <wheel_separation> must be > 0";
    return false;
  }
  _b.radius = radius;
  _b.separation = separation;
  // SpeedLimiter: a command's change per second is at most the
  // <max_linear_acceleration> / <max_angular_acceleration> (|min_*| alike).
  auto limit = [&](const char *_max, const char *_min, double &_out)
  {
    for (const char *tag : {_max, _min})
      if (plugin->HasElement(tag))
        _out = std::min(_out, std::abs(plugin->Get<double>(tag)));
  };
  limit("max_linear_acceleration", "min_linear_acceleration", _b.linearAccel);
  limit("max_angular_acceleration", "min_angular_acceleration",
      _b.angularAccel);
  return true;
}

}  // namespace

/////////////////////////////////////////////////
int main(int argc, char **argv)
{
  if (argc < 4)
  {
    std::cerr << "usage: physics_probe WORLD_FILE SCENARIO_FILE OUT_JSON "
                 "[MODEL_DIR ...]\n";
    return 2;
  }
  // On an alternate stack: a stack overflow (deep recursion in a dependency)
  // must still be reported.
  static std::vector<char> altStack(1 << 16);
  stack_t ss{};
  ss.ss_sp = altStack.data();
  ss.ss_size = altStack.size();
  sigaltstack(&ss, nullptr);
  for (int sig : {SIGSEGV, SIGABRT, SIGFPE, SIGBUS, SIGILL})
  {
    struct sigaction sa{};
    sa.sa_handler = OnFatalSignal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_ONSTACK | SA_RESETHAND;
    sigaction(sig, &sa, nullptr);
  }

  const std::string worldFile = argv[1];
  const std::string scenarioFile = argv[2];
  const std::string outJson = argv[3];
  for (int i = 4; i < argc; ++i)
    g_modelDirs.push_back(fs::absolute(argv[i]).lexically_normal().string());

  Scenario scenario;
  std::string err;
  if (!ParseScenario(scenarioFile, scenario, err))
  {
    std::cerr << "physics_probe: " << err << "\n";
    return 2;
  }

  ignition::common::Console::SetVerbosity(1);
  // gz-common copies log lines into ~/.ignition/auto_default.log by default.
  const fs::path outDir = fs::absolute(outJson).parent_path();
  ignLogInit(outDir.string(), "physics_probe-gz-common.log");

  // ------------------------------------------------------------ parse
  SetStage("parsing " + worldFile);
  sdf::ParserConfig config;
  for (const auto &dir : g_modelDirs)
    config.AddURIPath("model://", dir);
  config.SetFindCallback([](const std::string &_uri) -> std::string
  {
    const std::string prefix = "model://";
    if (_uri.rfind(prefix, 0) == 0)
      return FindInModelDirs(_uri.substr(prefix.size()));
    return "";
  });
  const auto t0 = Clock::now();
  sdf::Root root;
  const sdf::Errors errors = root.Load(worldFile, config);
  const double parseS = std::chrono::duration<double>(Clock::now() - t0).count();
  if (!errors.empty())
  {
    for (const auto &e : errors)
      std::cerr << "SDF error: " << e << "\n";
    return 1;
  }
  if (root.WorldCount() == 0)
  {
    std::cerr << "physics_probe: " << worldFile << " has no <world>\n";
    return 1;
  }
  const sdf::World *sdfWorld = root.WorldByIndex(0);

  // ------------------------------------------------------------ plugin
  SetStage("loading the dartsim plugin");
  const auto t1 = Clock::now();
  std::string pluginPath = scenario.plugin;
  if (pluginPath.empty())
  {
    // Physics::Configure: "libignition-physics-dartsim-plugin.so" found in
    // IGNITION_PHYSICS_ENGINE_INSTALL_DIR.
    pluginPath = std::string(IGNITION_PHYSICS_ENGINE_INSTALL_DIR) +
        "/libignition-physics-dartsim-plugin.so";
  }
  ignition::plugin::Loader loader;
  if (loader.LoadLib(pluginPath).empty())
  {
    std::cerr << "physics_probe: cannot load plugin library " << pluginPath
              << "\n";
    return 2;
  }
  EnginePtr engine;
  for (const auto &className : loader.PluginsImplementing<
           physics::ForwardStep::Implementation<Policy>>())
  {
    auto plugin = loader.Instantiate(className);
    if (!plugin)
      continue;
    engine = physics::RequestEngine<Policy, ProbeFeatures>::From(plugin);
    if (engine)
      break;
  }
  if (!engine)
  {
    std::cerr << "physics_probe: no plugin in " << pluginPath
              << " provides the features gz-sim requests\n";
    return 2;
  }
  const double pluginS =
      std::chrono::duration<double>(Clock::now() - t1).count();

  // ------------------------------------------------------------ world
  const auto t2 = Clock::now();
  SetStage("constructing the world");
  sdf::World worldDom;
  worldDom.SetName(sdfWorld->Name());
  worldDom.SetGravity(sdfWorld->Gravity());
  WorldPtr world = engine->ConstructWorld(worldDom);

  const sdf::Physics *phys = sdfWorld->PhysicsByIndex(0);
  if (phys == nullptr)
    phys = sdfWorld->PhysicsDefault();
  std::string worldDetector, worldSolver;
  double maxStep = 0.001;
  if (phys != nullptr)
  {
    maxStep = phys->MaxStepSize();
    const sdf::ElementPtr pe = phys->Element();
    if (pe && pe->HasElement("dart"))
    {
      const sdf::ElementPtr dart = pe->GetElement("dart");
      if (dart->HasElement("collision_detector"))
        worldDetector = dart->Get<std::string>("collision_detector");
      if (dart->HasElement("solver") &&
          dart->GetElement("solver")->HasElement("solver_type"))
        worldSolver =
            dart->GetElement("solver")->Get<std::string>("solver_type");
    }
  }
  const std::string requestedDetector =
      scenario.detector.empty() ? worldDetector : scenario.detector;
  if (!requestedDetector.empty())
    world->SetCollisionDetector(requestedDetector);
  if (!worldSolver.empty())
    world->SetSolver(worldSolver);
  const std::string detector = world->GetCollisionDetector();

  std::vector<const sdf::Model *> worldModels;
  std::vector<Pose3d> worldPoses;
  for (uint64_t mi = 0; mi < sdfWorld->ModelCount(); ++mi)
  {
    const sdf::Model *m = sdfWorld->ModelByIndex(mi);
    worldModels.push_back(m);
    worldPoses.push_back(ResolvedPose(*m));
  }
  BuildModels(world, worldModels, worldPoses,
      std::vector<int>(worldModels.size(), -1));
  const double buildS = std::chrono::duration<double>(Clock::now() - t2).count();

  // ------------------------------------------------------------ spawn
  const auto t3 = Clock::now();
  std::vector<sdf::Root> bodyRoots(scenario.bodies.size());
  std::vector<const sdf::Model *> bodyModels;
  std::vector<Pose3d> bodyPoses;
  std::vector<int> bodyIndex;
  for (std::size_t i = 0; i < scenario.bodies.size(); ++i)
  {
    const BodySpec &spec = scenario.bodies[i];
    SetStage("parsing body " + spec.name);
    const sdf::Errors errs = spec.kind == BodyKind::MODEL ?
        bodyRoots[i].Load(spec.file, config) :
        bodyRoots[i].LoadSdfString(BodySdf(spec));
    if (!errs.empty() || bodyRoots[i].Model() == nullptr)
    {
      for (const auto &e : errs)
        std::cerr << "SDF error (body " << spec.name << "): " << e << "\n";
      return 2;
    }
    bodyModels.push_back(bodyRoots[i].Model());
    bodyPoses.push_back(spec.pose);
    bodyIndex.push_back(static_cast<int>(i));
  }
  std::vector<BuiltModel> bodiesBuilt =
      BuildModels(world, bodyModels, bodyPoses, bodyIndex);
  for (std::size_t i = 0; i < scenario.bodies.size(); ++i)
  {
    Body b;
    b.spec = scenario.bodies[i];
    BuiltModel &bm = bodiesBuilt[i];
    if (b.spec.kind == BodyKind::ROBOT)
    {
      b.link = bm.links["chassis"];
      b.front = Eigen::Vector3d(kChassisX / 2, 0, kChassisCz);
      for (const char *w : {"fl", "rl"})
        b.leftJoints.push_back(bm.joints[std::string("wheel_") + w + "_joint"]);
      for (const char *w : {"fr", "rr"})
        b.rightJoints.push_back(bm.joints[std::string("wheel_") + w + "_joint"]);
      for (const auto &j : b.leftJoints)
        if (!j)
        {
          std::cerr << "physics_probe: robot joints were not built\n";
          return 2;
        }
      for (const auto &j : b.rightJoints)
        if (!j)
        {
          std::cerr << "physics_probe: robot joints were not built\n";
          return 2;
        }
      b.leftRate = b.spec.left / kWheelR;
      b.rightRate = b.spec.right / kWheelR;
    }
    else if (b.spec.kind == BodyKind::MODEL)
    {
      std::string err;
      if (!DriveModel(*bodyModels[i], bm, b, err))
      {
        std::cerr << "physics_probe: model " << b.spec.file << ": " << err
                  << "\n";
        return 2;
      }
    }
    else
    {
      b.link = bm.links["link"];
    }
    b.initial = LinkPose(b.link);
    b.current = b.initial;
    g_bodies.push_back(b);
  }
  const double spawnS = std::chrono::duration<double>(Clock::now() - t3).count();
  if (scenario.raiseSignal > 0)
  {
    SetStage("raise_signal " + std::to_string(scenario.raiseSignal) +
        " (scenario)");
    std::raise(scenario.raiseSignal);
  }

  // ------------------------------------------------------------ step
  const double dt = scenario.dt > 0 ? scenario.dt : maxStep;
  physics::ForwardStep::Input input;
  physics::ForwardStep::State state;
  physics::ForwardStep::Output output;
  input.Get<std::chrono::steady_clock::duration>() =
      std::chrono::duration_cast<std::chrono::steady_clock::duration>(
          std::chrono::duration<double>(dt));

  // Bodies still waiting for their first contact.
  std::size_t pending = g_bodies.size();
  long stopAt = -1;
  long stepsRun = 0;
  double firstStepS = 0.0;
  const auto loopStart = Clock::now();
  auto afterFirst = loopStart;
  for (long step = 1; step <= scenario.steps; ++step)
  {
    const double tNow = (step - 1) * dt;
    if (step == 1)
      SetStage("first step");
    else if (step == 2)
      SetStage("stepping");
    for (auto &b : g_bodies)
    {
      if (b.spec.kind != BodyKind::ROBOT && b.spec.kind != BodyKind::MODEL)
        continue;
      const bool on = tNow >= b.spec.start;
      if (b.spec.kind == BodyKind::MODEL)
      {
        // DiffDrive.cc PreUpdate: the limited speeds, then each side's rate.
        auto toward = [dt](double _now, double _goal, double _accel)
        {
          const double step = _accel * dt;
          return std::max(_now - step, std::min(_now + step, _goal));
        };
        b.linear = toward(b.linear, on ? b.spec.linear : 0.0, b.linearAccel);
        b.angular =
            toward(b.angular, on ? b.spec.angular : 0.0, b.angularAccel);
        const double turn = b.angular * b.separation / 2;
        b.leftRate = (b.linear - turn) / b.radius;
        b.rightRate = (b.linear + turn) / b.radius;
      }
      for (auto &j : b.leftJoints)
        j->SetVelocityCommand(0, on ? b.leftRate : 0.0);
      for (auto &j : b.rightJoints)
        j->SetVelocityCommand(0, on ? b.rightRate : 0.0);
    }
    world->Step(output, state, input);
    stepsRun = step;
    if (step == 1)
    {
      afterFirst = Clock::now();
      firstStepS = std::chrono::duration<double>(afterFirst - loopStart).count();
    }
    const double t = step * dt;

    if (pending > 0)
    {
      // Which bodies touched something in this step, and where. DART detects
      // collisions at the start of World::step, on the poses of the previous
      // step, and reports (through GetContactsFromLastStep) contacts up to
      // the detector's threshold, also still separated ones (depth <= 0);
      // a falling probe is not slowed by those (it keeps its full fall that
      // step: measured with Bullet, ~2% of a sphere's radius ahead of the
      // surface), so they do not count. A first contact is the first step with a
      // penetrating contact (depth > 0); its deepest point is reported, with
      // the body's pose before the step (what the detector saw) and after.
      const auto contacts = world->GetContactsFromLastStep();
      for (const auto &contact : contacts)
      {
        const auto &cp = contact.Get<ContactPoint>();
        const auto *extra = contact.Query<ExtraContactData>();
        const double depth =
            extra ? extra->depth : std::numeric_limits<double>::quiet_NaN();
        if (extra && !(depth > 0.0))
          continue;
        const std::size_t ids[2] = {cp.collision1->EntityID(),
            cp.collision2->EntityID()};
        for (int k = 0; k < 2; ++k)
        {
          const auto it = g_shapeOwners.find(ids[k]);
          if (it == g_shapeOwners.end() || it->second.body < 0)
            continue;
          Body &b = g_bodies[static_cast<std::size_t>(it->second.body)];
          if (b.contactStep >= 0 && b.contactStep != step)
            continue;
          const auto other = g_shapeOwners.find(ids[1 - k]);
          const std::string otherName = other == g_shapeOwners.end() ?
              std::string("?") : other->second.model + "/" +
              other->second.collision;
          const bool first = b.contactStep < 0;
          if (first)
          {
            b.contactStep = step;
            b.contactTime = t;
            b.contactPose = LinkPose(b.link);
            b.contactPoseBefore = b.current;
            --pending;
          }
          if (first || depth > b.contactDepth)
          {
            b.contactPoint = cp.point;
            b.contactNormal = extra ? extra->normal : Eigen::Vector3d::Zero();
            b.contactDepth = depth;
            b.contactOther = otherName;
          }
          ++b.contactCount;
        }
      }
    }
    for (auto &b : g_bodies)
    {
      Track(b, step);
      if (scenario.sampleEvery > 0 && step % scenario.sampleEvery == 0)
        b.samples.push_back(Sample{t, LinkPose(b.link)});
    }
    if (stopAt < 0 && scenario.stopAfterContact >= 0 && !g_bodies.empty() &&
        pending == 0)
      stopAt = step + scenario.stopAfterContact;
    if (stopAt >= 0 && step >= stopAt)
      break;
  }
  const auto loopEnd = Clock::now();
  const double loopS = std::chrono::duration<double>(loopEnd - afterFirst).count();
  const double rtf = (stepsRun > 1 && loopS > 0) ? (stepsRun - 1) * dt / loopS
                                                 : std::nan("");

  // ------------------------------------------------------------ report
  SetStage("writing " + outJson);
  std::ostringstream o;
  o << "{\"world_file\": " << Str(fs::absolute(worldFile).string())
    << ", \"world_name\": " << Str(sdfWorld->Name())
    << ", \"plugin\": " << Str(pluginPath)
    << ", \"world_collision_detector\": " << Str(worldDetector)
    << ", \"requested_collision_detector\": " << Str(requestedDetector)
    << ", \"collision_detector\": " << Str(detector)
    << ", \"solver\": " << Str(worldSolver)
    << ", \"dt\": " << Num(dt)
    << ", \"steps_requested\": " << scenario.steps
    << ", \"steps_run\": " << stepsRun
    << ", \"sim_time\": " << Num(stepsRun * dt)
    << ", \"times\": {\"sdf_parse_s\": " << Num(parseS)
    << ", \"plugin_load_s\": " << Num(pluginS)
    << ", \"build_s\": " << Num(buildS)
    << ", \"spawn_s\": " << Num(spawnS)
    << ", \"first_step_s\": " << Num(firstStepS)
    << ", \"step_loop_s\": " << Num(loopS) << "}"
    << ", \"rtf\": " << Num(rtf)
    << ", \"shapes_built\": " << g_built
    << ", \"shapes_failed\": " << g_failures.size()
    << ", \"built_by_type\": {";
  bool first = true;
  for (const auto &[type, n] : g_builtByType)
  {
    o << (first ? "" : ", ") << Str(type) << ": " << n;
    first = false;
  }
  o << "}, \"failures\": [";
  for (std::size_t i = 0; i < g_failures.size(); ++i)
  {
    const Failure &f = g_failures[i];
    o << (i ? ", " : "") << "{\"type\": " << Str(f.type)
      << ", \"model\": " << Str(f.model) << ", \"link\": " << Str(f.link)
      << ", \"collision\": " << Str(f.collision)
      << ", \"reason\": " << Str(f.reason) << "}";
  }
  o << "], \"bodies\": [";
  for (std::size_t i = 0; i < g_bodies.size(); ++i)
  {
    const Body &b = g_bodies[i];
    const auto frame = b.link->FrameDataRelativeToWorld();
    const char *kind = b.spec.kind == BodyKind::SPHERE ? "sphere" :
        (b.spec.kind == BodyKind::BOX ? "box" :
        (b.spec.kind == BodyKind::ROBOT ? "robot" : "model"));
    o << (i ? ",\n  " : "\n  ") << "{\"name\": " << Str(b.spec.name)
      << ", \"kind\": " << Str(kind)
      << ", \"initial_pose\": " << PoseJson(b.initial)
      << ", \"final_pose\": " << PoseJson(frame.pose)
      << ", \"front_initial\": " << Vec(b.initial * b.front)
      << ", \"front_final\": " << Vec(frame.pose * b.front)
      << ", \"max_advance\": " << Num(b.maxAdvance)
      << ", \"min_z\": " << Num(b.minZ)
      << ", \"min_z_step\": " << b.minZStep
      << ", \"final_linear_speed\": " << Num(frame.linearVelocity.norm())
      << ", \"final_angular_speed\": " << Num(frame.angularVelocity.norm())
      << ", \"first_contact\": ";
    if (b.contactStep < 0)
      o << "null";
    else
      o << "{\"step\": " << b.contactStep << ", \"time\": "
        << Num(b.contactTime) << ", \"pose\": " << PoseJson(b.contactPose)
        << ", \"pose_before\": " << PoseJson(b.contactPoseBefore)
        << ", \"point\": " << Vec(b.contactPoint)
        << ", \"normal\": " << Vec(b.contactNormal)
        << ", \"depth\": " << Num(b.contactDepth)
        << ", \"contacts\": " << b.contactCount
        << ", \"other\": " << Str(b.contactOther) << "}";
    o << ", \"samples\": [";
    for (std::size_t s = 0; s < b.samples.size(); ++s)
    {
      const Pose3d p = ignition::math::eigen3::convert(b.samples[s].pose);
      const Vector3d rpy = p.Rot().Euler();
      o << (s ? ", " : "") << "[" << Num(b.samples[s].t) << ", "
        << Num(p.Pos().X()) << ", " << Num(p.Pos().Y()) << ", "
        << Num(p.Pos().Z()) << ", " << Num(rpy.X()) << ", " << Num(rpy.Y())
        << ", " << Num(rpy.Z()) << "]";
    }
    o << "]}";
  }
  o << "\n]}\n";

  const std::string tmp = outJson + ".tmp";
  {
    std::ofstream out(tmp);
    out << o.str();
    if (!out)
    {
      std::cerr << "physics_probe: cannot write " << tmp << "\n";
      return 2;
    }
  }
  fs::rename(tmp, outJson);
  SetStage("exiting");
  // Skip the destructors of the physics world, the plugin and gz-common's
  // singletons: tearing a large world down only costs time, and everything
  // has been reported.
  std::fflush(nullptr);
  std::_Exit(0);
}
