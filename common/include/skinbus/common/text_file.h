// skinbus/common/text_file.h: opening and reading input files with errors that name them, and
// with bounds: a directory is refused (it would read as empty), and a file larger than the
// caller's limit is refused before it is read. Header-only, POSIX and the standard library only
// (the model files' reader uses it where yaml-cpp is not built, as in the Arm cross build).
#pragma once

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <string>

#include "skinbus/common/result.h"

namespace skinbus {

// The largest text file read whole unless the caller says otherwise (a skin map, a settings or
// unit file, a model's metadata): far above any real one.
inline constexpr uint64_t kMaxTextFileBytes = 64ull << 20;

// A file descriptor closed when it goes out of scope.
class UniqueFd {
 public:
  UniqueFd() = default;
  explicit UniqueFd(int fd) : fd_(fd) {}
  UniqueFd(UniqueFd&& o) noexcept : fd_(o.release()) {}
  UniqueFd& operator=(UniqueFd&& o) noexcept {
    if (this != &o) {
      reset();
      fd_ = o.release();
    }
    return *this;
  }
  UniqueFd(const UniqueFd&) = delete;
  UniqueFd& operator=(const UniqueFd&) = delete;
  ~UniqueFd() { reset(); }
  int get() const { return fd_; }
  int release() {
    const int fd = fd_;
    fd_ = -1;
    return fd;
  }
  void reset() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

 private:
  int fd_ = -1;
};

// Opens `path` for reading; `what` names it in the error ("dataset", "candump log"). A directory
// is an error (kInvalidArgument), not an empty file.
inline Result<UniqueFd> open_input_file(const std::string& path, const std::string& what) {
  UniqueFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) {
    const int e = errno;
    return make_error(e == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIo,
                      what + " " + path + ": " + std::strerror(e));
  }
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) {
    return make_error(ErrorCode::kIo, what + " " + path + ": " + std::strerror(errno));
  }
  if (S_ISDIR(st.st_mode)) {
    return make_error(ErrorCode::kInvalidArgument,
                      what + " " + path + ": is a directory, not a file");
  }
  return fd;
}

// Reads a whole text file; `what` names it in the error ("config file", "skin map"). Refuses a
// directory and a file of more than max_bytes (kOutOfRange).
inline Result<std::string> read_text_file(const std::string& path, const std::string& what,
                                          uint64_t max_bytes = kMaxTextFileBytes) {
  Result<UniqueFd> fd = open_input_file(path, what);
  if (!fd.ok()) return fd.error();
  struct stat st {};
  if (::fstat(fd->get(), &st) == 0 && S_ISREG(st.st_mode) &&
      static_cast<uint64_t>(st.st_size) > max_bytes) {
    return make_error(ErrorCode::kOutOfRange,
                      what + " " + path + ": " + std::to_string(st.st_size) +
                          " bytes, more than the " + std::to_string(max_bytes) + " accepted");
  }
  std::string out;
  char buf[64 * 1024];
  for (;;) {
    const ssize_t n = ::read(fd->get(), buf, sizeof buf);
    if (n < 0) {
      if (errno == EINTR) continue;
      return make_error(ErrorCode::kIo, what + " " + path + ": " + std::strerror(errno));
    }
    if (n == 0) break;
    if (out.size() + static_cast<std::size_t>(n) > max_bytes) {  // a pipe or a growing file
      return make_error(ErrorCode::kOutOfRange, what + " " + path + ": more than the " +
                                                    std::to_string(max_bytes) + " bytes accepted");
    }
    out.append(buf, static_cast<std::size_t>(n));
  }
  return out;
}

}  // namespace skinbus
