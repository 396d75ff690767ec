// skinbus/bus/codec.h: messages <-> frames, without allocation.
//
// Costs: encode and decode are O(payload bytes), touch only the caller's buffers and the
// stack, and never allocate or throw. Multi-part messages are put back together by
// skinbus/bus/reassembler.h; this header handles one frame or one whole payload at a time.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>
#include <variant>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/protocol.h"

namespace skinbus::bus {

// The body of a message; the variant index equals the MessageClass value.
using MessageBody = std::variant<Sync, Command, Ack, Sample, Info, Heartbeat>;

struct Message {
  uint8_t node = kNodeMin;  // sender (patch messages) or addressee (commands, SYNC: broadcast)
  uint8_t seq = 0;          // transfer sequence, per sender and class
  FrameKind kind = FrameKind::kFd;
  MessageBody body;

  MessageClass message_class() const { return static_cast<MessageClass>(body.index()); }
  bool operator==(const Message&) const = default;
};

// Why a frame or payload was not accepted. Cheap to return; names for logs below.
enum class DecodeError : uint8_t {
  kNone = 0,
  kForeign,       // not a skinbus frame: extended ID, remote or error frame
  kUnknownClass,  // identifier class not defined in this protocol version
  kBadNode,       // node field not allowed for this class
  kBadVersion,    // header version differs from kProtocolVersion (mixed versions on the bus)
  kBadPart,       // part index >= the class's part count for this frame kind
  kBadLength,     // frame too short for its part, or a classic frame longer than 8
  kBadCrc,        // reassembled payload failed its CRC
  kBadValue,      // a field holds a value the protocol does not define
};
inline constexpr int kDecodeErrorCount = 9;
std::string_view decode_error_name(DecodeError e);

enum class EncodeError : uint8_t {
  kNone = 0,
  kBadNode,         // node not allowed for this class (see docs/protocol.md, identifiers)
  kBufferTooSmall,  // `out` has fewer frames than part_count(class, kind)
};

struct EncodeResult {
  std::size_t frames = 0;  // frames written to `out`
  EncodeError error = EncodeError::kNone;
};

// A message body of class `c` with every field at its default.
MessageBody default_body(MessageClass c);

// True if `node` may appear in the identifier of a message of class `c`.
bool node_allowed(MessageClass c, uint8_t node);

// Serialises the payload of `body` (CRC included for multi-part classes) into `out`, which must
// hold payload_len(class) bytes. Returns the number of bytes written.
std::size_t serialize_payload(const MessageBody& body, std::span<uint8_t> out);

// Decodes a whole payload of class `c` (CRC checked for multi-part classes) into `body`.
DecodeError deserialize_payload(MessageClass c, std::span<const uint8_t> payload,
                                MessageBody* body);

// Encodes `msg` into part_count(class, msg.kind) frames in `out`. FD frames have BRS set and are
// zero-padded to the next valid FD length; classic frames are not padded.
EncodeResult encode(const Message& msg, std::span<CanFrame> out);

// What one frame says on its own.
struct FrameView {
  MessageClass message_class = MessageClass::kSample;
  uint8_t node = 0;
  FrameHeader header;
  FrameKind kind = FrameKind::kFd;
  uint8_t part_count = 1;
  uint16_t payload_offset = 0;         // where this part's bytes sit in the payload
  uint8_t part_len = 0;                // payload bytes this part carries (padding excluded)
  const uint8_t* part_data = nullptr;  // points into the frame passed to parse_frame
};

// Validates identifier, header, part index and length of one frame. On kNone fills `view`.
DecodeError parse_frame(const CanFrame& frame, FrameView* view);

// Decodes a single-frame message (SYNC, command, ack) directly. Multi-part classes return
// kBadPart unless the frame is their only part.
DecodeError decode_single(const CanFrame& frame, Message* msg);

// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).
uint16_t crc16_ccitt(std::span<const uint8_t> bytes);

}  // namespace skinbus::bus
