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
  f->extended = (head & 0xE000) == 0xE000;  // rarely: a foreign frame
  std::size_t len = data[*pos + 2] % 65;
  if (!f->fd) len %= 9;
  if (f->fd && !is_valid_fd_len(len)) len = round_up_fd_len(len);
  *pos += 3;
  const std::size_t n = len < size - *pos ? len : size - *pos;
  std::memcpy(f->data.data(), data + *pos, n);
  f->len = static_cast<uint8_t>(len);
  *pos += n;
  return true;
}

}  // namespace skinbus::bus::fuzz
