#include "skinbus/bus/dbc.h"

#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>

#include "skinbus/bus/codec.h"

namespace skinbus::bus {

namespace {

template <typename... Args>
void appendf(std::string* s, const char* fmt, Args... args) {
  char buf[512];
  const int n = std::snprintf(buf, sizeof buf, fmt, args...);
  s->append(buf, n < 0 ? 0 : static_cast<std::size_t>(n));
}

std::string upper(std::string_view v) {
  std::string s(v);
  for (char& c : s) c = static_cast<char>(c >= 'a' && c <= 'z' ? c - 32 : c);
  return s;
}

void range_of(const FieldDesc& f, double* lo, double* hi, bool* is_signed) {
  const std::size_t bits = 8 * field_size(f.type);
  *is_signed = f.type == FieldType::kI16;
  if (*is_signed) {
    *lo = -std::ldexp(1.0, static_cast<int>(bits) - 1) * f.scale;
    *hi = (std::ldexp(1.0, static_cast<int>(bits) - 1) - 1) * f.scale;
  } else {
    *lo = 0;
    *hi = (std::ldexp(1.0, static_cast<int>(bits)) - 1) * f.scale;
  }
}

}  // namespace

std::string generate_dbc(FrameKind kind, uint8_t first_node, uint8_t last_node) {
  const bool fd = kind == FrameKind::kFd;
  std::string s;
  s += "VERSION \"skinbus protocol v" + std::to_string(kProtocolVersion) +
       (fd ? " CAN FD" : " classic CAN") + "\"\n\n";
  s += "NS_ :\n\tCM_\n\tBA_DEF_\n\tBA_\n\tVAL_\n\tBA_DEF_DEF_\n\nBS_:\n\nBU_: HOST";
  for (int n = first_node; n <= last_node; ++n) appendf(&s, " PATCH_%03d", n);
  s += "\n\n";

  std::string comments;
  std::string attributes;
  auto emit_message = [&](MessageClass c, uint8_t node, const char* sender, const char* receiver) {
    const uint32_t id = make_can_id(c, node);
    const bool multi = is_multi_part(c);
    const std::size_t parts = part_count(c, kind);
    const std::size_t plen = multi ? part_len(kind) : payload_len(c);
    // The message length is that of its longest frame, as the encoder cuts it; a last part may
    // be shorter (see the file's comment).
    std::size_t dlc = 0;
    {
      Message probe;
      probe.node = node == kNodeBroadcast && c != MessageClass::kSync && c != MessageClass::kCommand
                       ? kNodeMin
                       : node;
      probe.kind = kind;
      switch (c) {
        case MessageClass::kSync:
          probe.body = Sync{};
          break;
        case MessageClass::kCommand:
          probe.body = Command{};
          break;
        case MessageClass::kAck:
          probe.body = Ack{};
          break;
        case MessageClass::kSample:
          probe.body = Sample{};
          break;
        case MessageClass::kInfo:
          probe.body = Info{};
          break;
        case MessageClass::kHeartbeat:
          probe.body = Heartbeat{};
          break;
      }
      CanFrame frames[kMaxParts];
      const EncodeResult r = encode(probe, frames);
      for (std::size_t i = 0; i < r.frames; ++i) dlc = std::max<std::size_t>(dlc, frames[i].len);
    }
    char name[48];
    if (node == kNodeBroadcast) {
      std::snprintf(name, sizeof name, "%s_ALL", upper(message_class_name(c)).c_str());
    } else {
      std::snprintf(name, sizeof name, "%s_N%03u", upper(message_class_name(c)).c_str(), node);
    }
    appendf(&s, "BO_ %" PRIu32 " %s: %zu %s\n", id, name, dlc, sender);
    appendf(&s, " SG_ part%s : 0|5@1+ (1,0) [0|31] \"\" %s\n", multi ? " M" : "", receiver);
    appendf(&s, " SG_ version : 5|3@1+ (1,0) [0|7] \"\" %s\n", receiver);
    appendf(&s, " SG_ seq : 8|8@1+ (1,0) [0|255] \"\" %s\n", receiver);
    for (const FieldDesc* f = fields_begin(c); f != fields_end(c); ++f) {
      const std::size_t size = field_size(f->type);
      const std::size_t part = f->offset / plen;
      if ((f->offset + size - 1) / plen != part || part >= parts) {
        appendf(&comments,
                "CM_ BO_ %" PRIu32
                " \"%s: field %s (payload bytes %u..%zu) spans two parts; decode the "
                "reassembled message (skinbus-decode)\";\n",
                id, name, f->name, f->offset, f->offset + size - 1);
        continue;
      }
      const std::size_t start_bit = 8 * (kHeaderLen + f->offset - part * plen);
      double lo, hi;
      bool is_signed;
      range_of(*f, &lo, &hi, &is_signed);
      char mux[8] = "";
      if (multi) std::snprintf(mux, sizeof mux, " m%zu", part);
      appendf(&s, " SG_ %s%s : %zu|%zu@1%c (%g,0) [%g|%g] \"%s\" %s\n", f->name, mux, start_bit,
              8 * size, is_signed ? '-' : '+', f->scale, lo, hi, f->unit, receiver);
    }
    s += "\n";
    if (fd) appendf(&attributes, "BA_ \"VFrameFormat\" BO_ %" PRIu32 " 14;\n", id);
  };

  for (int n = first_node; n <= last_node; ++n) {
    char patch[16];
    std::snprintf(patch, sizeof patch, "PATCH_%03d", n);
    const auto node = static_cast<uint8_t>(n);
    emit_message(MessageClass::kCommand, node, "HOST", patch);
    emit_message(MessageClass::kAck, node, patch, "HOST");
    emit_message(MessageClass::kSample, node, patch, "HOST");
    emit_message(MessageClass::kInfo, node, patch, "HOST");
    emit_message(MessageClass::kHeartbeat, node, patch, "HOST");
  }
  emit_message(MessageClass::kSync, kNodeBroadcast, "HOST", "Vector__XXX");
  emit_message(MessageClass::kCommand, kNodeBroadcast, "HOST", "Vector__XXX");

  s += "CM_ \"skinbus wire protocol; generated by skinbus-dbc from bus/src/protocol.cc. Multi-part "
       "messages are multiplexed on the part index; their CRC covers the reassembled payload. A "
       "message's length is that of its longest part: the last part may be shorter (decode without "
       "a strict length check).\";\n";
  s += comments;
  s += "BA_DEF_ BO_ \"VFrameFormat\" ENUM "
       "\"StandardCAN\",\"ExtendedCAN\",\"reserved\",\"J1939PG\",\"reserved\","
       "\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\",\"reserved\","
       "\"reserved\","
       "\"reserved\",\"StandardCAN_FD\",\"ExtendedCAN_FD\";\n";
  s += "BA_DEF_DEF_ \"VFrameFormat\" \"StandardCAN\";\n";
  s += attributes;
  return s;
}

}  // namespace skinbus::bus
