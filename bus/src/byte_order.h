// Little-endian loads and stores on byte buffers. Internal to bus/.
#pragma once

#include <cstdint>

namespace skinbus::bus::internal {

inline void put_u8(uint8_t* p, uint8_t v) {
  p[0] = v;
}
inline void put_u16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
}
inline void put_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
inline void put_u64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
inline void put_i16(uint8_t* p, int16_t v) {
  put_u16(p, static_cast<uint16_t>(v));
}

inline uint8_t get_u8(const uint8_t* p) {
  return p[0];
}
inline uint16_t get_u16(const uint8_t* p) {
  return static_cast<uint16_t>(p[0] | p[1] << 8);
}
inline uint32_t get_u32(const uint8_t* p) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = v << 8 | p[i];
  return v;
}
inline uint64_t get_u64(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = v << 8 | p[i];
  return v;
}
inline int16_t get_i16(const uint8_t* p) {
  return static_cast<int16_t>(get_u16(p));
}

}  // namespace skinbus::bus::internal
