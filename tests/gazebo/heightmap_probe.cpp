// heightmap_probe: check a generated Gazebo world with Gazebo's own libraries.
//
// Usage: heightmap_probe WORLD_FILE OUT_DIR [MODEL_DIR ...]
//
// * Parses WORLD_FILE with SDFormat 12 (sdf::Root::Load) in STRICT mode:
//   unrecognized elements, warnings and deprecated elements are errors.
//   model://NAME/... URIs are resolved against every MODEL_DIR (a folder that
//   holds model folders). SDFormat 12.3 does not apply these policies to
//   <include>d files, so each file a model came from is also loaded on its own
//   with the same strict config. Any parse error: errors on stderr, exit 1.
// * Walks every world -> model (nested and <include>d models too) -> link ->
//   collision / visual whose geometry is a heightmap and reports it as JSON on
//   stdout (one document).
// * For every COLLISION heightmap, rebuilds the height field the way
//   gz-physics' dartsim plugin does (gz-physics dartsim/src/CustomHeightmapShape.cc):
//     vertSize = W*sampling - sampling + 1
//     scale.x  = size.x / vertSize, scale.y likewise
//     scale.z  = |size.z| / MaxElevation()   (1 if MaxElevation() == 0)
//     ImageHeightmap::FillHeightMap(sampling, vertSize, size, scale, flipY=false)
//   and writes the heights as raw little-endian float32, row-major
//   (vertSize*vertSize values, row 0 = image top row) to OUT_DIR/<index>.f32.
//
// * Every other collision / visual geometry (box, plane, mesh, polyline, ...)
//   is reported under "shapes" with its pose in the WORLD frame. Polylines
//   come from the element tree (SDFormat 12.3 has no Polyline DOM class):
//   every <polyline> of the geometry with its points and height. Meshes are
//   loaded with gz-common's MeshManager (the loader gz-sim and its physics
//   use: STL, COLLADA, OBJ), and their triangles, in the mesh frame after the
//   loader's unit/up-axis handling, are written as raw little-endian float64
//   (triangles x 3 vertices x xyz) to OUT_DIR/mesh<index>.f64. Each submesh
//   is also reported ("submeshes": its triangle count and its material's
//   diffuse and ambient RGBA, null without a material): gz-common's COLLADA
//   loader makes one submesh per <triangles> element, with that element's
//   material, which is how a mesh's colours reach gz-sim's renderer.
//
//   gz-common 4.5.1's Image::MaxColor() fails on 16-bit images (it returns 0,
//   logging "Coordinates out of range" for each pixel), so MaxElevation() is 0
//   and gz-physics would fall back to scale.z = 1. A working gz-common scales to
//   the brightest sample; when MaxElevation() is 0 this probe computes the
//   brightest first-channel sample itself (normalised to 0..1 like MaxColor)
//   and reports "max_elevation_fallback": true.
//
// * Every polyline geometry is also extruded the way gz-sim builds it
//   (ign-gazebo6 src/systems/physics/Physics.cc for collisions and
//   src/rendering/SceneManager.cc for visuals): the points of each
//   <polyline> in order, one vector per <polyline>, then
//     MeshManager::CreateExtrudedPolyline("POLYLINE_<unique>", polylines,
//                                         height of the FIRST <polyline>)
//   and MeshByName(); gz-sim drops the geometry (no collision, no visual)
//   when that returns nullptr. Reported per geometry as "extrusion": "ok"
//   (triangles written as for meshes, to OUT_DIR/polyline<index>.f64),
//   "failed" (no mesh: gz-common logged "Unable to extrude mesh.
//   Triangulation failed" or similar), "crashed" (the triangulation, GTS,
//   killed the process; "extrusion_signal" names the signal) or "timeout"
//   (longer than HEIGHTMAP_PROBE_EXTRUDE_TIMEOUT seconds, default 120).
//   So that a crash cannot take the probe down, the extrusions run in a
//   forked child that reports each result through a pipe before starting
//   the next; when the child dies, the geometry it was extruding is
//   reported as crashed and a new child carries on with the next one.
//   HEIGHTMAP_PROBE_EXTRUDE=0 skips the extrusions ("extrusion": "skipped").
//   For the harness' own tests, HEIGHTMAP_PROBE_FAULT=crash:NAME (or hang:NAME)
//   makes the child raise SIGSEGV (or wait forever) instead of extruding the
//   geometry of the collision / visual called NAME.
//
// Exit status: 0 ok, 1 SDF parse error, 2 usage / image / I/O error (a failed
// or crashed extrusion is a result, reported in the JSON, not an error).

#include <sdf/Box.hh>
#include <sdf/Collision.hh>
#include <sdf/Element.hh>
#include <sdf/Error.hh>
#include <sdf/Geometry.hh>
#include <sdf/Heightmap.hh>
#include <sdf/Link.hh>
#include <sdf/Mesh.hh>
#include <sdf/Model.hh>
#include <sdf/ParserConfig.hh>
#include <sdf/Plane.hh>
#include <sdf/Root.hh>
#include <sdf/SemanticPose.hh>
#include <sdf/Visual.hh>
#include <sdf/World.hh>

