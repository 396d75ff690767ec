// skinbus/common/result.h: errors as return values across library boundaries.
//
// Every fallible public function of a skinbus library returns either a `Status` (nothing to
// give back) or a `Result<T>` (a value or an error). Exceptions are thrown only at tool edges
// (the mains in tools/). An `Error` carries a machine-readable `ErrorCode` and a message meant
// for a person: it names the setting, file, line or value that was wrong. Building an error
// allocates (the message); success never does, so hot paths that must not allocate use their
// own small enums instead (see skinbus/bus/codec.h).
#pragma once

#include <cassert>
#include <string>
#include <utility>
#include <variant>

namespace skinbus {

enum class ErrorCode {
  kInvalidArgument,  // the caller passed a value outside the contract
  kOutOfRange,       // a value is well formed but outside what the protocol or device allows
  kParse,            // text or bytes could not be parsed
  kIo,               // an operating-system call failed (errno in the message)
  kNotFound,         // a device, interface or file does not exist
  kUnsupported,      // the request is valid but this build or kernel cannot serve it
  kUnavailable,      // try again later (would block, queue full)
  kDegenerate,       // the input is valid but carries too little information to answer
  kNotConverged,     // an iterative solve ended without an answer it can vouch for
  kInternal,         // a broken invariant: a bug
};

// Returns a stable lower-case name for `code`, e.g. "invalid_argument".
constexpr const char* error_code_name(ErrorCode code) {
  switch (code) {
    case ErrorCode::kInvalidArgument:
      return "invalid_argument";
    case ErrorCode::kOutOfRange:
      return "out_of_range";
    case ErrorCode::kParse:
      return "parse";
    case ErrorCode::kIo:
      return "io";
    case ErrorCode::kNotFound:
      return "not_found";
    case ErrorCode::kUnsupported:
      return "unsupported";
    case ErrorCode::kUnavailable:
      return "unavailable";
    case ErrorCode::kDegenerate:
      return "degenerate";
    case ErrorCode::kNotConverged:
      return "not_converged";
    case ErrorCode::kInternal:
      return "internal";
  }
  return "unknown";
}

struct Error {
  ErrorCode code = ErrorCode::kInternal;
  std::string message;

  // "code: message", for logs and tool output.
  std::string to_string() const { return std::string(error_code_name(code)) + ": " + message; }
};

inline Error make_error(ErrorCode code, std::string message) {
  return Error{code, std::move(message)};
}

// A value of type T or an Error. Check `ok()` before `value()`.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::in_place_index<0>, std::move(value)) {}  // NOLINT: implicit by design
  Result(Error error) : v_(std::in_place_index<1>, std::move(error)) {}  // NOLINT

  bool ok() const { return v_.index() == 0; }
  explicit operator bool() const { return ok(); }

  T& value() & {
    assert(ok());
    return std::get<0>(v_);
  }
  const T& value() const& {
    assert(ok());
    return std::get<0>(v_);
  }
  T&& value() && {
    assert(ok());
    return std::get<0>(std::move(v_));
  }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

  const Error& error() const {
    assert(!ok());
    return std::get<1>(v_);
  }

 private:
  std::variant<T, Error> v_;
};

// Success or an Error.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error error) : error_(std::move(error)), ok_(false) {}  // NOLINT: implicit by design

  static Status Ok() { return Status(); }
  bool ok() const { return ok_; }
  explicit operator bool() const { return ok_; }
  const Error& error() const {
    assert(!ok_);
    return error_;
  }

 private:
  Error error_;
  bool ok_ = true;
};

}  // namespace skinbus
