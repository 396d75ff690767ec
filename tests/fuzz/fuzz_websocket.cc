// Fuzzes the web view's client-side inputs (skinbus/view): the WebSocket frame reader and the
// HTTP request head parser. The first byte splits the rest: the frame stream is fed to a
// FrameReader (4096-byte bound) in pieces whose sizes come from the input, the remainder is
// parsed as a request head. Invariants beyond "does not crash":
// - FrameReader: no frame's payload is over the bound; after an error it returns only errors
//   and holds nothing; it never buffers more than what was fed and not yet returned;
// - the head parser: a request it accepts has a path starting with '/' and holding no "..",
//   '\\' or '%', and header names in lower case;
// - the page command parser (the same bytes as a page's message): a command it accepts is a tare
//   or a mode change of a node in 1..125, and its answer is JSON.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "skinbus/view/http_request.h"
#include "skinbus/view/page_command.h"
#include "skinbus/view/websocket.h"

using namespace skinbus;
using namespace skinbus::view;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_websocket: %s\n", what);
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 2) return 0;
  const std::size_t split = std::min<std::size_t>(size - 1, data[0] * 4u);
  const uint8_t* frames = data + 1;
  const std::size_t frames_size = split;
  const std::string_view head(reinterpret_cast<const char*>(data + 1 + split), size - 1 - split);

  constexpr std::size_t kBound = 4096;
  FrameReader reader(kBound);
  std::size_t at = 0, fed = 0;
  bool failed = false;
  while (at < frames_size) {
    const std::size_t piece = std::min<std::size_t>(frames_size - at, 1 + frames[at] % 97);
    reader.feed({frames + at, piece});
    fed += failed ? 0 : piece;
    at += piece;
    ClientFrame frame;
    for (;;) {
      const auto step = reader.next(&frame);
      if (step == FrameReader::Step::kNeedMore) break;
      if (step == FrameReader::Step::kError) {
        failed = true;
        if (reader.buffered_bytes() != 0) fail("bytes held after an error");
        if (reader.close_code() == 0) fail("an error without a close code");
        break;
      }
      if (failed) fail("a frame after an error");
      if (frame.payload.size() > kBound) fail("a payload over the bound");
    }
    if (!failed && reader.buffered_bytes() > fed) fail("more buffered than fed");
  }

  auto length = request_head_length(head);
  if (length.ok() && *length > head.size()) fail("a head longer than the input");
  auto request = parse_request_head(head);
  if (request.ok()) {
    const std::string& p = request->path;
    if (p.empty() || p[0] != '/') fail("a path not starting with '/'");
    if (p.find("..") != std::string::npos || p.find_first_of("\\%") != std::string::npos) {
      fail("a path that could leave the served folders");
    }
    for (const auto& [name, value] : request->headers) {
      for (char c : name) {
        if (c >= 'A' && c <= 'Z') fail("a header name not in lower case");
      }
    }
    (void)request->is_websocket_upgrade();
  }
  auto command = parse_page_command(head);
  if (command.ok()) {
    if (command->node < 1 || command->node > 125) fail("a command to a node outside 1..125");
    if (command->command.opcode != bus::Opcode::kTare &&
        command->command.opcode != bus::Opcode::kSetMode) {
      fail("a command other than tare and mode");
    }
  }
  const std::string answer =
      command_result_to_json(command.ok() ? &*command : nullptr, command.ok(), "fuzz");
  if (answer.empty() || answer.front() != '{') fail("an answer that is not a JSON object");
  return 0;
}
