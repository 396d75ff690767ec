// Fuzzes the candump line parser. Anything it accepts, written back in candump form and parsed
// again, gives the same frame.
#include <cstdlib>
#include <string_view>

#include "skinbus/bus/candump.h"

using namespace skinbus::bus;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  std::string_view text(reinterpret_cast<const char*>(data), size);
  std::size_t start = 0;
  while (start <= text.size()) {
    std::size_t end = text.find('\n', start);
    if (end == std::string_view::npos) end = text.size();
    CandumpRecord rec;
    if (parse_candump_line(text.substr(start, end - start), &rec) == CandumpError::kNone) {
      char line[kCandumpLineMax];
      const std::size_t n =
          format_candump_line(rec.frame, rec.timestamp_us % 100000000000000000ull, "can0", line);
      CandumpRecord again;
      if (n == 0 || parse_candump_line(std::string_view(line, n), &again) != CandumpError::kNone)
        std::abort();
      if (!(again.frame == rec.frame)) std::abort();
    }
    start = end + 1;
  }
  return 0;
}
