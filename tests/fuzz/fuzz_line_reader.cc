// Fuzzes the bounded line readers (skinbus/common/line_reader.h) and the candump log reader on
// top of one. The first input byte picks the line bound (1..256 bytes, small so that the fuzzer
// reaches it); the rest is the text, read through a pipe in chunks as a stream arrives.
// Invariants beyond "does not crash":
// - LineReader: every line it returns is at most the bound and holds no '\n'; the lines (and the
//   skipped ones) are numbered 1, 2, ... without a gap, one per '\n' plus a last unterminated
//   line; the lines it returns are exactly the input's lines that fit, in order;
// - getline_bounded over the same text gives the same lines and the same skipped ones;
// - CandumpReader: records + bad lines = the lines that are neither blank nor comments, and no
//   line longer than kCandumpMaxLineBytes is a record.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "skinbus/bus/candump.h"
#include "skinbus/common/line_reader.h"

using namespace skinbus;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_line_reader: %s\n", what);
  std::abort();
}

struct Line {
  bool too_long;
  std::string text;
};

// The input's lines as they should come out for `bound`.
std::vector<Line> expected_lines(std::string_view text, std::size_t bound) {
  std::vector<Line> out;
  std::size_t start = 0;
  while (start < text.size()) {
    std::size_t end = text.find('\n', start);
    const bool last = end == std::string_view::npos;
    if (last) end = text.size();
    const std::string_view l = text.substr(start, end - start);
    out.push_back({l.size() > bound, l.size() > bound ? std::string() : std::string(l)});
    start = end + 1;
  }
  return out;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::size_t bound = 1 + data[0] % 256;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  const std::vector<Line> want = expected_lines(text, bound);

  // LineReader through a pipe, the writer sending chunks of 7 bytes.
  int fds[2];
  if (::pipe(fds) != 0) return 0;
  std::thread writer([&] {
    for (std::size_t i = 0; i < text.size(); i += 7) {
      const std::size_t n = std::min<std::size_t>(7, text.size() - i);
      if (::write(fds[1], text.data() + i, n) != static_cast<ssize_t>(n)) break;
    }
    ::close(fds[1]);
  });
  std::vector<Line> got;
  {
    LineReader r(fds[0], bound, /*wait_ms=*/50);
    std::string_view line;
    for (;;) {
      const LineReader::Status st = r.next(&line);
      if (st == LineReader::Status::kEof || st == LineReader::Status::kError) break;
      if (st == LineReader::Status::kWait) continue;
      if (r.line_number() != got.size() + 1) fail("line numbers skip");
      if (st == LineReader::Status::kTooLong) {
        got.push_back({true, ""});
        continue;
      }
      if (line.size() > bound) fail("a line longer than the bound was returned");
      if (line.find('\n') != std::string_view::npos) fail("a line holds a newline");
      got.push_back({false, std::string(line)});
    }
  }
  writer.join();
  ::close(fds[0]);
  if (got.size() != want.size()) fail("LineReader: another number of lines");
  for (std::size_t i = 0; i < got.size(); ++i) {
    if (got[i].too_long != want[i].too_long || got[i].text != want[i].text) {
      fail("LineReader: another line");
    }
  }

  // getline_bounded: the same.
  std::istringstream in(text);
  std::string line;
  std::size_t i = 0;
  for (BoundedLine st; (st = getline_bounded(in, line, bound)) != BoundedLine::kEof; ++i) {
    if (i >= want.size() || (st == BoundedLine::kTooLong) != want[i].too_long ||
        (st == BoundedLine::kLine && line != want[i].text)) {
      fail("getline_bounded: another line");
    }
  }
  if (i != want.size()) fail("getline_bounded: another number of lines");

  // CandumpReader over the text (its own bound).
  std::FILE* f = fmemopen(const_cast<char*>(text.data()), text.size(), "r");
  if (f == nullptr) return 0;
  bus::CandumpReader reader(f);
  bus::CandumpRecord rec;
  uint64_t records = 0;
  for (;;) {
    const auto st = reader.next(&rec);
    if (st == bus::CandumpReader::Status::kEof) break;
    if (st == bus::CandumpReader::Status::kRecord) {
      ++records;
      if (reader.line().size() > bus::kCandumpMaxLineBytes) fail("an overlong candump line read");
    }
  }
  std::fclose(f);
  uint64_t content = 0;
  for (const Line& l : expected_lines(text, bus::kCandumpMaxLineBytes)) {
    if (l.too_long) {
      ++content;
      continue;
    }
    bus::CandumpRecord r;
    if (bus::parse_candump_line(l.text, &r) != bus::CandumpError::kEmpty) ++content;
  }
  if (records + reader.bad_lines() != content) fail("CandumpReader: lines lost or counted twice");
  return 0;
}
