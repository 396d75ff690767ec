// skinbus/record/cdr.h: OMG CDR (XCDR1, little endian), the encoding ROS 2 puts on the wire and
// rosbag2 stores: a 4-byte encapsulation header (00 01 00 00: CDR_LE), then each field in
// declaration order, every primitive aligned to its own size (at most 8) from the byte after
// the header. A string is a uint32 length counting its terminating NUL, the bytes and the NUL; a
// sequence (T[]) a uint32 count and its elements; a fixed array (T[N]) its N elements. ROS
// message constants are not serialized.
//
// CdrWriter appends to a caller-owned buffer (allocation: the buffer's growth only). CdrReader
// reads a borrowed span and never reads past it: the first short read, bad header or string
// without its NUL sets an error (kept, named by the field being read) and every later read
// returns zero values, so a decoder reads on and checks ok() once at the end.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::record {

class CdrWriter {
 public:
  // Clears `out` and writes the encapsulation header. `out` is borrowed; it must outlive the
  // writer.
  explicit CdrWriter(std::vector<uint8_t>* out);

  void u8(uint8_t v) { put(&v, 1, 1); }
  void boolean(bool v) { u8(v ? 1 : 0); }
  void u16(uint16_t v) { put(&v, 2, 2); }
  void u32(uint32_t v) { put(&v, 4, 4); }
  void i32(int32_t v) { put(&v, 4, 4); }
  void u64(uint64_t v) { put(&v, 8, 8); }
  void f32(float v) { put(&v, 4, 4); }
  void f64(double v) { put(&v, 8, 8); }
  void string(std::string_view s);
  // A sequence's count; its elements follow, written by the caller.
  void count(std::size_t n) { u32(static_cast<uint32_t>(n)); }
  // uint8[] data (count and bytes).
  void bytes(std::span<const uint8_t> data);

 private:
  void put(const void* v, std::size_t size, std::size_t align);
  std::vector<uint8_t>* out_;
};

class CdrReader {
 public:
  // Reads `data` (borrowed); checks the encapsulation header (CDR_LE: big-endian data is
  // refused, kParse). `what` names the message in errors.
  CdrReader(std::span<const uint8_t> data, std::string what);

  uint8_t u8(const char* field) { return get<uint8_t>(field); }
  bool boolean(const char* field) { return u8(field) != 0; }
  uint16_t u16(const char* field) { return get<uint16_t>(field); }
  uint32_t u32(const char* field) { return get<uint32_t>(field); }
  int32_t i32(const char* field) { return get<int32_t>(field); }
  uint64_t u64(const char* field) { return get<uint64_t>(field); }
  float f32(const char* field) { return get<float>(field); }
  double f64(const char* field) { return get<double>(field); }
  std::string string(const char* field);
  // A sequence's count, refused (kParse) when even `min_element_bytes` a element would not fit
  // in what is left (so a hostile count cannot make the caller allocate).
  uint32_t count(const char* field, std::size_t min_element_bytes);
  std::vector<uint8_t> bytes(const char* field);

  bool ok() const { return error_.empty(); }
  // Ok, or kParse naming the message, the field and the byte offset of the first failure.
  Status status() const;
  std::size_t remaining() const { return data_.size() - pos_; }

 private:
  bool take(std::size_t size, std::size_t align, const char* field);
  void fail(const char* field, std::string_view why);
  template <typename T>
  T get(const char* field) {
    T v{};
    if (take(sizeof(T), sizeof(T), field))
      std::memcpy(&v, data_.data() + pos_ - sizeof(T), sizeof(T));
    return v;
  }

  std::span<const uint8_t> data_;
  std::size_t pos_ = 0;
  std::string what_;
  std::string error_;
};

}  // namespace skinbus::record
