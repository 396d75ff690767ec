// skinbus/common/csv.h: splitting and reading the fields of the project's CSV files.
//
// The CSV files here are simple: no quoting, fields separated by one character, '#' starts a
// comment line. These helpers never allocate beyond the returned field list.
#pragma once

#include <charconv>
#include <cmath>
#include <string_view>
#include <vector>

namespace skinbus {

// Fields of `line` split at `separator`, spaces, tabs and a trailing '\r' trimmed from each.
// An empty line gives one empty field.
inline std::vector<std::string_view> split_csv_fields(std::string_view line, char separator = ',') {
  std::vector<std::string_view> out;
  std::size_t pos = 0;
  while (true) {
    const std::size_t end = line.find(separator, pos);
    std::string_view f = line.substr(pos, end == std::string_view::npos ? line.npos : end - pos);
    while (!f.empty() && (f.front() == ' ' || f.front() == '\t')) f.remove_prefix(1);
    while (!f.empty() && (f.back() == ' ' || f.back() == '\t' || f.back() == '\r')) {
      f.remove_suffix(1);
    }
    out.push_back(f);
    if (end == std::string_view::npos) return out;
    pos = end + 1;
  }
}

// True for blank lines and lines whose first non-blank character is '#'.
inline bool is_csv_comment_or_blank(std::string_view line) {
  const std::size_t i = line.find_first_not_of(" \t\r");
  return i == std::string_view::npos || line[i] == '#';
}

// Reads a whole field as a finite number; false for empty, partial, NaN or Inf.
inline bool parse_csv_number(std::string_view field, double* out) {
  if (field.empty()) return false;
  if (field.front() == '+') field.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), *out);
  return ec == std::errc() && ptr == field.data() + field.size() && std::isfinite(*out);
}

// Reads a whole field as an integer in [lo, hi].
inline bool parse_csv_int(std::string_view field, long long lo, long long hi, long long* out) {
  const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), *out);
  return !field.empty() && ec == std::errc() && ptr == field.data() + field.size() && *out >= lo &&
         *out <= hi;
}

}  // namespace skinbus
