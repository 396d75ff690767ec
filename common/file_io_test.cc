// Bounded line reading, input files that are not files, and atomic output files.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/line_reader.h"
#include "skinbus/common/text_file.h"

namespace skinbus {
namespace {

class TempDir {
 public:
  TempDir() {
    char tmpl[] = "/tmp/skinbus_file_io_XXXXXX";
    path_ = ::mkdtemp(tmpl);
  }
  ~TempDir() { std::system(("rm -rf '" + path_ + "'").c_str()); }
  std::string file(const std::string& name) const { return path_ + "/" + name; }
  const std::string& path() const { return path_; }
  std::vector<std::string> entries() const {
    std::vector<std::string> out;
    FILE* p = ::popen(("ls -A '" + path_ + "'").c_str(), "r");
    char buf[512];
    while (p && std::fgets(buf, sizeof buf, p)) {
      std::string s(buf);
      if (!s.empty() && s.back() == '\n') s.pop_back();
      out.push_back(s);
    }
    if (p) ::pclose(p);
    return out;
  }

 private:
  std::string path_;
};

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Every status and line a reader gives over `text` written into a pipe in one go.
std::vector<std::string> read_all(const std::string& text, std::size_t max_line) {
  int fds[2];
  EXPECT_EQ(::pipe(fds), 0);
  EXPECT_EQ(::write(fds[1], text.data(), text.size()), static_cast<ssize_t>(text.size()));
  ::close(fds[1]);
  LineReader r(fds[0], max_line);
  std::vector<std::string> out;
  std::string_view line;
  for (;;) {
    const LineReader::Status st = r.next(&line);
    if (st == LineReader::Status::kEof) break;
    if (st == LineReader::Status::kLine) {
      out.push_back(std::to_string(r.line_number()) + ":" + std::string(line));
    } else if (st == LineReader::Status::kTooLong) {
      out.push_back(std::to_string(r.line_number()) + ":too long");
    } else {
      out.push_back("unexpected status");
      break;
    }
  }
  ::close(fds[0]);
  return out;
}

TEST(LineReader, SkipsLinesBeyondTheBoundAndKeepsCounting) {
  const std::string text = "short\n" + std::string(40, 'x') + "\nafter\nlast-no-newline";
  EXPECT_EQ(read_all(text, 16),
            (std::vector<std::string>{"1:short", "2:too long", "3:after", "4:last-no-newline"}));
  // Exactly the bound is accepted; one more is not.
  EXPECT_EQ(read_all(std::string(16, 'a') + "\n" + std::string(17, 'b') + "\n", 16),
            (std::vector<std::string>{"1:" + std::string(16, 'a'), "2:too long"}));
  // A long last line without a newline, and empty lines.
  EXPECT_EQ(read_all("\n\n" + std::string(100, 'z'), 8),
            (std::vector<std::string>{"1:", "2:", "3:too long"}));
}

TEST(LineReader, MemoryStaysBoundedOnAnEndlessLine) {
  // 64 MiB of zeros without a newline, through a pipe from a child: the reader's buffer is fixed
  // (max + 64 KiB), so it only counts the one line as too long.
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const pid_t child = ::fork();
  if (child == 0) {
    ::close(fds[0]);
    std::string zeros(1 << 20, '\0');
    for (int i = 0; i < 64; ++i) {
      if (::write(fds[1], zeros.data(), zeros.size()) < 0) ::_exit(1);
    }
    ::_exit(0);
  }
  ::close(fds[1]);
  LineReader r(fds[0], 4096);
  std::string_view line;
  EXPECT_EQ(r.next(&line), LineReader::Status::kTooLong);
  EXPECT_EQ(r.line_number(), 1u);
  EXPECT_EQ(r.bytes_read(), 64ull << 20);
  EXPECT_EQ(r.next(&line), LineReader::Status::kEof);
  ::close(fds[0]);
  int status = 0;
  ::waitpid(child, &status, 0);
}

TEST(LineReader, AQuietPipeAnswersWaitWithoutLosingData) {
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  LineReader r(fds[0], 64, /*wait_ms=*/10);
  std::string_view line;
  ASSERT_EQ(::write(fds[1], "par", 3), 3);
  EXPECT_EQ(r.next(&line), LineReader::Status::kWait);  // half a line, then nothing
  ASSERT_EQ(::write(fds[1], "tial\nnext\n", 10), 10);
  ASSERT_EQ(r.next(&line), LineReader::Status::kLine);
  EXPECT_EQ(line, "partial");
  ASSERT_EQ(r.next(&line), LineReader::Status::kLine);
  EXPECT_EQ(line, "next");
  EXPECT_EQ(r.next(&line), LineReader::Status::kWait);
  ::close(fds[1]);
  EXPECT_EQ(r.next(&line), LineReader::Status::kEof);
  ::close(fds[0]);
}

TEST(GetlineBounded, SkipsLongLines) {
  std::istringstream in("ab\n" + std::string(50, 'c') + "\nde");
  std::string line;
  EXPECT_EQ(getline_bounded(in, line, 10), BoundedLine::kLine);
  EXPECT_EQ(line, "ab");
  EXPECT_EQ(getline_bounded(in, line, 10), BoundedLine::kTooLong);
  EXPECT_EQ(line, "");
  EXPECT_EQ(getline_bounded(in, line, 10), BoundedLine::kLine);
  EXPECT_EQ(line, "de");
  EXPECT_EQ(getline_bounded(in, line, 10), BoundedLine::kEof);
}

TEST(TextFile, RefusesADirectoryAndAFileTooLarge) {
  TempDir dir;
  Result<std::string> d = read_text_file(dir.path(), "skin map");
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.error().message.find("is a directory"), std::string::npos) << d.error().message;
  EXPECT_NE(d.error().message.find("skin map " + dir.path()), std::string::npos);
  std::ofstream(dir.file("big")) << std::string(1000, 'x');
  Result<std::string> big = read_text_file(dir.file("big"), "unit file", 999);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.error().code, ErrorCode::kOutOfRange);
  EXPECT_NE(big.error().message.find("1000 bytes, more than the 999"), std::string::npos);
  Result<std::string> fits = read_text_file(dir.file("big"), "unit file", 1000);
  ASSERT_TRUE(fits.ok());
  EXPECT_EQ(fits->size(), 1000u);
  Result<std::string> missing = read_text_file(dir.file("nope"), "model metadata");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
}

