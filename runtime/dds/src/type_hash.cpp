#include "hxmap/dds/type_hash.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cstdint>
#include <set>
#include <vector>

#include <fmt/format.h>

namespace hxmap::rt::dds {

// ------------------------------------------------------------------ SHA-256

namespace {

constexpr std::array<uint32_t, 64> kRound = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

constexpr uint32_t rotr(uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }

void compress(std::array<uint32_t, 8>& h, const uint8_t* block) {
  std::array<uint32_t, 64> w{};
  for (int i = 0; i < 16; ++i) {
    w[i] = static_cast<uint32_t>(block[4 * i]) << 24 | static_cast<uint32_t>(block[4 * i + 1]) << 16 |
           static_cast<uint32_t>(block[4 * i + 2]) << 8 | static_cast<uint32_t>(block[4 * i + 3]);
  }
  for (int i = 16; i < 64; ++i) {
    const uint32_t s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >> 3);
    const uint32_t s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >> 10);
    w[i] = w[i - 16] + s0 + w[i - 7] + s1;
  }
  uint32_t a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], k = h[7];
  for (int i = 0; i < 64; ++i) {
    const uint32_t t1 = k + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + kRound[i] + w[i];
    const uint32_t t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
    k = g;
    g = f;
    f = e;
    e = d + t1;
    d = c;
    c = b;
    b = a;
    a = t1 + t2;
  }
  h[0] += a, h[1] += b, h[2] += c, h[3] += d, h[4] += e, h[5] += f, h[6] += g, h[7] += k;
}

}  // namespace

std::string sha256Hex(std::string_view data) {
  std::array<uint32_t, 8> h = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                               0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
  const auto* bytes = reinterpret_cast<const uint8_t*>(data.data());
  size_t full = data.size() / 64;
  for (size_t i = 0; i < full; ++i) compress(h, bytes + 64 * i);
  // The tail, 0x80, zeros, and the length in bits (big-endian) in one or
  // two last blocks.
  std::array<uint8_t, 128> tail{};
  const size_t rest = data.size() - 64 * full;
  std::copy(bytes + 64 * full, bytes + data.size(), tail.begin());
  tail[rest] = 0x80;
  const size_t blocks = rest + 1 + 8 <= 64 ? 1 : 2;
  const uint64_t bits = static_cast<uint64_t>(data.size()) * 8;
  for (int i = 0; i < 8; ++i) tail[64 * blocks - 1 - i] = static_cast<uint8_t>(bits >> (8 * i));
  for (size_t i = 0; i < blocks; ++i) compress(h, tail.data() + 64 * i);
  std::string out;
  for (uint32_t v : h) out += fmt::format("{:08x}", v);
  return out;
}

// ------------------------------------------------------------- IDL subset

