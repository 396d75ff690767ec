// skinbus/common/atomic_file.h: writing output files so that a reader finds either the old file
// or the whole new one, never a torn or empty one. The data goes to a temporary file beside the
// target (`<path>.tmp.<pid>.<n>`), every write is checked (a full disk is an error naming the
// file, not a silent short file), the file is synced, renamed over the target, and the folder
// synced. Until commit() nothing at `path` changes; a writer destroyed without commit() removes
// its temporary file. Header-only, POSIX and the standard library only.
//
//   AtomicFile f;
//   if (Status s = f.open(path, "dataset"); !s.ok()) return s;
//   f.write(text);  ...  return f.commit();
//
// A target that exists and is not a regular file (/dev/null, a FIFO) is written in place, with
// the same checks.
//
// Several files that must change together (a model's weights and metadata) are each written
// and synced, then renamed one after the other with rename_into_place(): a reader still needs a
// way to tell a mixed pair (the model format's weight fingerprint).
#pragma once

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>

#include "skinbus/common/result.h"

namespace skinbus {

class AtomicFile {
 public:
  AtomicFile() = default;
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  ~AtomicFile() { abandon(); }

  // Creates the temporary file for `path`; `what` names the file in errors.
  Status open(const std::string& path, const std::string& what) {
    abandon();
    error_.clear();
    in_place_ = false;
    path_ = path;
    what_ = what;
    struct stat st {};
    if (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode)) {
      fd_ = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
      if (fd_ < 0) return fail("cannot write " + what_ + " " + path_, errno);
      in_place_ = true;
      return Status::Ok();
    }
    static std::atomic<unsigned> counter{0};
    temp_ = path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(counter++);
    fd_ = ::open(temp_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd_ < 0) {
      const int e = errno;
      temp_.clear();
      return fail("cannot create " + what_ + " " + path_, e);
    }
    return Status::Ok();
  }

  // Appends `data`; an error (a full disk, a failed device) is kept and returned by commit()
  // too, so a caller may check only there.
  Status write(std::string_view data) {
    if (!error_.empty()) return make_error(ErrorCode::kIo, error_);
    if (fd_ < 0) return make_error(ErrorCode::kInternal, what_ + " " + path_ + ": not open");
    while (!data.empty()) {
      const ssize_t n = ::write(fd_, data.data(), data.size());
      if (n < 0) {
        if (errno == EINTR) continue;
        return fail("write to " + what_ + " " + path_ + " failed", errno);
      }
      data.remove_prefix(static_cast<std::size_t>(n));
    }
    return Status::Ok();
  }

  // Syncs and closes the temporary file; the target is not touched yet.
  Status finish() {
    if (!error_.empty()) return make_error(ErrorCode::kIo, error_);
    if (fd_ < 0) {
      return temp_.empty() && !in_place_ ? make_error(ErrorCode::kInternal, "not open")
                                         : Status::Ok();
    }
    if (!in_place_ && ::fsync(fd_) != 0)
      return fail("sync of " + what_ + " " + path_ + " failed", errno);
    const int fd = fd_;
    fd_ = -1;
    if (::close(fd) != 0) return fail("write to " + what_ + " " + path_ + " failed", errno);
    return Status::Ok();
  }

  // Renames the finished temporary file over the target and syncs the folder.
  Status rename_into_place() {
    if (Status s = finish(); !s.ok()) return s;
    if (in_place_) return Status::Ok();
    if (::rename(temp_.c_str(), path_.c_str()) != 0) {
      return fail("cannot rename the new " + what_ + " to " + path_, errno);
    }
    temp_.clear();
    sync_folder(path_);
    return Status::Ok();
  }

  // finish() and rename_into_place(): the whole file appears at `path` at once.
  Status commit() { return rename_into_place(); }

  // Removes the temporary file (nothing at `path` changes).
  void abandon() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    if (!temp_.empty()) ::unlink(temp_.c_str());
    temp_.clear();
  }

  const std::string& path() const { return path_; }

 private:
  Status fail(const std::string& what, int e) {
    error_ = what + ": " + std::strerror(e);
    abandon();
    return make_error(e == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIo, error_);
  }
  static void sync_folder(const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    const std::string dir = slash == std::string::npos ? "."
                            : slash == 0               ? "/"
                                                       : path.substr(0, slash);
    const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd >= 0) {
      ::fsync(fd);  // best effort: some file systems refuse to sync a folder
      ::close(fd);
    }
  }

  std::string path_, what_, temp_, error_;
  int fd_ = -1;
  bool in_place_ = false;
};

// The whole of `contents` into `path` through an AtomicFile.
inline Status write_file_atomic(const std::string& path, std::string_view contents,
                                const std::string& what) {
  AtomicFile f;
  if (Status s = f.open(path, what); !s.ok()) return s;
  if (Status s = f.write(contents); !s.ok()) return s;
  return f.commit();
}

// FNV-1a, 64 bit, of `bytes`: a fingerprint that ties files together (not a cryptographic hash).
inline uint64_t fnv1a64(std::string_view bytes, uint64_t h = 14695981039346656037ull) {
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

}  // namespace skinbus
