// Small helpers shared by the command-line tools (tools/ only).
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "skinbus/common/stats.h"

namespace skinbus::tools {

// Parses "1-4,7,9-10" into node IDs, each within [lo, hi]. Throws std::invalid_argument with
// a message naming the bad part (tools report it and exit non-zero).
inline std::vector<int> parse_id_list(const std::string& text, int lo, int hi) {
  std::vector<int> out;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t comma = text.find(',', pos);
    const std::string part =
        text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    if (part.empty()) throw std::invalid_argument("empty entry in ID list '" + text + "'");
    const std::size_t dash = part.find('-');
    int a = 0, b = 0;
    try {
      std::size_t used = 0;
      a = std::stoi(part.substr(0, dash), &used);
      if (used != (dash == std::string::npos ? part.size() : dash)) throw std::invalid_argument("");
      b = a;
      if (dash != std::string::npos) {
        const std::string rest = part.substr(dash + 1);
        b = std::stoi(rest, &used);
        if (used != rest.size()) throw std::invalid_argument("");
      }
    } catch (const std::exception&) {
      throw std::invalid_argument("bad ID list entry '" + part + "' (expected N or N-M)");
    }
    if (a < lo || b > hi || a > b) {
      throw std::invalid_argument("ID range '" + part + "' outside " + std::to_string(lo) + "-" +
                                  std::to_string(hi));
    }
    for (int i = a; i <= b; ++i) out.push_back(i);
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  return out;
}

using skinbus::mean;
using skinbus::quantile;

// Set by SIGINT / SIGTERM once install_stop_handler() ran; long-running tools poll it.
inline std::atomic<bool>& stop_requested() {
  static std::atomic<bool> flag{false};
  return flag;
}
inline void install_stop_handler() {
  auto handler = [](int) { stop_requested().store(true); };
  std::signal(SIGINT, handler);
  std::signal(SIGTERM, handler);
  std::signal(SIGPIPE, SIG_IGN);
}

}  // namespace skinbus::tools
