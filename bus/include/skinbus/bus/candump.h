// skinbus/bus/candump.h: the can-utils log format (`candump -L`, `candump -l` files,
// `canplayer` input) and cansend's frame syntax, read and written.
//
//   (1699999999.123456) can0 183#0100AABB...      classic, 11-bit identifier
//   (1699999999.123456) can0 1F334455#0102         classic, 29-bit identifier
//   (1699999999.123456) can0 183##1<hex data>      CAN FD; the digit after ## holds the flags
//                                                  (1 = bit-rate switch, 2 = error state)
//   (1699999999.123456) can0 123#R                 remote frame (also #R<len>)
//   (1699999999.123456) can0 20000004#0004...      error frame (CAN_ERR_FLAG in the identifier)
//
// Parsing never allocates: a record's interface name points into the line passed in. A
// trailing direction marker (" R" / " T", from `candump -x`) is accepted and ignored.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <span>
#include <string>
#include <string_view>

#include "skinbus/bus/can_frame.h"
#include "skinbus/common/line_reader.h"

namespace skinbus::bus {

inline constexpr uint32_t kCanErrFlag = 0x20000000;  // as in <linux/can.h>

struct CandumpRecord {
  bool has_timestamp = false;
  uint64_t timestamp_us = 0;  // wall-clock microseconds from the (sec.usec) field
  std::string_view iface;     // interface name as written (points into the parsed line)
  CanFrame frame;
};

enum class CandumpError : uint8_t {
  kNone = 0,
  kEmpty,         // blank line or a comment (#...): skip, not an error
  kBadTimestamp,  // "(sec.usec)" malformed
  kMissingIface,  // no interface field
  kBadId,         // identifier not 3 or 8 hex digits, or out of range
  kMissingHash,   // no '#' after the identifier
  kBadData,       // odd number of hex digits, non-hex character, or too many bytes
  kBadFlags,      // CAN FD flags digit missing or not hex
  kUnsupported,   // valid can-utils syntax this protocol does not carry (CAN XL)
  kLineTooLong,   // longer than kCandumpMaxLineBytes (skipped to its end, nothing kept)
};
std::string_view candump_error_name(CandumpError e);

// Parses one line of `candump -L` output (timestamp and interface required).
CandumpError parse_candump_line(std::string_view line, CandumpRecord* record);

// Parses cansend's frame syntax alone ("123#DEADBEEF", "5A1##1...", dots allowed between bytes).
CandumpError parse_frame_text(std::string_view text, CanFrame* frame);

// Writes `frame` in `candump -L` form without a newline into `out` (256 bytes always suffice).
// Returns the number of characters written (0 if `out` is too small).
inline constexpr std::size_t kCandumpLineMax = 256;
std::size_t format_candump_line(const CanFrame& frame, uint64_t timestamp_us,
                                std::string_view iface, std::span<char> out);
std::string format_candump_line(const CanFrame& frame, uint64_t timestamp_us,
                                std::string_view iface);

// Writes the cansend syntax of `frame` ("183##1AABB..."); returns characters written.
std::size_t format_frame_text(const CanFrame& frame, std::span<char> out);

// The longest line a log reader takes: a valid line is under 200 characters (a CAN FD frame's
// 64 bytes are 128 hex digits). Longer lines are skipped, counted and reported, so no input can
// make a reader hold more than this (plus a fixed 64 KiB buffer).
inline constexpr std::size_t kCandumpMaxLineBytes = 1024;

// Reads a candump log from a stream line by line, counting what it could not parse. Owns one
// fixed buffer (kCandumpMaxLineBytes + 64 KiB); no other allocation.
class CandumpReader {
 public:
  // wait_ms < 0: next() blocks until a line or the end of the input. wait_ms >= 0: next() waits
  // at most that long on a quiet pipe or terminal and answers kWait, as it does when a signal
  // interrupts the read (so a caller can look at its stop flag); no data is lost.
  explicit CandumpReader(std::FILE* stream, int wait_ms = -1)
      : lines_(stream, kCandumpMaxLineBytes, wait_ms), wait_(wait_ms >= 0) {}
  CandumpReader(const CandumpReader&) = delete;
  CandumpReader& operator=(const CandumpReader&) = delete;

  enum class Status { kRecord, kBadLine, kEof, kWait };
  // Reads the next line. kRecord: `record` is valid until the next call. kBadLine: error() and
  // line_number() say what and where; keep calling. Blank and comment lines are skipped. kEof
  // also ends a read that failed: read_error() then holds its errno (EISDIR for a directory).
  Status next(CandumpRecord* record);

  CandumpError error() const { return error_; }
  uint64_t line_number() const { return lines_.line_number(); }
  uint64_t records() const { return records_; }
  uint64_t bad_lines() const { return bad_lines_; }
  int read_error() const { return read_error_; }
  std::string_view line() const { return line_; }

 private:
  LineReader lines_;
  bool wait_;
  std::string_view line_;
  uint64_t records_ = 0;
  uint64_t bad_lines_ = 0;
  int read_error_ = 0;
  CandumpError error_ = CandumpError::kNone;
};

}  // namespace skinbus::bus