#include <ignition/common/Console.hh>
#include <ignition/common/Image.hh>
#include <ignition/common/ImageHeightmap.hh>
#include <ignition/common/Material.hh>
#include <ignition/common/Mesh.hh>
#include <ignition/common/MeshManager.hh>
#include <ignition/common/SubMesh.hh>
#include <ignition/math/Pose3.hh>
#include <ignition/math/SphericalCoordinates.hh>
#include <ignition/math/Vector3.hh>

#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "probe_common.hh"

using probe::FindInModelDirs;
using probe::g_modelDirs;
using probe::Num;
using probe::ResolveUri;
using probe::Str;

namespace fs = std::filesystem;
using ignition::math::Pose3d;
using ignition::math::Vector3d;

namespace
{

/////////////////////////////////////////////////
std::string Vec(const Vector3d &_v)
{
  return "[" + Num(_v.X()) + ", " + Num(_v.Y()) + ", " + Num(_v.Z()) + "]";
}

/////////////////////////////////////////////////
std::string PoseJson(const Pose3d &_p)
{
  const Vector3d rpy = _p.Rot().Euler();
  return "[" + Num(_p.Pos().X()) + ", " + Num(_p.Pos().Y()) + ", " +
      Num(_p.Pos().Z()) + ", " + Num(rpy.X()) + ", " + Num(rpy.Y()) + ", " +
      Num(rpy.Z()) + "]";
}

/////////////////////////////////////////////////
/// True for the pixel formats gz-common 4.5.1's FillHeightMap reads as
/// uint16 samples (ImageHeightmap.cc); false for the 8-bit ones.
bool IsWide(ignition::common::Image::PixelFormatType _fmt)
{
  using PF = ignition::common::Image::PixelFormatType;
  return _fmt == PF::L_INT16 || _fmt == PF::RGB_INT16 ||
      _fmt == PF::BGR_INT16 || _fmt == PF::RGB_FLOAT16 ||
      _fmt == PF::R_FLOAT16;
}

/////////////////////////////////////////////////
/// Brightest first-channel sample of an image, normalised to 0..1 (what
/// Image::MaxColor().R() returns for a working gz-common). Reads the same
/// buffer, with the same indexing, as ImageHeightmap::FillHeights in
/// gz-common 4.5.1 (ignition/common/ImageHeightmap.hh).
double BrightestSample(const std::string &_path, std::string &_err)
{
  ignition::common::Image img;
  if (img.Load(_path) != 0 || !img.Valid())
  {
    _err = "cannot load image " + _path;
    return 0.0;
  }
  const unsigned int width = img.Width();
  const unsigned int height = img.Height();
  const unsigned int pitch = static_cast<unsigned int>(img.Pitch());
  if (width == 0 || height == 0 || pitch == 0)
  {
    _err = "empty image " + _path;
    return 0.0;
  }

  using PF = ignition::common::Image::PixelFormatType;
  const PF fmt = img.PixelFormat();
  bool wide = false;
  switch (fmt)
  {
    case PF::L_INT8:
    case PF::RGB_INT8:
    case PF::RGBA_INT8:
    case PF::BGR_INT8:
    case PF::BGRA_INT8:
    case PF::BAYER_BGGR8:
    case PF::BAYER_GBRG8:
    case PF::BAYER_GRBG8:
    case PF::BAYER_RGGB8:
      wide = false;
      break;
    case PF::L_INT16:
    case PF::RGB_INT16:
    case PF::BGR_INT16:
    case PF::RGB_FLOAT16:
    case PF::R_FLOAT16:
      wide = true;
      break;
    default:
      _err = "unsupported pixel format " + std::to_string(static_cast<int>(fmt));
      return 0.0;
  }

  unsigned char *data = nullptr;
  unsigned int count = 0;
  img.Data(&data, count);
  if (data == nullptr)
  {
    _err = "no pixel data in " + _path;
    return 0.0;
  }

  const unsigned int bpp = pitch / width;           // bytes per pixel
  const unsigned int sampleBytes = wide ? 2u : 1u;
  const unsigned int channels = std::max(1u, bpp / sampleBytes);
  const unsigned int pitchInPixels = pitch / bpp;
  double best = 0.0;
  for (unsigned int y = 0; y < height; ++y)
  {
    for (unsigned int x = 0; x < width; ++x)
    {
      const std::size_t idx =
          (static_cast<std::size_t>(y) * pitchInPixels + x) * channels;
      double v;
      if (wide)
      {
        if ((idx + 1) * 2 > count)
          continue;
        uint16_t s;
        std::memcpy(&s, data + idx * 2, sizeof(s));
        v = s / 65535.0;
      }
      else
      {
        if (idx + 1 > count)
          continue;
        v = data[idx] / 255.0;
      }
      best = std::max(best, v);
    }
  }
  delete [] data;
  return best;
}

std::vector<std::string> g_entries;
std::string g_outDir;
int g_collisionIndex = 0;
int g_status = 0;

/////////////////////////////////////////////////
void ReportHeightmap(const std::string &_model, const std::string &_link,
    const std::string &_kind, const std::string &_name, const Pose3d &_pose,
    const std::string &_poseMethod, const sdf::Heightmap &_hm)
{
  const std::string path = ResolveUri(_hm.Uri(), _hm.FilePath());
  std::ostringstream o;
  o << "{\"model\": " << Str(_model)
    << ", \"link\": " << Str(_link)
    << ", \"kind\": " << Str(_kind)
    << ", \"name\": " << Str(_name)
    << ", \"pose\": " << PoseJson(_pose)
    << ", \"pose_method\": " << Str(_poseMethod)
    << ", \"uri\": " << Str(_hm.Uri())
    << ", \"sdf_file\": " << Str(_hm.FilePath())
    << ", \"path\": " << (path.empty() ? std::string("null") : Str(path))
    << ", \"size\": " << Vec(_hm.Size())
    << ", \"pos\": " << Vec(_hm.Position())
    << ", \"sampling\": " << _hm.Sampling()
    << ", \"use_terrain_paging\": " << (_hm.UseTerrainPaging() ? "true" : "false")
    << ", \"textures\": " << _hm.TextureCount()
    << ", \"blends\": " << _hm.BlendCount();

  if (_kind == "collision")
  {
    if (path.empty())
    {
      std::cerr << "heightmap_probe: cannot resolve heightmap uri ["
                << _hm.Uri() << "] of " << _model << "/" << _link << "/"
                << _name << "\n";
      g_status = 2;
      o << ", \"error\": " << Str("unresolved uri") << "}";
      g_entries.push_back(o.str());
      return;
    }

    // gz-physics dartsim/src/CustomHeightmapShape.cc
    ignition::common::ImageHeightmap img;
    if (img.Load(path) != 0)
    {
      std::cerr << "heightmap_probe: cannot load heightmap image [" << path
                << "]\n";
      g_status = 2;
      o << ", \"error\": " << Str("image load failed") << "}";
      g_entries.push_back(o.str());
      return;
    }
    const int sampling = static_cast<int>(_hm.Sampling());
    const unsigned int width = img.Width();
    const unsigned int height = img.Height();
    const int vertSize = static_cast<int>(width) * sampling - sampling + 1;
    const Vector3d size = _hm.Size();

    // gz-common 4.5.1 Image::MaxColor() reads pixels with FreeImage_GetPixelIndex
    // / GetPixelColor, which only work on 8-bit-per-channel bitmaps: on a 16-bit
    // image it fails for every pixel, logging one "Coordinates out of range"
    // line each (and formatting + writing them costs ~1 min for 2049x2049),
    // then returns 0. So on 16-bit images MaxElevation() is only called when
    // the image is small enough (<= 129x129) to show the bug cheaply.
    ignition::common::Image raw;
    raw.Load(path);
    const bool wide = IsWide(raw.PixelFormat());
    const bool callMaxElevation =
        !wide || static_cast<uint64_t>(width) * height <= 129u * 129u;
    double maxElevation = 0.0;
    if (callMaxElevation)
    {
      ignition::common::Console::SetVerbosity(0);
      maxElevation = img.MaxElevation();
      ignition::common::Console::SetVerbosity(1);
    }
    const double reportedMaxElevation = maxElevation;
    bool fallback = false;
    if (maxElevation == 0.0)
    {
      std::string err;
      const double brightest = BrightestSample(path, err);
      if (!err.empty())
      {
        std::cerr << "heightmap_probe: " << err << "\n";
        g_status = 2;
      }
      if (brightest > 0.0)
      {
        maxElevation = brightest;
        fallback = true;
      }
    }

    Vector3d scale;
    scale.X(size.X() / vertSize);
    scale.Y(size.Y() / vertSize);
    if (maxElevation == 0.0)
      scale.Z(1.0);
    else
      scale.Z(std::fabs(size.Z()) / maxElevation);

    std::vector<float> heights;
    img.FillHeightMap(sampling, static_cast<unsigned int>(vertSize), size,
        scale, false, heights);

    const std::string fileName = std::to_string(g_collisionIndex++) + ".f32";
    const fs::path outPath = fs::path(g_outDir) / fileName;
    std::ofstream out(outPath, std::ios::binary);
    // x86-64 / aarch64 are little-endian; float is IEEE-754 binary32.
    out.write(reinterpret_cast<const char *>(heights.data()),
        static_cast<std::streamsize>(heights.size() * sizeof(float)));
    out.close();
    if (!out)
    {
      std::cerr << "heightmap_probe: cannot write " << outPath << "\n";
      g_status = 2;
    }

    o << ", \"image_width\": " << width
      << ", \"image_height\": " << height
      << ", \"image_bpp\": " << raw.BPP()
      << ", \"vert_size\": " << vertSize
      << ", \"scale\": " << Vec(scale)
      << ", \"max_elevation_called\": " << (callMaxElevation ? "true" : "false")
      << ", \"max_elevation_reported\": "
      << (callMaxElevation ? Num(reportedMaxElevation) : std::string("null"))
      << ", \"max_elevation\": " << Num(maxElevation)
      << ", \"max_elevation_fallback\": " << (fallback ? "true" : "false")
      << ", \"heights_count\": " << heights.size()
      << ", \"heights_file\": " << Str(fs::absolute(outPath).string());
  }
  o << "}";
  g_entries.push_back(o.str());
}

/// JSON text of each non-heightmap geometry WITHOUT its closing brace; the
/// extrusion fields of polylines are appended once they are known.
std::vector<std::string> g_shapes;
int g_meshIndex = 0;

/// One polyline geometry to extrude: its polylines' points and the height.
struct ExtrudeJob
{
  std::size_t shape;  ///< index in g_shapes
  std::string name;  ///< the collision / visual name
  std::string label;  ///< model/link/name, for messages
  std::vector<std::vector<ignition::math::Vector2d>> polylines;
  double height;
};
std::vector<ExtrudeJob> g_jobs;

/////////////////////////////////////////////////
/// Every triangle of every submesh, as 9 doubles (3 vertices x xyz).
std::vector<double> Triangles(const ignition::common::Mesh *_mesh)
{
  std::vector<double> xyz;
  for (unsigned int si = 0; si < _mesh->SubMeshCount(); ++si)
  {
    auto sub = _mesh->SubMeshByIndex(si).lock();
    if (!sub)
      continue;
    for (unsigned int k = 0; k + 2 < sub->IndexCount(); k += 3)
    {
      for (unsigned int c = 0; c < 3; ++c)
      {
        const Vector3d v = sub->Vertex(static_cast<unsigned int>(sub->Index(k + c)));
        xyz.push_back(v.X());
        xyz.push_back(v.Y());
        xyz.push_back(v.Z());
      }
    }
  }
  return xyz;
}

/////////////////////////////////////////////////
/// Write raw little-endian float64 values; false on an I/O error.
bool WriteDoubles(const fs::path &_path, const std::vector<double> &_values)
{
  std::ofstream out(_path, std::ios::binary);
  out.write(reinterpret_cast<const char *>(_values.data()),
      static_cast<std::streamsize>(_values.size() * sizeof(double)));
  out.close();
  return static_cast<bool>(out);
}

/////////////////////////////////////////////////
std::string ColorJson(const ignition::math::Color &_c)
{
  return "[" + Num(_c.R()) + ", " + Num(_c.G()) + ", " + Num(_c.B()) + ", " +
      Num(_c.A()) + "]";
}

/////////////////////////////////////////////////
/// Each submesh of a mesh, in order: its triangles and its material's colours.
std::string SubMeshesJson(const ignition::common::Mesh *_mesh)
{
  std::ostringstream o;
  o << "[";
  for (unsigned int si = 0; si < _mesh->SubMeshCount(); ++si)
  {
    auto sub = _mesh->SubMeshByIndex(si).lock();
    o << (si ? ", " : "") << "{\"triangles\": "
      << (sub ? sub->IndexCount() / 3 : 0);
    // gz-common 4: MaterialIndex() is unsigned; a submesh without a material
    // keeps the largest value, and MaterialByIndex() returns null past the end.
    ignition::common::MaterialPtr mat;
    if (sub && sub->MaterialIndex() < _mesh->MaterialCount())
      mat = _mesh->MaterialByIndex(sub->MaterialIndex());
    if (mat)
    {
      o << ", \"material\": " << sub->MaterialIndex()
        << ", \"diffuse\": " << ColorJson(mat->Diffuse())
        << ", \"ambient\": " << ColorJson(mat->Ambient());
    }
    else
    {
      o << ", \"material\": null, \"diffuse\": null, \"ambient\": null";
    }
    o << "}";
  }
  o << "]";
  return o.str();
}

/////////////////////////////////////////////////
/// Triangles of a mesh file as gz-common's MeshManager loads it, written to
/// OUT_DIR/mesh<index>.f64; returns the JSON fields describing the load.
std::string LoadMesh(const std::string &_path)
{
  std::ostringstream o;
  const ignition::common::Mesh *mesh =
      ignition::common::MeshManager::Instance()->Load(_path);
  if (mesh == nullptr)
  {
    o << ", \"mesh_loaded\": false";
    return o.str();
  }
  const std::vector<double> xyz = Triangles(mesh);
  const fs::path outPath =
      fs::path(g_outDir) / ("mesh" + std::to_string(g_meshIndex++) + ".f64");
  if (!WriteDoubles(outPath, xyz))
  {
    std::cerr << "heightmap_probe: cannot write " << outPath << "\n";
    g_status = 2;
  }
  o << ", \"mesh_loaded\": true"
    << ", \"mesh_submeshes\": " << mesh->SubMeshCount()
    << ", \"mesh_vertices\": " << mesh->VertexCount()
    << ", \"mesh_triangles\": " << xyz.size() / 9
    << ", \"mesh_min\": " << Vec(mesh->Min())
    << ", \"mesh_max\": " << Vec(mesh->Max())
    << ", \"submeshes\": " << SubMeshesJson(mesh)
    << ", \"triangles_file\": " << Str(fs::absolute(outPath).string());
  return o.str();
}

/////////////////////////////////////////////////
/// A collision / visual geometry that is not a heightmap.
void ReportShape(const std::string &_model, const std::string &_link,
    const std::string &_kind, const std::string &_name, const Pose3d &_pose,
    const std::string &_poseMethod, const sdf::Geometry &_geom)
{
  std::ostringstream o;
  o << "{\"model\": " << Str(_model)
    << ", \"link\": " << Str(_link)
    << ", \"kind\": " << Str(_kind)
    << ", \"name\": " << Str(_name)
    << ", \"pose\": " << PoseJson(_pose)
    << ", \"pose_method\": " << Str(_poseMethod);
  const sdf::ElementPtr elem = _geom.Element();
  switch (_geom.Type())
  {
    case sdf::GeometryType::BOX:
      o << ", \"type\": \"box\", \"size\": " << Vec(_geom.BoxShape()->Size());
      break;
    case sdf::GeometryType::PLANE:
    {
      const auto size = _geom.PlaneShape()->Size();
      o << ", \"type\": \"plane\", \"size\": [" << Num(size.X()) << ", "
        << Num(size.Y()) << "], \"normal\": " << Vec(_geom.PlaneShape()->Normal());
      break;
    }
    case sdf::GeometryType::MESH:
    {
      const sdf::Mesh *mesh = _geom.MeshShape();
      const std::string path = ResolveUri(mesh->Uri(), mesh->FilePath());
      o << ", \"type\": \"mesh\", \"uri\": " << Str(mesh->Uri())
        << ", \"scale\": " << Vec(mesh->Scale())
        << ", \"path\": " << (path.empty() ? std::string("null") : Str(path));
      if (path.empty())
      {
        std::cerr << "heightmap_probe: cannot resolve mesh uri [" << mesh->Uri()
                  << "] of " << _model << "/" << _link << "/" << _name << "\n";
        g_status = 2;
      }
      else
      {
        o << LoadMesh(path);
      }
      break;
    }
    default:
      if (elem && elem->HasElement("polyline"))
      {
        // SDFormat 12.3 knows <polyline> only as elements; Gazebo extrudes all
        // the polylines of one geometry together (holes: even-odd).
        // sdf::Polyline::Points() in gz-sim: the <point> values in order.
        o << ", \"type\": \"polyline\", \"polylines\": [";
        ExtrudeJob job;
        job.shape = g_shapes.size();
        job.name = _name;
        job.label = _model + "/" + _link + "/" + _name;
        bool firstLine = true;
        for (sdf::ElementPtr line = elem->GetElement("polyline"); line;
             line = line->GetNextElement("polyline"))
        {
          const double height = line->Get<double>("height");
          if (firstLine)
            job.height = height;
          o << (firstLine ? "" : ", ") << "{\"height\": "
            << Num(height) << ", \"points\": [";
          firstLine = false;
          job.polylines.emplace_back();
          bool firstPoint = true;
          if (line->HasElement("point"))
          {
            for (sdf::ElementPtr pt = line->GetElement("point"); pt;
                 pt = pt->GetNextElement("point"))
            {
              const auto v = pt->Get<ignition::math::Vector2d>();
              job.polylines.back().push_back(v);
              o << (firstPoint ? "" : ", ") << "[" << Num(v.X()) << ", "
                << Num(v.Y()) << "]";
              firstPoint = false;
            }
          }
          o << "]}";
        }
        o << "]";
        g_jobs.push_back(std::move(job));
      }
      else
      {
        o << ", \"type\": \"other\", \"geometry_type\": "
          << static_cast<int>(_geom.Type());
      }
  }
  g_shapes.push_back(o.str());
}

/////////////////////////////////////////////////
/// What a child reports through the pipe for each extrusion.
struct ExtrudeRecord
{
  uint64_t job;
  int32_t ok;  ///< 1: MeshByName found the mesh, 0: it did not
  int32_t written;  ///< 1: triangles file written
  uint64_t triangles;
  uint64_t vertices;
  double min[3];
  double max[3];
};

/// Result of one extrusion, for the JSON.
struct ExtrudeResult
{
  std::string status = "crashed";
  int signal = 0;
  int exitCode = -1;
  ExtrudeRecord record{};
};

/////////////////////////////////////////////////
fs::path PolylineFile(std::size_t _job)
{
  return fs::path(g_outDir) / ("polyline" + std::to_string(_job) + ".f64");
}

/////////////////////////////////////////////////
/// Child: extrude jobs [_first, end) in order, one record each; never returns.
[[noreturn]] void ExtrudeChild(std::size_t _first, int _fd, unsigned int _timeout)
{
  // stdout carries the parent's JSON: whatever the child prints (GLib prints
  // "Bail out! ..." there when a GTS assertion fails) goes to stderr.
  dup2(STDERR_FILENO, STDOUT_FILENO);
  // A crash here is a result: no core file.
  const struct rlimit noCore = {0, 0};
  setrlimit(RLIMIT_CORE, &noCore);
  // gz-common's errors for failed extrusions are a result, not noise.
  ignition::common::Console::SetVerbosity(0);
  auto *manager = ignition::common::MeshManager::Instance();
  const char *fault = std::getenv("HEIGHTMAP_PROBE_FAULT");
  const std::string faultSpec = fault ? fault : "";
  for (std::size_t k = _first; k < g_jobs.size(); ++k)
  {
    const ExtrudeJob &job = g_jobs[k];
    // SIGALRM's default action ends the child: reported as a timeout.
    alarm(_timeout);
    if (faultSpec == "crash:" + job.name)
      raise(SIGSEGV);
    if (faultSpec == "hang:" + job.name)
    {
      while (true)
        pause();
    }
    // ign-gazebo6 Physics.cc: "POLYLINE_" + Uuid(); any unique name will do.
    const std::string name = "POLYLINE_heightmap_probe_" + std::to_string(k);
    manager->CreateExtrudedPolyline(name, job.polylines, job.height);
    const ignition::common::Mesh *mesh = manager->MeshByName(name);
    alarm(0);
    ExtrudeRecord rec{};
    rec.job = k;
    rec.ok = mesh != nullptr;
    if (mesh != nullptr)
    {
      const std::vector<double> xyz = Triangles(mesh);
      rec.written = WriteDoubles(PolylineFile(k), xyz);
      rec.triangles = xyz.size() / 9;
      rec.vertices = mesh->VertexCount();
      const Vector3d lo = mesh->Min(), hi = mesh->Max();
      rec.min[0] = lo.X(); rec.min[1] = lo.Y(); rec.min[2] = lo.Z();
      rec.max[0] = hi.X(); rec.max[1] = hi.Y(); rec.max[2] = hi.Z();
      manager->RemoveMesh(name);
    }
    const char *p = reinterpret_cast<const char *>(&rec);
    std::size_t left = sizeof(rec);
    while (left > 0)
    {
      const ssize_t n = write(_fd, p, left);
      if (n < 0 && errno == EINTR)
        continue;
      if (n <= 0)
        _exit(3);
      p += n;
      left -= static_cast<std::size_t>(n);
    }
  }
  _exit(0);
}

/////////////////////////////////////////////////
/// Extrude every polyline geometry in forked children (see the header).
std::vector<ExtrudeResult> RunExtrusions()
{
  std::vector<ExtrudeResult> results(g_jobs.size());
  unsigned int timeout = 120;
  if (const char *env = std::getenv("HEIGHTMAP_PROBE_EXTRUDE_TIMEOUT"))
    timeout = static_cast<unsigned int>(std::max(1L, std::strtol(env, nullptr, 10)));
  std::size_t next = 0;
  while (next < g_jobs.size())
  {
    int fds[2];
    if (pipe(fds) != 0)
    {
      std::cerr << "heightmap_probe: pipe failed\n";
      g_status = 2;
      return results;
    }
    std::cout.flush();
    std::cerr.flush();
    const pid_t pid = fork();
    if (pid < 0)
    {
      std::cerr << "heightmap_probe: fork failed\n";
      g_status = 2;
      close(fds[0]);
      close(fds[1]);
      return results;
    }
    if (pid == 0)
    {
      close(fds[0]);
      ExtrudeChild(next, fds[1], timeout);
    }
    close(fds[1]);
    ExtrudeRecord rec{};
    std::size_t have = 0;
    while (true)
    {
      const ssize_t n = read(fds[0], reinterpret_cast<char *>(&rec) + have,
          sizeof(rec) - have);
      if (n < 0 && errno == EINTR)
        continue;
      if (n <= 0)
        break;
      have += static_cast<std::size_t>(n);
      if (have < sizeof(rec))
        continue;
      have = 0;
      if (rec.job != next)
      {
        std::cerr << "heightmap_probe: extrusion records out of order\n";
        g_status = 2;
        break;
      }
      ExtrudeResult &r = results[next++];
      r.record = rec;
      r.status = rec.ok ? "ok" : "failed";
      if (rec.ok && !rec.written)
      {
        std::cerr << "heightmap_probe: cannot write " << PolylineFile(rec.job) << "\n";
        g_status = 2;
      }
    }
    close(fds[0]);
    int wstatus = 0;
    while (waitpid(pid, &wstatus, 0) < 0 && errno == EINTR)
    {
    }
    if (next < g_jobs.size())
    {
      // The child died while extruding job `next`.
      ExtrudeResult &r = results[next];
      if (WIFSIGNALED(wstatus))
      {
        r.signal = WTERMSIG(wstatus);
        r.status = r.signal == SIGALRM ? "timeout" : "crashed";
      }
      else
      {
        r.exitCode = WIFEXITED(wstatus) ? WEXITSTATUS(wstatus) : -1;
        r.status = "crashed";
      }
      std::cerr << "heightmap_probe: extruding " << g_jobs[next].label << " "
                << r.status << " (signal " << r.signal << ", exit "
                << r.exitCode << ")\n";
      ++next;
    }
  }
  return results;
}

/////////////////////////////////////////////////
/// Append the extrusion fields to each polyline shape, close every shape.
void FinishShapes()
{
  const char *env = std::getenv("HEIGHTMAP_PROBE_EXTRUDE");
  const bool skip = env != nullptr && std::string(env) == "0";
  std::vector<ExtrudeResult> results;
  if (!skip)
    results = RunExtrusions();
  for (std::size_t k = 0; k < g_jobs.size(); ++k)
  {
    std::ostringstream o;
    if (skip)
    {
      o << ", \"extrusion\": \"skipped\"";
    }
    else
    {
      const ExtrudeResult &r = results[k];
      o << ", \"extrusion\": " << Str(r.status);
      if (r.status == "ok")
      {
        const ExtrudeRecord &rec = r.record;
        o << ", \"mesh_vertices\": " << rec.vertices
          << ", \"mesh_triangles\": " << rec.triangles
          << ", \"mesh_min\": "
          << Vec(Vector3d(rec.min[0], rec.min[1], rec.min[2]))
          << ", \"mesh_max\": "
          << Vec(Vector3d(rec.max[0], rec.max[1], rec.max[2]))
          << ", \"triangles_file\": "
          << Str(fs::absolute(PolylineFile(k)).string());
      }
      else if (r.status != "failed")
      {
        o << ", \"extrusion_signal\": " << r.signal
          << ", \"extrusion_exit\": " << r.exitCode;
      }
    }
    g_shapes[g_jobs[k].shape] += o.str();
  }
  for (auto &shape : g_shapes)
    shape += "}";
}

/////////////////////////////////////////////////
/// Pose of _child in the frame named _frame, via the SDFormat pose graph.
template <typename T>
bool Resolve(const T &_child, const std::string &_frame, Pose3d &_out)
{
  Pose3d p;
  const sdf::Errors errs = _child.SemanticPose().Resolve(p, _frame);
  if (!errs.empty())
    return false;
  _out = p;
  return true;
}

/////////////////////////////////////////////////
void WalkModel(const sdf::Model &_model, const Pose3d &_worldPose,
    bool _semantic, const std::string &_prefix)
{
  const std::string modelName = _prefix.empty() ?
      _model.Name() : _prefix + "::" + _model.Name();

  for (uint64_t li = 0; li < _model.LinkCount(); ++li)
  {
    const sdf::Link *link = _model.LinkByIndex(li);
    Pose3d linkInModel = link->RawPose();
    bool linkSemantic = _semantic && Resolve(*link, "__model__", linkInModel);
    if (!linkSemantic)
      linkInModel = link->RawPose();

    auto handle = [&](const auto &_elem, const std::string &_kind)
    {
      const sdf::Geometry *geom = _elem.Geom();
      if (geom == nullptr)
        return;
      // Collision / visual poses resolve to the model frame; the model's world
      // pose was resolved by the caller (world scope).
      Pose3d elemInModel;
      bool ok = linkSemantic && Resolve(_elem, "__model__", elemInModel);
      if (!ok)
        elemInModel = linkInModel * _elem.RawPose();  // raw: relative to link
      // ignition::math 6.10 Pose3: X_OQ = X_OP * X_PQ.
      const Pose3d world = _worldPose * elemInModel;
      if (geom->Type() != sdf::GeometryType::HEIGHTMAP ||
          geom->HeightmapShape() == nullptr)
      {
        ReportShape(modelName, link->Name(), _kind, _elem.Name(), world,
            ok ? "semantic" : "raw", *geom);
        return;
      }
      ReportHeightmap(modelName, link->Name(), _kind, _elem.Name(), world,
          ok ? "semantic" : "raw", *geom->HeightmapShape());
    };

    for (uint64_t ci = 0; ci < link->CollisionCount(); ++ci)
      handle(*link->CollisionByIndex(ci), "collision");
    for (uint64_t vi = 0; vi < link->VisualCount(); ++vi)
      handle(*link->VisualByIndex(vi), "visual");
  }

  for (uint64_t mi = 0; mi < _model.ModelCount(); ++mi)
  {
    const sdf::Model *child = _model.ModelByIndex(mi);
    Pose3d childInParent;
    bool ok = _semantic && Resolve(*child, "__model__", childInParent);
    if (!ok)
      childInParent = child->RawPose();
    WalkModel(*child, _worldPose * childInParent, ok, modelName);
  }
}

/////////////////////////////////////////////////
/// Files that models (and nested models) were read from.
void CollectModelFiles(const sdf::Model &_model, std::set<std::string> &_files)
{
  if (_model.Element() != nullptr && !_model.Element()->FilePath().empty())
    _files.insert(_model.Element()->FilePath());
  for (uint64_t mi = 0; mi < _model.ModelCount(); ++mi)
    CollectModelFiles(*_model.ModelByIndex(mi), _files);
}

}  // namespace

