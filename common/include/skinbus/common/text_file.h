// skinbus/common/text_file.h: reading a whole text file with an error that names it. Header-only,
// no dependencies beyond the standard library (the model files' reader uses it where yaml-cpp is
// not built, as in the Arm cross build).
#pragma once

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>

#include "skinbus/common/result.h"

namespace skinbus {

// Reads a whole text file; `what` names it in the error ("config file", "skin map").
inline Result<std::string> read_text_file(const std::string& path, const std::string& what) {
  std::ifstream in(path);
  if (!in) return make_error(ErrorCode::kNotFound, what + " " + path + ": " + std::strerror(errno));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace skinbus