TEST(AtomicFile, NothingChangesUntilCommitAndNoTemporaryIsLeft) {
  TempDir dir;
  const std::string path = dir.file("out.csv");
  std::ofstream(path) << "old\n";
  {
    AtomicFile f;
    ASSERT_TRUE(f.open(path, "dataset").ok());
    ASSERT_TRUE(f.write("new 1\n").ok());
    EXPECT_EQ(slurp(path), "old\n");  // a reader still sees the old file
    // Abandoned (an error elsewhere, a crash): the old file stays, the temporary goes.
  }
  EXPECT_EQ(slurp(path), "old\n");
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.csv"});
  ASSERT_TRUE(write_file_atomic(path, "new 2\n", "dataset").ok());
  EXPECT_EQ(slurp(path), "new 2\n");
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.csv"});
}

TEST(AtomicFile, AFullDiskIsAnErrorNamingTheFile) {
  // /dev/full is not a regular file: written in place, and every write fails with ENOSPC.
  Status s = write_file_atomic("/dev/full", std::string(1 << 16, 'x'), "model weights");
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kIo);
  EXPECT_NE(s.error().message.find("model weights /dev/full"), std::string::npos)
      << s.error().message;
  EXPECT_NE(s.error().message.find(std::strerror(ENOSPC)), std::string::npos);
  // A folder that does not exist.
  Status t = write_file_atomic("/nonexistent/dir/x.json", "{}", "model metadata");
  ASSERT_FALSE(t.ok());
  EXPECT_NE(t.error().message.find("/nonexistent/dir/x.json"), std::string::npos);
}

TEST(Fingerprint, Fnv1a64KnownValues) {
  EXPECT_EQ(fnv1a64(""), 0xcbf29ce484222325ull);
  EXPECT_EQ(fnv1a64("a"), 0xaf63dc4c8601ec8cull);
  EXPECT_NE(fnv1a64("ab"), fnv1a64("ba"));
}

}  // namespace
}  // namespace skinbus
