#include "skinbus/bus/format.h"

#include <cinttypes>
#include <cstdio>

#include "byte_order.h"
#include "text.h"

namespace skinbus::bus {

using internal::appendf;

namespace {

std::string join_bits(unsigned bits, const char* const* names, int count) {
  std::string s;
  for (int i = 0; i < count; ++i) {
    if (!(bits & (1u << i))) continue;
    if (!s.empty()) s += ',';
    s += names[i];
  }
  return s.empty() ? "-" : s;
}

std::string heartbeat_status_text(uint8_t status) {
  static const char* const kNames[] = {"sync", "identify", "tared", "simulated"};
  return join_bits(status, kNames, 4);
}

struct Formatter {
  std::string* s;
  void operator()(const Sync& m) const {
    appendf(s, " counter=%u host_time_us=%" PRIu32, m.counter, m.host_time_us);
  }
  void operator()(const Command& m) const {
    appendf(s, " op=%s", std::string(opcode_name(m.opcode)).c_str());
    if (opcode_name(m.opcode) == "unknown") appendf(s, "(0x%02X)", static_cast<unsigned>(m.opcode));
    const uint32_t arg32 = internal::get_u32(m.arg.data());
    switch (m.opcode) {
      case Opcode::kSetMode:
        appendf(s, " mode=%s",
                m.arg[0] < kPatchModeCount
                    ? std::string(patch_mode_name(static_cast<PatchMode>(m.arg[0]))).c_str()
                    : "invalid");
        break;
      case Opcode::kSetRate:
        appendf(s, " rate_hz=%.2f", internal::get_u16(m.arg.data()) / 100.0);
        break;
      case Opcode::kSyncMode:
        appendf(s, " enable=%u", m.arg[0]);
        break;
      case Opcode::kIdentify:
        appendf(s, " seconds=%u", m.arg[0]);
        break;
      case Opcode::kReboot:
        appendf(s, " magic=%08" PRIX32, arg32);
        break;
      default:
        break;
    }
    appendf(s, " arg=%02X%02X%02X%02X%02X", m.arg[0], m.arg[1], m.arg[2], m.arg[3], m.arg[4]);
  }
  void operator()(const Ack& m) const {
    const std::string op(opcode_name(static_cast<Opcode>(m.opcode)));
    appendf(s, " op=%s", op.c_str());
    if (op == "unknown") appendf(s, "(0x%02X)", m.opcode);
    appendf(s, " status=%s cmd_seq=%u%s value=%u", std::string(ack_status_name(m.status)).c_str(),
            m.command_seq, m.broadcast ? " broadcast" : "", m.value);
  }
  void operator()(const Sample& m) const {
    appendf(s, " t_us=%" PRIu32 " flags=%s fault=%04X sat=%04X field_ut=", m.timestamp_us,
            format_sample_flags(m.flags).c_str(), m.fault_mask, m.saturation_mask);
    for (int ch = 0; ch < kChannelCount; ++ch) {
      appendf(s, ch ? ",%.1f" : "%.1f", m.field_lsb[ch] * kFieldUtPerLsb);
    }
  }
  void operator()(const Info& m) const {
    appendf(
        s, " uid=%016" PRIx64 " fw=%u.%u.%u proto=%u sensors=%ux%u gain=%u res=%02X osr=%u filt=%u",
        m.hardware_uid, m.fw_major, m.fw_minor, m.fw_patch, m.protocol_version, m.sensor_count,
        m.axis_count, m.gain_sel, m.resolution, m.oversampling, m.digital_filter);
    appendf(s, " rate_hz=%.2f max_rate_hz=%.2f conv_us=%u lsb_nt=%u", m.rate_chz / 100.0,
            m.max_rate_chz / 100.0, m.conversion_time_us, m.field_lsb_nt);
  }
  void operator()(const Heartbeat& m) const {
    appendf(s,
            " state=%s mode=%s rate_hz=%.2f uptime_s=%" PRIu32 " uid=%016" PRIx64
            " fw=%u.%u.%u status=%s",
            std::string(patch_state_name(m.state)).c_str(),
            std::string(patch_mode_name(m.mode)).c_str(), m.rate_chz / 100.0, m.uptime_s,
            m.hardware_uid, m.fw_major, m.fw_minor, m.fw_patch,
            heartbeat_status_text(m.status).c_str());
    appendf(s, " fault=%04X i2c_err=%u can_err=%u sat=%u temp_c=%.2f", m.fault_mask, m.i2c_errors,
            m.can_errors, m.saturation_count, m.temperature_cdeg / 100.0);
  }
};

}  // namespace

std::string format_sample_flags(uint16_t flags) {
  static const char* const kNames[] = {"contact", "saturated", "tare_active", "tared",
                                       "fault",   "synced",    "event_tail",  "drift_tracking"};
  return join_bits(flags, kNames, 8);
}

std::string format_message(const Message& msg) {
  std::string s(message_class_name(msg.message_class()));
  appendf(&s, " node=%u seq=%u", msg.node, msg.seq);
  std::visit(Formatter{&s}, msg.body);
  return s;
}

std::string describe_frame(const CanFrame& frame) {
  FrameView v;
  const DecodeError e = parse_frame(frame, &v);
  std::string s;
  if (e != DecodeError::kNone) {
    appendf(&s, "invalid id=%03X len=%u: %s", frame.id, frame.len,
            std::string(decode_error_name(e)).c_str());
    return s;
  }
  if (v.part_count == 1 && !is_multi_part(v.message_class)) {
    Message m;
    if (decode_single(frame, &m) == DecodeError::kNone) return format_message(m);
  }
  s = std::string(message_class_name(v.message_class));
  appendf(&s, " node=%u seq=%u part=%u/%u bytes=%u..%u", v.node, v.header.seq, v.header.part + 1u,
          v.part_count, v.payload_offset, v.payload_offset + v.part_len - 1u);
  for (const FieldDesc* f = fields_begin(v.message_class); f != fields_end(v.message_class); ++f) {
    const std::size_t size = field_size(f->type);
    if (f->offset < v.payload_offset || f->offset + size > v.payload_offset + v.part_len) continue;
    const uint8_t* p = v.part_data + (f->offset - v.payload_offset);
    switch (f->type) {
      case FieldType::kU8:
        appendf(&s, " %s=%u", f->name, p[0]);
        break;
      case FieldType::kU16:
        if (f->scale != 1) {
          appendf(&s, " %s=%g", f->name, internal::get_u16(p) * f->scale);
        } else {
          appendf(&s, " %s=%u", f->name, internal::get_u16(p));
        }
        break;
      case FieldType::kI16:
        appendf(&s, " %s=%g", f->name, internal::get_i16(p) * f->scale);
        break;
      case FieldType::kU32:
        appendf(&s, " %s=%" PRIu32, f->name, internal::get_u32(p));
        break;
      case FieldType::kU64:
        appendf(&s, " %s=%016" PRIx64, f->name, internal::get_u64(p));
        break;
    }
  }
  return s;
}

}  // namespace skinbus::bus
