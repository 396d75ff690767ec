// skinbus/bus/can_frame.h: one CAN or CAN FD frame, independent of the kernel headers.
//
// The protocol code (codec, reassembler, candump) works on this plain struct so it builds and
// is tested on machines without SocketCAN; skinbus/bus/socketcan.h converts to and from the
// kernel's `struct can_frame` / `struct canfd_frame`.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

namespace skinbus::bus {

inline constexpr std::size_t kClassicMaxLen = 8;
inline constexpr std::size_t kFdMaxLen = 64;
inline constexpr uint32_t kStandardIdMask = 0x7FF;
inline constexpr uint32_t kExtendedIdMask = 0x1FFFFFFF;

struct CanFrame {
  uint32_t id = 0;        // 11-bit (standard) or 29-bit (extended) identifier, no flag bits
  bool extended = false;  // 29-bit identifier
  bool fd = false;        // CAN FD frame (FDF); len may then be any valid FD length
  bool brs = false;       // FD bit-rate switch
  bool esi = false;       // FD error-state indicator (transmitter is error passive)
  bool rtr = false;       // classic remote-transmission request (no data)
  bool error = false;     // SocketCAN error frame: `id` holds the CAN_ERR_* class bits
  uint8_t len = 0;        // data length in bytes: 0..8 classic, a valid FD length for FD
  std::array<uint8_t, kFdMaxLen> data{};

  bool operator==(const CanFrame& o) const;
};

// True if `len` is a length a CAN FD frame can carry (0..8, 12, 16, 20, 24, 32, 48, 64).
constexpr bool is_valid_fd_len(std::size_t len) {
  return len <= 8 || len == 12 || len == 16 || len == 20 || len == 24 || len == 32 || len == 48 ||
         len == 64;
}

// Smallest valid CAN FD length >= len (len <= 64).
constexpr uint8_t round_up_fd_len(std::size_t len) {
  constexpr uint8_t kLens[] = {12, 16, 20, 24, 32, 48, 64};
  if (len <= 8) return static_cast<uint8_t>(len);
  for (uint8_t l : kLens) {
    if (len <= l) return l;
  }
  return 64;
}

// The 4-bit DLC code that carries `len` bytes (len must be a valid FD length).
constexpr uint8_t fd_len_to_dlc(std::size_t len) {
  constexpr uint8_t kLens[] = {12, 16, 20, 24, 32, 48, 64};
  if (len <= 8) return static_cast<uint8_t>(len);
  for (uint8_t i = 0; i < 7; ++i) {
    if (len <= kLens[i]) return static_cast<uint8_t>(9 + i);
  }
  return 15;
}

}  // namespace skinbus::bus
