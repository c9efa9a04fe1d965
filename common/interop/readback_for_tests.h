// Test-only readers for the files interop.h writes, written from the format specifications and
// independent of the writer's code: a binary PLY parser that follows the header it finds (any
// vertex/face property order, float/double/int types, uchar/int list counts), a TUM trajectory
// reader and a COLMAP images.txt / cameras.txt reader.
#pragma once

#include <cstdint>
#include <cstring>
#include <fstream>
#include <glm/glm.hpp>
#include <glm/gtc/quaternion.hpp>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace exo::interop::testing {

struct PlyData {
  std::string error;  // empty on success
  std::vector<std::string> comments;
  std::map<std::string, std::vector<double>> vertex;  // property name -> values
  std::vector<std::vector<int64_t>> faces;
};

inline size_t PlyTypeSize(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32")
    return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

inline double PlyRead(const std::string& t, const uint8_t* p) {
  auto get = [p](auto v) {
    std::memcpy(&v, p, sizeof(v));
    return static_cast<double>(v);
  };
  if (t == "char" || t == "int8") return get(int8_t{});
  if (t == "uchar" || t == "uint8") return get(uint8_t{});
  if (t == "short" || t == "int16") return get(int16_t{});
  if (t == "ushort" || t == "uint16") return get(uint16_t{});
  if (t == "int" || t == "int32") return get(int32_t{});
  if (t == "uint" || t == "uint32") return get(uint32_t{});
  if (t == "float" || t == "float32") return get(float{});
  return get(double{});
}

inline PlyData ReadBinaryPly(const std::string& path) {
  PlyData d;
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t end = bytes.find("end_header\n");
  if (bytes.rfind("ply\n", 0) != 0 || end == std::string::npos) {
    d.error = "not a PLY file";
    return d;
  }
  struct Prop {
    std::string name, type, count_type;  // count_type set for lists
  };
  struct Element {
    std::string name;
    size_t count = 0;
    std::vector<Prop> props;
  };
  std::vector<Element> elements;
  std::istringstream header(bytes.substr(0, end));
  for (std::string line; std::getline(header, line);) {
    std::istringstream ls(line);
    std::string w;
    ls >> w;
    if (w == "format") {
      std::string f;
      ls >> f;
      if (f != "binary_little_endian") d.error = "format " + f;
    } else if (w == "comment") {
      d.comments.push_back(line.size() > 8 ? line.substr(8) : "");
    } else if (w == "element") {
      Element e;
      ls >> e.name >> e.count;
      elements.push_back(e);
    } else if (w == "property" && !elements.empty()) {
      Prop p;
      ls >> p.type;
      if (p.type == "list") ls >> p.count_type >> p.type;
      ls >> p.name;
      elements.back().props.push_back(p);
    }
  }
  if (!d.error.empty()) return d;
  const uint8_t* p = reinterpret_cast<const uint8_t*>(bytes.data()) + end + 11;
  const uint8_t* stop = reinterpret_cast<const uint8_t*>(bytes.data()) + bytes.size();
  for (const Element& e : elements) {
    for (size_t i = 0; i < e.count; ++i) {
      for (const Prop& pr : e.props) {
        if (!pr.count_type.empty()) {
          const size_t cs = PlyTypeSize(pr.count_type), vs = PlyTypeSize(pr.type);
          if (cs == 0 || vs == 0 || p + cs > stop) {
            d.error = "truncated list";
            return d;
          }
          const int64_t n = static_cast<int64_t>(PlyRead(pr.count_type, p));
          p += cs;
          if (n < 0 || p + n * vs > stop) {
            d.error = "truncated list values";
            return d;
          }
          std::vector<int64_t> list;
          for (int64_t k = 0; k < n; ++k, p += vs)
            list.push_back(static_cast<int64_t>(PlyRead(pr.type, p)));
          if (e.name == "face") d.faces.push_back(list);
        } else {
          const size_t s = PlyTypeSize(pr.type);
          if (s == 0 || p + s > stop) {
            d.error = "truncated scalar";
            return d;
          }
          if (e.name == "vertex") d.vertex[pr.name].push_back(PlyRead(pr.type, p));
          p += s;
        }
      }
    }
  }
  if (p != stop) d.error = "trailing bytes after the last element";
  return d;
}

// A pose line: id + 7 numbers, as written.
struct PoseLine {
  uint32_t id = 0;
  glm::dvec3 t{0.0};
  glm::dquat q{1.0, 0.0, 0.0, 0.0};
  int camera_id = 0;
  std::string name;
};

// TUM: `timestamp tx ty tz qx qy qz qw` (comments start with '#').
inline std::vector<PoseLine> ReadTum(const std::string& path) {
  std::vector<PoseLine> out;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    PoseLine p;
    double ts;
    ls >> ts >> p.t.x >> p.t.y >> p.t.z >> p.q.x >> p.q.y >> p.q.z >> p.q.w;
    p.id = static_cast<uint32_t>(ts);
    if (ls) out.push_back(p);
  }
  return out;
}

// COLMAP images.txt: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` then a points line (kept
// separately in `points_lines`).
inline std::vector<PoseLine> ReadColmapImages(const std::string& path,
                                              std::vector<std::string>* points_lines) {
  std::vector<PoseLine> out;
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);)
    if (line.empty() || line[0] != '#') lines.push_back(line);
  for (size_t i = 0; i < lines.size(); i += 2) {
    std::istringstream ls(lines[i]);
    PoseLine p;
    ls >> p.id >> p.q.w >> p.q.x >> p.q.y >> p.q.z >> p.t.x >> p.t.y >> p.t.z >> p.camera_id >>
        p.name;
    if (!ls) break;
    out.push_back(p);
    if (points_lines) points_lines->push_back(i + 1 < lines.size() ? lines[i + 1] : "<missing>");
  }
  return out;
}

struct ColmapCamera {
  std::string model;
  int width = 0, height = 0;
  std::vector<double> params;
};
inline std::map<int, ColmapCamera> ReadColmapCameras(const std::string& path) {
  std::map<int, ColmapCamera> out;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    int id;
    ColmapCamera c;
    ls >> id >> c.model >> c.width >> c.height;
    for (double v; ls >> v;) c.params.push_back(v);
    out[id] = c;
  }
  return out;
}

// Rotation matrix of a unit quaternion from the textbook formula (not glm's cast).
inline glm::dmat3 QuatToMatrix(const glm::dquat& q) {
  const double w = q.w, x = q.x, y = q.y, z = q.z;
  glm::dmat3 r;  // column-major: r[col][row]
  r[0][0] = 1 - 2 * (y * y + z * z);
  r[1][0] = 2 * (x * y - w * z);
  r[2][0] = 2 * (x * z + w * y);
  r[0][1] = 2 * (x * y + w * z);
  r[1][1] = 1 - 2 * (x * x + z * z);
  r[2][1] = 2 * (y * z - w * x);
  r[0][2] = 2 * (x * z - w * y);
  r[1][2] = 2 * (y * z + w * x);
  r[2][2] = 1 - 2 * (x * x + y * y);
  return r;
}

}  // namespace exo::interop::testing