/////////////////////////////////////////////////
int main(int argc, char **argv)
{
  if (argc < 3)
  {
    std::cerr << "usage: heightmap_probe WORLD_FILE OUT_DIR [MODEL_DIR ...]\n";
    return 2;
  }
  // Keep gz-common quiet on stdout (stdout carries the JSON); errors still
  // reach stderr.
  ignition::common::Console::SetVerbosity(1);

  const std::string worldFile = argv[1];
  g_outDir = argv[2];
  for (int i = 3; i < argc; ++i)
    g_modelDirs.push_back(fs::absolute(argv[i]).lexically_normal().string());

  std::error_code ec;
  fs::create_directories(g_outDir, ec);
  // gz-common copies every log line (whatever the verbosity) into a log file,
  // by default ~/.ignition/auto_default.log: keep it inside OUT_DIR instead.
  ignLogInit(fs::absolute(g_outDir).string(), "gz-common.log");

  sdf::ParserConfig config;
  config.SetWarningsPolicy(sdf::EnforcementPolicy::ERR);
  config.SetUnrecognizedElementsPolicy(sdf::EnforcementPolicy::ERR);
  config.SetDeprecatedElementsPolicy(sdf::EnforcementPolicy::ERR);
  for (const auto &dir : g_modelDirs)
    config.AddURIPath("model://", dir);
  // The URI path map only answers model://; anything else goes through this
  // callback, which only ever looks inside the given model dirs.
  config.SetFindCallback([](const std::string &_uri) -> std::string
  {
    const std::string prefix = "model://";
    if (_uri.rfind(prefix, 0) == 0)
      return FindInModelDirs(_uri.substr(prefix.size()));
    return "";
  });

  sdf::Root root;
  const sdf::Errors errors = root.Load(worldFile, config);
  if (!errors.empty())
  {
    for (const auto &e : errors)
      std::cerr << "SDF error: " << e << "\n";
    return 1;
  }

  // SDFormat 12.3 does not apply the ParserConfig policies to <include>d
  // files: a misspelled element inside an included model.sdf is only logged
  // (or not at all) and Root::Load still succeeds. So every file that
  // contributed a model is loaded again, on its own, with the strict config.
  std::set<std::string> files;
  for (uint64_t wi = 0; wi < root.WorldCount(); ++wi)
  {
    const sdf::World *world = root.WorldByIndex(wi);
    for (uint64_t mi = 0; mi < world->ModelCount(); ++mi)
      CollectModelFiles(*world->ModelByIndex(mi), files);
  }
  if (root.Model() != nullptr)
    CollectModelFiles(*root.Model(), files);
  bool includeErrors = false;
  for (const auto &file : files)
  {
    std::error_code same;
    if (fs::equivalent(file, worldFile, same))
      continue;
    sdf::Root included;
    const sdf::Errors errs = included.Load(file, config);
    for (const auto &e : errs)
    {
      std::cerr << "SDF error (included file " << file << "): " << e << "\n";
      includeErrors = true;
    }
  }
  if (includeErrors)
    return 1;

  for (uint64_t wi = 0; wi < root.WorldCount(); ++wi)
  {
    const sdf::World *world = root.WorldByIndex(wi);
    for (uint64_t mi = 0; mi < world->ModelCount(); ++mi)
    {
      const sdf::Model *model = world->ModelByIndex(mi);
      Pose3d modelInWorld;
      bool ok = Resolve(*model, "world", modelInWorld);
      if (!ok)
        modelInWorld = model->RawPose();
      WalkModel(*model, modelInWorld, ok, "");
    }
  }
  if (root.Model() != nullptr)
  {
    // A model file on its own: report poses in the model frame.
    WalkModel(*root.Model(), root.Model()->RawPose(), true, "");
  }

  FinishShapes();

  // root.Version() is the version SDFormat converted the document TO (1.9 for
  // SDFormat 12); OriginalVersion() is the <sdf version="..."> of the file.
  const std::string original =
      root.Element() ? root.Element()->OriginalVersion() : std::string();
  // <spherical_coordinates> of the first world: its reference, and where world points lie
  // on the earth as gz-sim puts them (PositionTransform from LOCAL2, the frame gz-sim's
  // NavSat uses with gz-math 6; gz-math 7 calls it LOCAL).
  std::ostringstream spherical;
  spherical << "null";
  const ignition::math::SphericalCoordinates *sc =
      root.WorldCount() > 0 ? root.WorldByIndex(0)->SphericalCoordinates() : nullptr;
  if (sc != nullptr)
  {
    spherical.str("");
    spherical.precision(17);
    spherical << "{\"latitude_deg\": " << sc->LatitudeReference().Degree()
              << ", \"longitude_deg\": " << sc->LongitudeReference().Degree()
              << ", \"elevation\": " << sc->ElevationReference()
              << ", \"heading_deg\": " << sc->HeadingOffset().Degree() << ", \"points\": [";
    const double pts[][3] = {{0, 0, 0},    {500, 0, 0},     {0, 500, 0},
                             {-300, -400, 0}, {1000, 1000, 10}, {0, 0, 100}};
    bool first = true;
    for (const auto &q : pts)
    {
      const ignition::math::Vector3d rad = sc->PositionTransform(
          {q[0], q[1], q[2]}, ignition::math::SphericalCoordinates::LOCAL2,
          ignition::math::SphericalCoordinates::SPHERICAL);
      spherical << (first ? "" : ", ") << "[" << q[0] << ", " << q[1] << ", " << q[2] << ", "
                << IGN_RTOD(rad.X()) << ", " << IGN_RTOD(rad.Y()) << ", " << rad.Z() << "]";
      first = false;
    }
    spherical << "]}";
  }
  std::cout << "{\"sdf_version\": " << Str(root.Version())
            << ", \"sdf_original_version\": " << Str(original)
            << ", \"spherical\": " << spherical.str()
            << ", \"heightmaps\": [";
  for (std::size_t i = 0; i < g_entries.size(); ++i)
    std::cout << (i ? ",\n  " : "\n  ") << g_entries[i];
  std::cout << "\n], \"shapes\": [";
  for (std::size_t i = 0; i < g_shapes.size(); ++i)
    std::cout << (i ? ",\n  " : "\n  ") << g_shapes[i];
  std::cout << "\n]}\n";
  return g_status;
}
