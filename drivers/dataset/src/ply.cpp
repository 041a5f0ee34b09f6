#include "hxmap/dataset/ply.hpp"

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <fmt/format.h>

#include "hxmap/dataset/dataset.hpp"

namespace hxmap::drv {

Status writeTextFile(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) return Error{path + ": cannot open for writing (does the folder exist and is it writable?)"};
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.flush();
    if (!out) {
      out.close();
      std::error_code ignored;
      std::filesystem::remove(tmp, ignored);  // no half-written leftover beside the outputs
      return Error{path + ": write failed (disk full?)"};
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    return Error{path + ": cannot rename temporary file: " + ec.message()};
  }
  return Status::ok();
}

Status writePly(const std::string& path, const alg::TriangleMesh& mesh) {
  const bool colors = mesh.colors.size() == mesh.vertices.size() && !mesh.vertices.empty();
  // Per-vertex normals: the area-weighted sum of the adjoining faces'
  // normals (triangles are counter-clockwise seen from outside, so they
  // point out of the surface, towards where the camera was).
  std::vector<Eigen::Vector3f> normals(mesh.vertices.size(), Eigen::Vector3f::Zero());
  for (const auto& t : mesh.triangles) {
    if (t.minCoeff() < 0 || t.maxCoeff() >= static_cast<int>(mesh.vertices.size())) continue;
    const Eigen::Vector3f n = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    for (int k = 0; k < 3; ++k) normals[t[k]] += n;
  }
  for (auto& n : normals) {
    const float len = n.norm();
    n = len > 0 && std::isfinite(len) ? Eigen::Vector3f(n / len) : Eigen::Vector3f::Zero();
  }
  std::string out = fmt::format(
      "ply\nformat binary_little_endian 1.0\ncomment written by hxmap\nelement vertex {}\n"
      "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
      "property float nz\n{}element face {}\nproperty list uchar int vertex_indices\nend_header\n",
      mesh.vertices.size(), colors ? "property uchar red\nproperty uchar green\nproperty uchar blue\n" : "",
      mesh.triangles.size());
  const size_t header = out.size();
  out.resize(header + mesh.vertices.size() * (24 + (colors ? 3 : 0)) + mesh.triangles.size() * 13);
  char* p = out.data() + header;
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    std::memcpy(p, mesh.vertices[i].data(), 12);
    p += 12;
    std::memcpy(p, normals[i].data(), 12);
    p += 12;
    if (colors) {
      std::memcpy(p, mesh.colors[i].data(), 3);
      p += 3;
    }
  }
  for (const auto& t : mesh.triangles) {
    *p++ = 3;
    std::memcpy(p, t.data(), 12);
    p += 12;
  }
  return writeTextFile(path, out);
}

Status writePlyBoxes(const std::string& path, const std::vector<Eigen::AlignedBox3f>& boxes, const alg::Color3& color) {
  std::string out = fmt::format(
      "ply\nformat ascii 1.0\ncomment written by hxmap\nelement vertex {}\nproperty float x\nproperty float y\n"
      "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement edge {}\n"
      "property int vertex1\nproperty int vertex2\nend_header\n",
      boxes.size() * 8, boxes.size() * 12);
  for (const auto& b : boxes) {
    for (int i = 0; i < 8; ++i) {
      out += fmt::format("{} {} {} {} {} {}\n", (i & 1) ? b.max().x() : b.min().x(), (i & 2) ? b.max().y() : b.min().y(),
                         (i & 4) ? b.max().z() : b.min().z(), color[0], color[1], color[2]);
    }
  }
  for (size_t k = 0; k < boxes.size(); ++k) {
    const size_t base = 8 * k;
    for (int a = 0; a < 8; ++a) {
      for (int bit : {1, 2, 4}) {
        if (!(a & bit)) out += fmt::format("{} {}\n", base + a, base + (a | bit));
      }
    }
  }
  return writeTextFile(path, out);
}

namespace {

enum class Type { kChar, kUChar, kShort, kUShort, kInt, kUInt, kFloat, kDouble, kInvalid };

Type parseType(const std::string& s) {
  if (s == "char" || s == "int8") return Type::kChar;
  if (s == "uchar" || s == "uint8") return Type::kUChar;
  if (s == "short" || s == "int16") return Type::kShort;
  if (s == "ushort" || s == "uint16") return Type::kUShort;
  if (s == "int" || s == "int32") return Type::kInt;
  if (s == "uint" || s == "uint32") return Type::kUInt;
  if (s == "float" || s == "float32") return Type::kFloat;
  if (s == "double" || s == "float64") return Type::kDouble;
  return Type::kInvalid;
}

size_t sizeOf(Type t) {
  switch (t) {
    case Type::kChar:
    case Type::kUChar: return 1;
    case Type::kShort:
    case Type::kUShort: return 2;
    case Type::kInt:
    case Type::kUInt:
    case Type::kFloat: return 4;
    case Type::kDouble: return 8;
    default: return 0;
  }
}

struct Property {
  std::string name;
  Type type = Type::kFloat;
  bool is_list = false;
  Type count_type = Type::kUChar;
};

struct Element {
  std::string name;
  size_t count = 0;
  std::vector<Property> props;
};

// Reads values from binary or ascii bodies, bounds-checked.
class Reader {
 public:
  Reader(const std::string& s, size_t pos, bool binary) : s_(s), pos_(pos), binary_(binary) {
    if (!binary_) ascii_.str(s_.substr(pos_));
  }
  bool read(Type t, double& v) {
    if (!binary_) return static_cast<bool>(ascii_ >> v);
    const size_t n = sizeOf(t);
    if (n == 0 || pos_ + n > s_.size()) return false;
    const char* p = s_.data() + pos_;
    pos_ += n;
    switch (t) {
      case Type::kChar: v = static_cast<int8_t>(*p); break;
      case Type::kUChar: v = static_cast<uint8_t>(*p); break;
      case Type::kShort: { int16_t x; std::memcpy(&x, p, 2); v = x; break; }
      case Type::kUShort: { uint16_t x; std::memcpy(&x, p, 2); v = x; break; }
      case Type::kInt: { int32_t x; std::memcpy(&x, p, 4); v = x; break; }
      case Type::kUInt: { uint32_t x; std::memcpy(&x, p, 4); v = x; break; }
      case Type::kFloat: { float x; std::memcpy(&x, p, 4); v = x; break; }
      case Type::kDouble: { double x; std::memcpy(&x, p, 8); v = x; break; }
      default: return false;
    }
    return true;
  }