namespace {

// A field as REP 2011's type description has it (FieldType ids of
// type_description_interfaces).
struct Field {
  std::string name;
  int type_id = 0;
  uint64_t capacity = 0, string_capacity = 0;
  std::string nested;  ///< "pkg/msg/Name" for nested types, else empty
};

struct Type {
  std::string name;  ///< "pkg/msg/Name"
  std::vector<Field> fields;
};

struct Token {
  std::string text;
  int line = 0;
};

std::vector<Token> tokenize(const std::string& idl) {
  std::vector<Token> out;
  int line = 1;
  for (size_t i = 0; i < idl.size();) {
    const char c = idl[i];
    if (c == '\n') {
      ++line;
      ++i;
    } else if (std::isspace(static_cast<unsigned char>(c))) {
      ++i;
    } else if (idl.compare(i, 2, "//") == 0) {
      while (i < idl.size() && idl[i] != '\n') ++i;
    } else if (idl.compare(i, 2, "/*") == 0) {
      const size_t end = idl.find("*/", i + 2);
      for (size_t j = i; j < std::min(end, idl.size()); ++j) line += idl[j] == '\n';
      i = end == std::string::npos ? idl.size() : end + 2;
    } else if (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '@' || c == ':') {
      size_t j = i;
      while (j < idl.size() && (std::isalnum(static_cast<unsigned char>(idl[j])) || idl[j] == '_' || idl[j] == ':' ||
                                (j == i && idl[j] == '@'))) {
        ++j;
      }
      out.push_back({idl.substr(i, j - i), line});
      i = j;
    } else {
      out.push_back({std::string(1, c), line});
      ++i;
    }
  }
  return out;
}

// FieldType ids of the basic types (type_description_interfaces/FieldType).
int basicTypeId(const std::string& t) {
  static const std::map<std::string, int> kIds = {{"int8", 2},     {"uint8", 3},   {"int16", 4},   {"uint16", 5},
                                                  {"int32", 6},    {"uint32", 7},  {"int64", 8},   {"uint64", 9},
                                                  {"float", 10},   {"double", 11}, {"char", 13},   {"wchar", 14},
                                                  {"boolean", 15}, {"octet", 16},  {"string", 17}, {"wstring", 18}};
  const auto it = kIds.find(t);
  return it == kIds.end() ? 0 : it->second;
}

// "pkg::msg::dds_::Name_" -> "pkg/msg/Name" (empty when not that form).
std::string rosName(const std::string& dds) {
  const size_t a = dds.find("::msg::dds_::");
  if (a == std::string::npos || dds.size() < a + 14 || dds.back() != '_') return {};
  return dds.substr(0, a) + "/msg/" + dds.substr(a + 13, dds.size() - a - 14);
}

class Parser {
 public:
  Parser(std::vector<Token> tokens, std::string source) : t_(std::move(tokens)), source_(std::move(source)) {}

  Status parse(std::map<std::string, Type>& types) {
    while (i_ < t_.size()) {
      if (auto s = definition(types); !s) return s;
    }
    return Status::ok();
  }

 private:
  const std::string& peek() const {
    static const std::string kEnd;
    return i_ < t_.size() ? t_[i_].text : kEnd;
  }
  Error fail(const std::string& what) const {
    const int line = i_ < t_.size() ? t_[i_].line : (t_.empty() ? 0 : t_.back().line);
    return Error{fmt::format("{}:{}: {}", source_, line, what)};
  }
  bool take(const std::string& s) {
    if (peek() != s) return false;
    ++i_;
    return true;
  }

  Status definition(std::map<std::string, Type>& types) {
    if (take("module")) {
      const std::string name = peek();
      ++i_;
      if (!take("{")) return fail("expected '{' after module " + name);
      scope_.push_back(name);
      while (!take("}")) {
        if (i_ >= t_.size()) return fail("module " + name + " is not closed");
        if (auto s = definition(types); !s) return s;
      }
      scope_.pop_back();
      take(";");
      return Status::ok();
    }
    if (take("struct")) return structure(types);
    return fail(fmt::format("expected module or struct, got '{}'", peek()));
  }

  Status structure(std::map<std::string, Type>& types) {
    std::string dds;
    for (const auto& s : scope_) dds += s + "::";
    dds += peek();
    ++i_;
    Type type{rosName(dds), {}};
    if (type.name.empty()) return fail("struct " + dds + " is not named pkg::msg::dds_::Name_");
    if (!take("{")) return fail("expected '{' after struct " + dds);
    while (!take("}")) {
      if (i_ >= t_.size()) return fail("struct " + dds + " is not closed");
      if (auto s = member(type); !s) return s;
    }
    take(";");
    types[dds] = std::move(type);
    return Status::ok();
  }

  // [@annotation[(...)]]* type name ["[" N "]"] ("," name ...)* ";"
  Status member(Type& type) {
    while (!peek().empty() && peek()[0] == '@') {
      ++i_;
      if (take("(")) {
        while (i_ < t_.size() && !take(")")) ++i_;
      }
    }
    Field base;
    if (auto s = fieldType(base); !s) return s;
    do {
      Field f = base;
      f.name = peek();
      ++i_;
      if (take("[")) {
        f.capacity = std::stoull(peek());
        ++i_;
        if (!take("]")) return fail("expected ']'");
        f.type_id += 48;  // ..._ARRAY
      }
      type.fields.push_back(std::move(f));
    } while (take(","));
    if (!take(";")) return fail(fmt::format("expected ';' after member of {}", type.name));
    return Status::ok();
  }

