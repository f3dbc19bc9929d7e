// probe_common.hh: what heightmap_probe.cpp and physics_probe.cpp share: JSON numbers and
// strings, and model:// / file:// URI resolution against the MODEL_DIRs given on the command
// line (filled by each probe's main into g_modelDirs). Included once by each probe; the
// Python side hashes this file with each probe's source (tests/gazebo_harness.probe_binary).
#pragma once

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

namespace probe
{
namespace fs = std::filesystem;

inline std::vector<std::string> g_modelDirs;

/////////////////////////////////////////////////
/// A JSON number (null for inf and nan, which JSON has not).
inline std::string Num(double _v)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.17g", _v);
  std::string s(buf);
  // JSON has no inf / nan.
  if (s.find("inf") != std::string::npos || s.find("nan") != std::string::npos)
    return "null";
  return s;
}

/////////////////////////////////////////////////
/// A JSON string.
inline std::string Str(const std::string &_s)
{
  std::string out = "\"";
  for (unsigned char c : _s)
  {
    switch (c)
    {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      default:
        if (c < 0x20)
        {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        }
        else
        {
          out += static_cast<char>(c);
        }
    }
  }
  return out + "\"";
}

/////////////////////////////////////////////////
/// Find "NAME/rest" (the part after model://) in the model directories.
inline std::string FindInModelDirs(const std::string &_rest)
{
  for (const auto &dir : g_modelDirs)
  {
    fs::path p = fs::path(dir) / _rest;
    if (fs::exists(p))
      return fs::absolute(p).lexically_normal().string();
  }
  return "";
}

/////////////////////////////////////////////////
/// Resolve a heightmap <uri> to an absolute file path, the way gz-sim does
/// for the common cases: model:// against the model dirs, file:// stripped,
/// relative paths against the folder of the SDF file that holds the element.
inline std::string ResolveUri(const std::string &_uri, const std::string &_sdfFile)
{
  const std::string modelPrefix = "model://";
  const std::string filePrefix = "file://";
  if (_uri.rfind(modelPrefix, 0) == 0)
    return FindInModelDirs(_uri.substr(modelPrefix.size()));

  std::string path = _uri;
  if (path.rfind(filePrefix, 0) == 0)
    path = path.substr(filePrefix.size());

  fs::path p(path);
  if (p.is_relative() && !_sdfFile.empty())
    p = fs::path(_sdfFile).parent_path() / p;
  if (!fs::exists(p))
    return "";
  return fs::absolute(p).lexically_normal().string();
}
}  // namespace probe