 private:
  const std::string& s_;
  size_t pos_;
  bool binary_;
  std::istringstream ascii_;
};

}  // namespace

Expected<alg::TriangleMesh> parsePly(const std::string& content, const std::string& source) {
  if (content.compare(0, 3, "ply") != 0) return Error{source + ": not a PLY file (no 'ply' magic)"};
  const size_t end = content.find("end_header");
  if (end == std::string::npos) return Error{source + ": PLY header has no end_header"};
  size_t body = content.find('\n', end);
  if (body == std::string::npos) return Error{source + ": PLY header is truncated"};
  ++body;
  std::istringstream header(content.substr(0, end));
  std::string line, format;
  std::vector<Element> elements;
  while (std::getline(header, line)) {
    std::istringstream ls(line);
    std::string word;
    ls >> word;
    if (word == "format") {
      ls >> format;
    } else if (word == "element") {
      Element e;
      long long count = -1;
      ls >> e.name >> count;
      if (count < 0 || count > 500'000'000) return Error{source + ": bad element count in '" + line + "'"};
      e.count = static_cast<size_t>(count);
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) return Error{source + ": property before any element"};
      Property p;
      std::string t;
      ls >> t;
      if (t == "list") {
        std::string ct, it;
        ls >> ct >> it >> p.name;
        p.is_list = true;
        p.count_type = parseType(ct);
        p.type = parseType(it);
      } else {
        p.type = parseType(t);
        ls >> p.name;
      }
      if (p.type == Type::kInvalid || p.count_type == Type::kInvalid) {
        return Error{source + ": unknown property type in '" + line + "'"};
      }
      elements.back().props.push_back(p);
    }
  }
  if (format != "ascii" && format != "binary_little_endian") {
    return Error{source + ": PLY format '" + format + "' not supported (ascii or binary_little_endian)"};
  }
  Reader r(content, body, format != "ascii");
  alg::TriangleMesh mesh;
  const std::string truncated = source + ": PLY body is truncated or malformed";
  for (const auto& e : elements) {
    const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
    int ix = -1, iy = -1, iz = -1, ir = -1, ig = -1, ib = -1;
    for (int k = 0; k < static_cast<int>(e.props.size()); ++k) {
      const auto& n = e.props[k].name;
      if (n == "x") ix = k;
      if (n == "y") iy = k;
      if (n == "z") iz = k;
      if (n == "red") ir = k;
      if (n == "green") ig = k;
      if (n == "blue") ib = k;
    }
    if (is_vertex && (ix < 0 || iy < 0 || iz < 0)) return Error{source + ": vertex element lacks x, y or z"};
    const bool colors = is_vertex && ir >= 0 && ig >= 0 && ib >= 0;
    std::vector<double> values(e.props.size());
    for (size_t i = 0; i < e.count; ++i) {
      std::vector<int> face;
      for (size_t k = 0; k < e.props.size(); ++k) {
        const auto& p = e.props[k];
        if (!p.is_list) {
          if (!r.read(p.type, values[k])) return Error{truncated};
          continue;
        }
        double count = 0;
        if (!r.read(p.count_type, count) || count < 0 || count > 1000) return Error{truncated};
        for (int c = 0; c < static_cast<int>(count); ++c) {
          double v = 0;
          if (!r.read(p.type, v)) return Error{truncated};
          if (is_face) face.push_back(static_cast<int>(v));
        }
      }
      if (is_vertex) {
        mesh.vertices.emplace_back(values[ix], values[iy], values[iz]);
        if (colors) mesh.colors.emplace_back(values[ir], values[ig], values[ib]);
      }
      for (size_t c = 2; c < face.size(); ++c) mesh.triangles.emplace_back(face[0], face[c - 1], face[c]);
    }
  }
  const int nv = static_cast<int>(mesh.vertices.size());
  for (const auto& t : mesh.triangles) {
    if (t.minCoeff() < 0 || t.maxCoeff() >= nv) return Error{source + ": a face references a missing vertex"};
  }
  for (const auto& v : mesh.vertices) {
    if (!v.allFinite()) return Error{source + ": a vertex coordinate is not finite"};
  }
  return mesh;
}

Expected<alg::TriangleMesh> readPly(const std::string& path) {
  auto text = readTextFile(path);
  if (!text) return Error{text.message()};
  return parsePly(*text, path);
}

}  // namespace hxmap::drv
