// skinbus/common/yaml_reader.h: reading YAML settings files with errors that name the setting
// and its line, and writing strings that read back identically. Shared by every file format of
// the project that is YAML (patch node settings, skin maps). Header-only; link skinbus::yaml.
// Also gives read_text_file (skinbus/common/text_file.h).
#pragma once

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/common/text_file.h"

namespace skinbus {

// Reading a YAML tree with the path of every value, so errors can name it. Conversion errors
// are collected as the first Error; later reads are skipped.
class YamlReader {
 public:
  std::optional<Error> error;

  void fail(const std::string& path, const YAML::Node& n, const std::string& what) {
    if (error) return;
    std::string where = path;
    if (n.Mark().line >= 0) {
      where += " (line " + std::to_string(n.Mark().line + 1) + ")";
    }
    error = make_error(ErrorCode::kParse, where + ": " + what);
  }

  // Keys of a map that are not in `known`: an error naming the first.
  void only(const YAML::Node& map, const std::string& path,
            std::initializer_list<const char*> known) {
    if (error) return;
    if (!map.IsMap()) {
      fail(path.empty() ? "(top level)" : path, map, "expected a mapping of settings");
      return;
    }
    std::vector<std::string> seen;
    for (const auto& kv : map) {
      const std::string key = kv.first.as<std::string>();
      if (std::find(seen.begin(), seen.end(), key) != seen.end()) {
        error = make_error(ErrorCode::kInvalidArgument,
                           (path.empty() ? "" : path + ".") + key + " (line " +
                               std::to_string(kv.first.Mark().line + 1) + "): given twice");
        return;
      }
      seen.push_back(key);
      bool ok = false;
      for (const char* k : known) ok = ok || key == k;
      if (!ok) {
        std::string list;
        for (const char* k : known) list += std::string(list.empty() ? "" : ", ") + k;
        error = make_error(ErrorCode::kInvalidArgument,
                           (path.empty() ? "" : path + ".") + key + " (line " +
                               std::to_string(kv.first.Mark().line + 1) +
                               "): unknown setting; known here: " + list);
        return;
      }
    }
  }

  bool integer(const YAML::Node& n, const std::string& path, long long lo, long long hi,
               long long* out) {
    if (error || !n) return false;
    if (!n.IsScalar()) {
      fail(path, n, "expected an integer");
      return false;
    }
    const std::string s = n.Scalar();
    errno = 0;
    char* end = nullptr;
    const long long v = std::strtoll(s.c_str(), &end, 0);
    if (s.empty() || *end != '\0' || errno != 0) {
      fail(path, n, "'" + s + "' is not an integer");
      return false;
    }
    if (v < lo || v > hi) {
      fail(path, n, s + " is outside " + std::to_string(lo) + ".." + std::to_string(hi));
      error->code = ErrorCode::kOutOfRange;
      return false;
    }
    *out = v;
    return true;
  }
  template <typename T>
  void get_int(const YAML::Node& map, const char* key, const std::string& path, long long lo,
               long long hi, T* out) {
    long long v;
    if (integer(map[key], path + key, lo, hi, &v)) *out = static_cast<T>(v);
  }
  // A 64-bit unsigned integer (decimal or 0x hex); any minus sign is refused (strtoull would
  // wrap " -5" around to a huge number).
  void get_uint64(const YAML::Node& map, const char* key, const std::string& path,
                  unsigned long long* out) {
    const YAML::Node n = map[key];
    if (error || !n) return;
    const std::string v = n.IsScalar() ? n.Scalar() : "";
    char* end = nullptr;
    errno = 0;
    const unsigned long long x = std::strtoull(v.c_str(), &end, 0);
    if (v.empty() || *end != '\0' || errno != 0 || v.find('-') != std::string::npos) {
      fail(path + key, n, "'" + v + "' is not a 64-bit unsigned integer");
      return;
    }
    *out = x;
  }
  // One scalar as a finite number; `path` names it in the error.
  bool number(const YAML::Node& n, const std::string& path, double* out) {
    if (error) return false;
    const std::string s = n.IsScalar() ? n.Scalar() : "";
    char* end = nullptr;
    const double v = std::strtod(s.c_str(), &end);
    if (s.empty() || *end != '\0' || !std::isfinite(v)) {
      fail(path, n, "'" + s + "' is not a number");
      return false;
    }
    *out = v;
    return true;
  }
  void get_double(const YAML::Node& map, const char* key, const std::string& path, double lo,
                  double hi, double* out) {
    const YAML::Node n = map[key];
    if (error || !n) return;
    double v;
    if (!number(n, path + key, &v)) return;
    const std::string s = n.Scalar();
    if (v < lo || v > hi) {
      fail(path + key, n, s + " is outside " + std::to_string(lo) + ".." + std::to_string(hi));
      error->code = ErrorCode::kOutOfRange;
      return;
    }
    *out = v;
  }
  void get_bool(const YAML::Node& map, const char* key, const std::string& path, bool* out) {
    const YAML::Node n = map[key];
    if (error || !n) return;
    const std::string s = n.IsScalar() ? n.Scalar() : "";
    if (s == "true" || s == "yes" || s == "on") {
      *out = true;
    } else if (s == "false" || s == "no" || s == "off") {
      *out = false;
    } else {
      fail(path + key, n, "'" + s + "' is not true or false");
    }
  }
  void get_string(const YAML::Node& map, const char* key, const std::string& path,
                  std::string* out) {
    const YAML::Node n = map[key];
    if (error || !n) return;
    if (!n.IsScalar()) {
      fail(path + key, n, "expected a string");
      return;
    }
    *out = n.Scalar();
  }
};

// A finite double as a YAML scalar that reads back to the same bits: 15 significant digits,
// which keep a file readable, or 17 when 15 do not read back exactly.
inline std::string yaml_number(double x) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.15g", x);
  if (std::strtod(buf, nullptr) != x) std::snprintf(buf, sizeof buf, "%.17g", x);
  return buf;
}

// A string as a YAML scalar that reads back the same: plain when that is safe, else
// double-quoted with escapes.
inline std::string yaml_string(const std::string& v) {
  // Words YAML reads as something other than a string (null) or that settings read as a
  // keyword (none, true, false) are quoted.
  bool plain = !v.empty() && v != "none" && v != "true" && v != "false" && v != "null" &&
               v != "Null" && v != "NULL";
  for (char c : v) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '.' || c == '/' || c == '-';
    plain = plain && ok;
  }
  if (plain && (v[0] == '-' || v[0] == '.')) plain = false;
  if (plain) return v;
  std::string out = "\"";
  for (unsigned char c : v) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += static_cast<char>(c);
    } else if (c < 0x20 || c == 0x7F) {  // bytes >= 0x80 stay as they are (UTF-8 text)
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    } else {
      out += static_cast<char>(c);
    }
  }
  return out + "\"";
}

// Parses `text` as YAML; a syntax error names its line and column.
inline Result<YAML::Node> parse_yaml_text(const std::string& text) {
  try {
    return YAML::Load(text);
  } catch (const YAML::Exception& e) {
    return make_error(ErrorCode::kParse, "line " + std::to_string(e.mark.line + 1) + ", column " +
                                             std::to_string(e.mark.column + 1) + ": " + e.msg);
  }
}

}  // namespace skinbus
