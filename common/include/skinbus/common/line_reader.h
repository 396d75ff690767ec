// skinbus/common/line_reader.h: reading text line by line with a bound on the line length, so
// that no input (a file of zeros without a newline, a pipe that never ends a line) can make a
// reader grow without limit. Header-only, POSIX and the standard library only.
//
// LineReader reads a file descriptor through one fixed buffer (max_line_bytes + 64 KiB, taken
// once): a line longer than the bound is skipped to its end and reported as kTooLong with its
// number, and reading goes on. With a wait (wait_ms >= 0) it never blocks longer than that on a
// quiet pipe or terminal and answers kWait, as it does when a signal interrupts the read, so
// that the caller can look at its stop flag and call again; no data is lost either way.
//
// getline_bounded does the same for a std::istream (the readers that take one).
#pragma once

#include <poll.h>
#include <unistd.h>

#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <istream>
#include <memory>
#include <streambuf>
#include <string>
#include <string_view>

namespace skinbus {

class LineReader {
 public:
  enum class Status : uint8_t {
    kLine,     // `line` holds the next line, without its '\n' (valid until the next call)
    kTooLong,  // a line longer than max_line_bytes was skipped; line_number() names it
    kEof,      // end of input
    kWait,     // no data within wait_ms, or a signal interrupted the read: call again
    kError,    // the read failed; error_number() holds errno
  };

  static constexpr std::size_t kChunkBytes = 64 * 1024;

  LineReader(int fd, std::size_t max_line_bytes, int wait_ms = -1)
      : fd_(fd),
        max_(max_line_bytes),
        wait_ms_(wait_ms),
        cap_(max_line_bytes + 1 + kChunkBytes),
        buf_(new char[cap_]) {}
  // A stream with a file descriptor is read through the descriptor (nothing may have been read
  // from the stream before); one without (fmemopen) through stdio, without waits.
  LineReader(std::FILE* stream, std::size_t max_line_bytes, int wait_ms = -1)
      : LineReader(stream != nullptr ? ::fileno(stream) : -1, max_line_bytes, wait_ms) {
    if (fd_ < 0) stream_ = stream;
  }

  Status next(std::string_view* line) {
    for (;;) {
      const char* start = buf_.get() + begin_;
      const void* nl = std::memchr(start, '\n', end_ - begin_);
      if (nl != nullptr) {
        const std::size_t len = static_cast<std::size_t>(static_cast<const char*>(nl) - start);
        begin_ += len + 1;
        ++line_;
        if (skipping_ || len > max_) {
          skipping_ = false;
          return Status::kTooLong;
        }
        *line = std::string_view(start, len);
        return Status::kLine;
      }
      if (end_ - begin_ > max_) {  // no end in sight: drop what is held and skip to the end
        skipping_ = true;
        begin_ = end_ = 0;
      }
      if (eof_) {
        if (end_ == begin_ && !skipping_) return Status::kEof;
        ++line_;  // the last line, without a newline
        const std::size_t len = end_ - begin_;
        *line = std::string_view(buf_.get() + begin_, len);
        begin_ = end_ = 0;
        if (skipping_) {
          skipping_ = false;
          return Status::kTooLong;
        }
        return Status::kLine;
      }
      if (begin_ > 0) {
        std::memmove(buf_.get(), buf_.get() + begin_, end_ - begin_);
        end_ -= begin_;
        begin_ = 0;
      }
      if (stream_ != nullptr) {
        const std::size_t n = std::fread(buf_.get() + end_, 1, cap_ - end_, stream_);
        end_ += n;
        bytes_ += n;
        if (n == 0) {
          if (std::ferror(stream_)) {
            errno_ = errno != 0 ? errno : EIO;
            return Status::kError;
          }
          eof_ = true;
        }
        continue;
      }
      if (wait_ms_ >= 0) {
        pollfd p{fd_, POLLIN, 0};
        const int r = ::poll(&p, 1, wait_ms_);
        if (r == 0 || (r < 0 && errno == EINTR)) return Status::kWait;
        if (r < 0) {
          errno_ = errno;
          return Status::kError;
        }
      }
      const ssize_t n = ::read(fd_, buf_.get() + end_, cap_ - end_);
      if (n < 0) {
        if (errno == EINTR || errno == EAGAIN) return Status::kWait;
        errno_ = errno;
        return Status::kError;
      }
      if (n == 0) {
        eof_ = true;
      } else {
        end_ += static_cast<std::size_t>(n);
        bytes_ += static_cast<uint64_t>(n);
      }
    }
  }

  uint64_t line_number() const { return line_; }  // of the line last returned (1-based)
  int error_number() const { return errno_; }
  uint64_t bytes_read() const { return bytes_; }
  std::size_t max_line_bytes() const { return max_; }

 private:
  int fd_;
  std::FILE* stream_ = nullptr;
  std::size_t max_;
  int wait_ms_;
  std::size_t cap_;
  std::unique_ptr<char[]> buf_;
  std::size_t begin_ = 0, end_ = 0;
  bool skipping_ = false, eof_ = false;
  uint64_t line_ = 0, bytes_ = 0;
  int errno_ = 0;
};

// std::getline with a bound: kLine (`line` without its '\n'), kTooLong (the line was longer
// than max_bytes and has been skipped to its end; `line` is cleared) or kEof.
enum class BoundedLine : uint8_t { kLine, kTooLong, kEof };
inline BoundedLine getline_bounded(std::istream& in, std::string& line, std::size_t max_bytes) {
  line.clear();
  std::streambuf* sb = in.rdbuf();
  if (sb == nullptr || !in.good()) return BoundedLine::kEof;
  bool any = false, too_long = false;
  for (;;) {
    const int c = sb->sbumpc();
    if (c == std::char_traits<char>::eof()) {
      in.setstate(std::ios::eofbit);
      if (!any) return BoundedLine::kEof;
      break;
    }
    any = true;
    if (c == '\n') break;
    if (too_long) continue;
    if (line.size() >= max_bytes) {
      too_long = true;
      line.clear();
      line.shrink_to_fit();
      continue;
    }
    line.push_back(static_cast<char>(c));
  }
  return too_long ? BoundedLine::kTooLong : BoundedLine::kLine;
}

}  // namespace skinbus