  Status fieldType(Field& f) {
    if (take("sequence")) {
      if (!take("<")) return fail("expected '<' after sequence");
      if (auto s = fieldType(f); !s) return s;
      const bool bounded = take(",");
      if (bounded) ++i_;  // the bound: REP 2011 records no capacity for sequences
      if (!take(">")) return fail("expected '>' closing the sequence");
      f.type_id += bounded ? 96 : 144;  // ..._BOUNDED_SEQUENCE / _UNBOUNDED_SEQUENCE
      return Status::ok();
    }
    const std::string t = peek();
    ++i_;
    if ((t == "string" || t == "wstring") && take("<")) {
      f.string_capacity = std::stoull(peek());
      ++i_;
      if (!take(">")) return fail("expected '>' closing the string bound");
      f.type_id = t == "string" ? 21 : 22;  // BOUNDED_STRING / BOUNDED_WSTRING
      return Status::ok();
    }
    if (const int id = basicTypeId(t); id > 0) {
      f.type_id = id;
      return Status::ok();
    }
    f.nested = rosName(t);
    if (f.nested.empty()) return fail(fmt::format("type '{}' is neither a basic type nor pkg::msg::dds_::Name_", t));
    f.type_id = 1;  // NESTED_TYPE
    return Status::ok();
  }

  std::vector<Token> t_;
  std::string source_;
  size_t i_ = 0;
  std::vector<std::string> scope_;
};

std::string typeJson(const Type& t) {
  std::string out = fmt::format("{{\"type_name\": \"{}\", \"fields\": [", t.name);
  for (size_t k = 0; k < t.fields.size(); ++k) {
    const Field& f = t.fields[k];
    out += fmt::format(
        "{}{{\"name\": \"{}\", \"type\": {{\"type_id\": {}, \"capacity\": {}, \"string_capacity\": {}, "
        "\"nested_type_name\": \"{}\"}}}}",
        k ? ", " : "", f.name, f.type_id, f.capacity, f.string_capacity, f.nested);
  }
  return out + "]}";
}

}  // namespace

Expected<std::map<std::string, std::string>> rosTypeHashes(const std::string& idl, const std::string& source) {
  std::map<std::string, Type> types;  // by DDS name
  if (auto s = Parser(tokenize(idl), source).parse(types); !s) return Error{s.message()};
  std::map<std::string, const Type*> by_ros;
  for (const auto& [dds, t] : types) by_ros[t.name] = &t;
  std::map<std::string, std::string> out;
  for (const auto& [dds, t] : types) {
    // The types it refers to, directly or not, sorted by name (a std::set).
    std::set<std::string> refs;
    std::vector<std::string> queue;
    for (const Field& f : t.fields) {
      if (!f.nested.empty()) queue.push_back(f.nested);
    }
    while (!queue.empty()) {
      const std::string name = queue.back();
      queue.pop_back();
      if (!refs.insert(name).second) continue;
      const auto it = by_ros.find(name);
      if (it == by_ros.end())
        return Error{fmt::format("{}: {} refers to {}, which it does not define", source, t.name, name)};
      for (const Field& f : it->second->fields) {
        if (!f.nested.empty()) queue.push_back(f.nested);
      }
    }
    std::string json = "{\"type_description\": " + typeJson(t) + ", \"referenced_type_descriptions\": [";
    bool first = true;
    for (const std::string& r : refs) {
      json += (first ? "" : ", ") + typeJson(*by_ros.at(r));
      first = false;
    }
    json += "]}";
    out[dds] = "RIHS01_" + sha256Hex(json);
  }
  return out;
}

const std::map<std::string, std::string>& wireTypeHashes() {
  static const std::map<std::string, std::string> hashes = [] {
    static const char* const kIdl =
#include "hxmap_msgs_idl.inc"
        ;
    auto h = rosTypeHashes(kIdl, "hxmap_msgs.idl");
    return h ? *h : std::map<std::string, std::string>{};  // a parse error is caught by the tests
  }();
  return hashes;
}

}  // namespace hxmap::rt::dds
