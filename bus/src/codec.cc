#include "skinbus/bus/codec.h"

#include <algorithm>
#include <array>
#include <cstring>

#include "byte_order.h"

namespace skinbus::bus {

using namespace internal;  // NOLINT: byte-order helpers

std::string_view decode_error_name(DecodeError e) {
  switch (e) {
    case DecodeError::kNone:
      return "none";
    case DecodeError::kForeign:
      return "foreign";
    case DecodeError::kUnknownClass:
      return "unknown_class";
    case DecodeError::kBadNode:
      return "bad_node";
    case DecodeError::kBadVersion:
      return "bad_version";
    case DecodeError::kBadPart:
      return "bad_part";
    case DecodeError::kBadLength:
      return "bad_length";
    case DecodeError::kBadCrc:
      return "bad_crc";
    case DecodeError::kBadValue:
      return "bad_value";
  }
  return "unknown";
}

namespace {

constexpr std::array<uint16_t, 256> make_crc_table() {
  std::array<uint16_t, 256> t{};
  for (int i = 0; i < 256; ++i) {
    uint16_t crc = static_cast<uint16_t>(i << 8);
    for (int b = 0; b < 8; ++b)
      crc = static_cast<uint16_t>((crc & 0x8000) ? (crc << 1) ^ 0x1021 : crc << 1);
    t[i] = crc;
  }
  return t;
}
constexpr std::array<uint16_t, 256> kCrcTable = make_crc_table();

}  // namespace

uint16_t crc16_ccitt(std::span<const uint8_t> bytes) {
  // Byte-wise table form (512 bytes of table, built at compile time); checked against the
  // catalogue value 0x29B1 in codec_test.cc.
  uint16_t crc = 0xFFFF;
  for (uint8_t b : bytes) crc = static_cast<uint16_t>(crc << 8 ^ kCrcTable[(crc >> 8 ^ b) & 0xFF]);
  return crc;
}

MessageBody default_body(MessageClass c) {
  switch (c) {
    case MessageClass::kSync:
      return Sync{};
    case MessageClass::kCommand:
      return Command{};
    case MessageClass::kAck:
      return Ack{};
    case MessageClass::kSample:
      return Sample{};
    case MessageClass::kInfo:
      return Info{};
    case MessageClass::kHeartbeat:
      return Heartbeat{};
  }
  return Sample{};
}

bool node_allowed(MessageClass c, uint8_t node) {
  switch (c) {
    case MessageClass::kSync:
      return node == kNodeBroadcast;
    case MessageClass::kCommand:
      return is_patch_node(node) || node == kNodeBroadcast;
    case MessageClass::kAck:
    case MessageClass::kSample:
    case MessageClass::kInfo:
    case MessageClass::kHeartbeat:
      return is_patch_node(node) || node == kNodeUnassigned;
  }
  return false;
}

namespace {

void put_crc(uint8_t* payload, std::size_t len_with_crc) {
  const std::size_t n = len_with_crc - kCrcLen;
  put_u16(payload + n, crc16_ccitt({payload, n}));
}

bool crc_ok(std::span<const uint8_t> payload) {
  const std::size_t n = payload.size() - kCrcLen;
  return get_u16(payload.data() + n) == crc16_ccitt(payload.first(n));
}

struct Serializer {
  uint8_t* p;
  std::size_t operator()(const Sync& m) const {
    put_u32(p + 0, m.host_time_us);
    put_u16(p + 4, m.counter);
    return kSyncPayloadLen;
  }
  std::size_t operator()(const Command& m) const {
    put_u8(p + 0, static_cast<uint8_t>(m.opcode));
    std::memcpy(p + 1, m.arg.data(), m.arg.size());
    return kCommandPayloadLen;
  }
  std::size_t operator()(const Ack& m) const {
    put_u8(p + 0, m.opcode);
    put_u8(p + 1, static_cast<uint8_t>(m.status));
    put_u8(p + 2, m.command_seq);
    put_u8(p + 3, m.broadcast ? 1 : 0);
    put_u16(p + 4, m.value);
    return kAckPayloadLen;
  }
  std::size_t operator()(const Sample& m) const {
    put_u32(p + 0, m.timestamp_us);
    put_u16(p + 4, m.flags);
    put_u16(p + 6, m.fault_mask);
    put_u16(p + 8, m.saturation_mask);
    for (int ch = 0; ch < kChannelCount; ++ch) put_i16(p + 10 + 2 * ch, m.field_lsb[ch]);
    put_crc(p, kSamplePayloadLen);
    return kSamplePayloadLen;
  }
  std::size_t operator()(const Info& m) const {
    put_u64(p + 0, m.hardware_uid);
    put_u8(p + 8, m.fw_major);
    put_u8(p + 9, m.fw_minor);
    put_u8(p + 10, m.fw_patch);
    put_u8(p + 11, m.protocol_version);
    put_u8(p + 12, m.sensor_count);
    put_u8(p + 13, m.axis_count);
    put_u8(p + 14, m.gain_sel);
    put_u8(p + 15, m.resolution);
    put_u8(p + 16, m.oversampling);
    put_u8(p + 17, m.digital_filter);
    put_u16(p + 18, m.rate_chz);
    put_u16(p + 20, m.max_rate_chz);
    put_u16(p + 22, m.conversion_time_us);
    put_u16(p + 24, m.field_lsb_nt);
    put_crc(p, kInfoPayloadLen);
    return kInfoPayloadLen;
  }
  std::size_t operator()(const Heartbeat& m) const {
    put_u8(p + 0, static_cast<uint8_t>(m.state));
    put_u8(p + 1, static_cast<uint8_t>(m.mode));
    put_u16(p + 2, m.rate_chz);
    put_u32(p + 4, m.uptime_s);
    put_u64(p + 8, m.hardware_uid);
    put_u8(p + 16, m.fw_major);
    put_u8(p + 17, m.fw_minor);
    put_u8(p + 18, m.fw_patch);
    put_u8(p + 19, m.status);
    put_u16(p + 20, m.fault_mask);
    put_u16(p + 22, m.i2c_errors);
    put_u16(p + 24, m.can_errors);
    put_u16(p + 26, m.saturation_count);
    put_i16(p + 28, m.temperature_cdeg);
    put_crc(p, kHeartbeatPayloadLen);
    return kHeartbeatPayloadLen;
  }
};

}  // namespace

std::size_t serialize_payload(const MessageBody& body, std::span<uint8_t> out) {
  const auto c = static_cast<MessageClass>(body.index());
  if (out.size() < payload_len(c)) return 0;
  return std::visit(Serializer{out.data()}, body);
}

DecodeError deserialize_payload(MessageClass c, std::span<const uint8_t> payload,
                                MessageBody* body) {
  if (payload.size() < payload_len(c)) return DecodeError::kBadLength;
  payload = payload.first(payload_len(c));
  if (is_multi_part(c) && !crc_ok(payload)) return DecodeError::kBadCrc;
  const uint8_t* p = payload.data();
  switch (c) {
    case MessageClass::kSync: {
      Sync m;
      m.host_time_us = get_u32(p + 0);
      m.counter = get_u16(p + 4);
      *body = m;
      return DecodeError::kNone;
    }
    case MessageClass::kCommand: {
      Command m;
      m.opcode = static_cast<Opcode>(get_u8(p + 0));  // unknown opcodes pass: the patch NACKs them
      std::memcpy(m.arg.data(), p + 1, m.arg.size());
      *body = m;
      return DecodeError::kNone;
    }
    case MessageClass::kAck: {
      Ack m;
      m.opcode = get_u8(p + 0);
      if (get_u8(p + 1) >= kAckStatusCount) return DecodeError::kBadValue;
      m.status = static_cast<AckStatus>(get_u8(p + 1));
      m.command_seq = get_u8(p + 2);
      if (get_u8(p + 3) > 1) return DecodeError::kBadValue;  // only bit 0 is defined
      m.broadcast = get_u8(p + 3) & 1;
      m.value = get_u16(p + 4);
      *body = m;
      return DecodeError::kNone;
    }
    case MessageClass::kSample: {
      Sample m;
      m.timestamp_us = get_u32(p + 0);
      m.flags = get_u16(p + 4);
      m.fault_mask = get_u16(p + 6);
      m.saturation_mask = get_u16(p + 8);
      for (int ch = 0; ch < kChannelCount; ++ch) m.field_lsb[ch] = get_i16(p + 10 + 2 * ch);
      *body = m;
      return DecodeError::kNone;
    }
    case MessageClass::kInfo: {
      Info m;
      m.hardware_uid = get_u64(p + 0);
      m.fw_major = p[8];
      m.fw_minor = p[9];
      m.fw_patch = p[10];
      m.protocol_version = p[11];
      m.sensor_count = p[12];
      m.axis_count = p[13];
      m.gain_sel = p[14];
      m.resolution = p[15];
      m.oversampling = p[16];
      m.digital_filter = p[17];
      m.rate_chz = get_u16(p + 18);
      m.max_rate_chz = get_u16(p + 20);
      m.conversion_time_us = get_u16(p + 22);
      m.field_lsb_nt = get_u16(p + 24);
      *body = m;
      return DecodeError::kNone;
    }
    case MessageClass::kHeartbeat: {
      Heartbeat m;
      if (p[0] >= kPatchStateCount || p[1] >= kPatchModeCount) return DecodeError::kBadValue;
      m.state = static_cast<PatchState>(p[0]);
      m.mode = static_cast<PatchMode>(p[1]);
      m.rate_chz = get_u16(p + 2);
      m.uptime_s = get_u32(p + 4);
      m.hardware_uid = get_u64(p + 8);
      m.fw_major = p[16];
      m.fw_minor = p[17];
      m.fw_patch = p[18];
      m.status = p[19];
      m.fault_mask = get_u16(p + 20);
      m.i2c_errors = get_u16(p + 22);
      m.can_errors = get_u16(p + 24);
      m.saturation_count = get_u16(p + 26);
      m.temperature_cdeg = get_i16(p + 28);
      *body = m;
      return DecodeError::kNone;
    }
  }
  return DecodeError::kUnknownClass;
}

EncodeResult encode(const Message& msg, std::span<CanFrame> out) {
  const MessageClass c = msg.message_class();
  if (!node_allowed(c, msg.node)) return {0, EncodeError::kBadNode};
  const std::size_t parts = part_count(c, msg.kind);
  if (out.size() < parts) return {0, EncodeError::kBufferTooSmall};

  uint8_t payload[kMaxPayloadLen];
  const std::size_t len = serialize_payload(msg.body, payload);
  const std::size_t plen = is_multi_part(c) ? part_len(msg.kind) : len;
  const uint32_t id = make_can_id(c, msg.node);
  for (std::size_t i = 0; i < parts; ++i) {
    CanFrame& f = out[i];
    const std::size_t off = i * plen;
    const std::size_t n = std::min(plen, len - off);
    f = CanFrame{};
    f.id = id;
    f.fd = msg.kind == FrameKind::kFd;
    f.brs = f.fd;
    f.data[0] = header_byte0(kProtocolVersion, static_cast<uint8_t>(i));
    f.data[1] = msg.seq;
    std::memcpy(f.data.data() + kHeaderLen, payload + off, n);
    const std::size_t used = kHeaderLen + n;
    f.len =
        static_cast<uint8_t>(f.fd ? round_up_fd_len(used) : used);  // data[] is zeroed: padding 0
  }
  return {parts, EncodeError::kNone};
}

DecodeError parse_frame(const CanFrame& frame, FrameView* view) {
  if (frame.extended || frame.rtr || frame.error || frame.id > kStandardIdMask)
    return DecodeError::kForeign;
  if (!frame.fd && frame.len > kClassicMaxLen) return DecodeError::kBadLength;
  if (frame.len > kFdMaxLen) return DecodeError::kBadLength;
  const uint8_t cls = can_id_class(frame.id);
  if (!is_known_class(cls)) return DecodeError::kUnknownClass;
  const auto c = static_cast<MessageClass>(cls);
  const uint8_t node = can_id_node(frame.id);
  if (!node_allowed(c, node)) return DecodeError::kBadNode;
  if (frame.len < kHeaderLen) return DecodeError::kBadLength;
  const uint8_t version = frame.data[0] >> 5;
  if (version != kProtocolVersion) return DecodeError::kBadVersion;

  const FrameKind kind = frame.fd ? FrameKind::kFd : FrameKind::kClassic;
  const uint8_t part = frame.data[0] & 0x1F;
  const std::size_t parts = part_count(c, kind);
  if (part >= parts) return DecodeError::kBadPart;
  const std::size_t len = payload_len(c);
  const std::size_t plen = is_multi_part(c) ? part_len(kind) : len;
  const std::size_t off = part * plen;
  const std::size_t n = std::min(plen, len - off);
  if (frame.len < kHeaderLen + n) return DecodeError::kBadLength;

  view->message_class = c;
  view->node = node;
  view->header = FrameHeader{version, part, frame.data[1]};
  view->kind = kind;
  view->part_count = static_cast<uint8_t>(parts);
  view->payload_offset = static_cast<uint16_t>(off);
  view->part_len = static_cast<uint8_t>(n);
  view->part_data = frame.data.data() + kHeaderLen;
  return DecodeError::kNone;
}

DecodeError decode_single(const CanFrame& frame, Message* msg) {
  FrameView v;
  if (DecodeError e = parse_frame(frame, &v); e != DecodeError::kNone) return e;
  if (v.part_count != 1) return DecodeError::kBadPart;
  msg->node = v.node;
  msg->seq = v.header.seq;
  msg->kind = v.kind;
  return deserialize_payload(v.message_class, {v.part_data, v.part_len}, &msg->body);
}

}  // namespace skinbus::bus
