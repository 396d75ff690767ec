// Turns fuzzer bytes into CAN frames: per frame, 2 bytes of identifier and flags, 1 length
// byte, then the data bytes. Shared by the fuzz targets.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

#include "skinbus/bus/can_frame.h"

namespace skinbus::bus::fuzz {

// Reads one frame from data[*pos...]; false when the input is used up.
inline bool next_frame(const uint8_t* data, std::size_t size, std::size_t* pos, CanFrame* f) {
  if (*pos + 3 > size) return false;
  const uint16_t head = static_cast<uint16_t>(data[*pos] | data[*pos + 1] << 8);
  *f = CanFrame{};
  f->id = head & 0x7FF;
  f->fd = head & 0x800;
  f->brs = head & 0x1000;
  const unsigned kind = head >> 13;  // rarely: frames of other kinds, as a bus can carry them
  f->extended = kind == 7;
  f->rtr = kind == 6 && !f->fd;
  f->error = kind == 5;
  // Lengths as a receiver may see them: any 0..64 (invalid FD lengths included; a classic
  // frame longer than 8 must be rejected, not read).
  const std::size_t len = data[*pos + 2] % 65;
  *pos += 3;
  const std::size_t n = len < size - *pos ? len : size - *pos;
  std::memcpy(f->data.data(), data + *pos, n);
  f->len = static_cast<uint8_t>(len);
  *pos += n;
  return true;
}

}  // namespace skinbus::bus::fuzz
