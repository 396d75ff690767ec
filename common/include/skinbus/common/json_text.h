// skinbus/common/json_text.h: reading the project's JSON files (unit, correction and model files)
// with errors that say where. Header-only over nlohmann::json (link skinbus::json).
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "skinbus/common/result.h"

namespace skinbus {

// Parses `text` as JSON. A syntax error, or a number no double holds (1e400), is kParse
// "not valid JSON: parse error at line L, column C: ..." (the parser's words, without its tag).
inline Result<nlohmann::json> parse_json_text(std::string_view text) {
  try {
    return nlohmann::json::parse(text.begin(), text.end());
  } catch (const nlohmann::json::exception& e) {
    // "[json.exception.parse_error.101] parse error at line 3, column 7: ..." -> after the tag.
    std::string what = e.what();
    if (const std::size_t close = what.find("] "); close != std::string::npos) {
      what = what.substr(close + 2);
    }
    return make_error(ErrorCode::kParse, "not valid JSON: " + what);
  }
}

// The "format" value of a JSON document of `format`, major version `major`: "<format> <major>"
// (e.g. "skinbus-unit 1"), as its writer puts it and parse_json_document() wants it.
inline std::string json_format_name(std::string_view format, int major) {
  return std::string(format) + " " + std::to_string(major);
}

// Parses `text` as a JSON object whose "format" is "<format> <major>" (e.g. "skinbus-unit 1").
// Errors, kParse: as parse_json_text(); "not a JSON object"; "not a <what> (format is not
// '<format> <major>')"; "format '<found>': this reader knows '<format> <major>'" (another
// version of the same format).
inline Result<nlohmann::json> parse_json_document(std::string_view text, std::string_view format,
                                                  int major, std::string_view what) {
  Result<nlohmann::json> j = parse_json_text(text);
  if (!j.ok()) return j;
  if (!j->is_object()) return make_error(ErrorCode::kParse, "not a JSON object");
  const std::string want = json_format_name(format, major);
  const std::string family = std::string(format) + " ";
  const auto it = j->find("format");
  if (it == j->end() || !it->is_string() || it->get<std::string>().rfind(family, 0) != 0) {
    return make_error(ErrorCode::kParse,
                      "not a " + std::string(what) + " (format is not '" + want + "')");
  }
  if (it->get<std::string>() != want) {
    return make_error(ErrorCode::kParse,
                      "format '" + it->get<std::string>() + "': this reader knows '" + want + "'");
  }
  return j;
}

}  // namespace skinbus
