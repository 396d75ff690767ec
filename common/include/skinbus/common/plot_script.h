// skinbus/common/plot_script.h: running one of the project's plot scripts (tools/plot_*.py,
// python3-matplotlib) from a tool or a report, the one way they are found and called.
#pragma once

#include <cstdlib>
#include <string>
#include <vector>

#include "skinbus/common/error_format.h"
#include "skinbus/common/result.h"

namespace skinbus {

// Runs `script` (a file name, e.g. "plot_cpu.py") from $SKINBUS_TOOLS_DIR, else from
// `default_tools_dir` (the caller's source tree's tools/), with `args` each single-quoted.
// Blocks until it ends. kIo naming the command when it cannot run or exits non-zero.
inline Status run_plot_script(const std::string& default_tools_dir, const std::string& script,
                              const std::vector<std::string>& args) {
  const char* dir = std::getenv("SKINBUS_TOOLS_DIR");
  std::string cmd =
      "'" + (dir != nullptr ? std::string(dir) : default_tools_dir) + "/" + script + "'";
  for (const std::string& a : args) cmd += " '" + a + "'";
  if (std::system(cmd.c_str()) != 0)
    return errorf(ErrorCode::kIo, "the plot failed: %s", cmd.c_str());
  return Status::Ok();
}

}  // namespace skinbus
