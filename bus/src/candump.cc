#include "skinbus/bus/candump.h"

#include <cstdlib>
#include <cstring>

namespace skinbus::bus {

std::string_view candump_error_name(CandumpError e) {
  switch (e) {
    case CandumpError::kNone:
      return "none";
    case CandumpError::kEmpty:
      return "empty";
    case CandumpError::kBadTimestamp:
      return "bad_timestamp";
    case CandumpError::kMissingIface:
      return "missing_interface";
    case CandumpError::kBadId:
      return "bad_identifier";
    case CandumpError::kMissingHash:
      return "missing_hash";
    case CandumpError::kBadData:
      return "bad_data";
    case CandumpError::kBadFlags:
      return "bad_fd_flags";
    case CandumpError::kUnsupported:
      return "unsupported";
    case CandumpError::kLineTooLong:
      return "line_too_long";
  }
  return "unknown";
}

namespace {

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n';
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

// Splits off the next whitespace-separated token.
std::string_view next_token(std::string_view* s) {
  *s = trim(*s);
  std::size_t i = 0;
  while (i < s->size() && !is_space((*s)[i])) ++i;
  std::string_view tok = s->substr(0, i);
  s->remove_prefix(i);
  return tok;
}

bool parse_timestamp(std::string_view tok, uint64_t* us) {
  if (tok.size() < 3 || tok.front() != '(' || tok.back() != ')') return false;
  tok = tok.substr(1, tok.size() - 2);
  const std::size_t dot = tok.find('.');
  if (dot == std::string_view::npos || dot == 0 || dot > 12) return false;
  uint64_t sec = 0;
  for (char c : tok.substr(0, dot)) {
    if (c < '0' || c > '9') return false;
    sec = sec * 10 + static_cast<uint64_t>(c - '0');
  }
  std::string_view frac = tok.substr(dot + 1);
  if (frac.empty() || frac.size() > 9) return false;
  uint64_t f = 0;
  std::size_t digits = 0;
  for (char c : frac) {
    if (c < '0' || c > '9') return false;
    if (digits < 6) f = f * 10 + static_cast<uint64_t>(c - '0');
    ++digits;
  }
  for (; digits < 6; ++digits) f *= 10;
  *us = sec * 1000000ull + f;
  return true;
}

CandumpError parse_data(std::string_view s, CanFrame* f, std::size_t max_len) {
  std::size_t n = 0;
  std::size_t i = 0;
  while (i < s.size()) {
    if (s[i] == '.') {  // cansend allows dots between bytes
      ++i;
      continue;
    }
    if (s[i] == '_' && !f->fd) {  // classic len8_dlc suffix "_9".."_F": the DLC is not carried
      if (i + 2 != s.size() || hex_value(s[i + 1]) < 9) return CandumpError::kBadData;
      break;
    }
    if (i + 1 >= s.size()) return CandumpError::kBadData;
    const int hi = hex_value(s[i]);
    const int lo = hex_value(s[i + 1]);
    if (hi < 0 || lo < 0 || n >= max_len) return CandumpError::kBadData;
    f->data[n++] = static_cast<uint8_t>(hi << 4 | lo);
    i += 2;
  }
  if (f->fd && !is_valid_fd_len(n)) return CandumpError::kBadData;
  f->len = static_cast<uint8_t>(n);
  return CandumpError::kNone;
}

}  // namespace

CandumpError parse_frame_text(std::string_view text, CanFrame* frame) {
  *frame = CanFrame{};
  const std::size_t hash = text.find('#');
  if (hash == std::string_view::npos) {
    return text.empty() ? CandumpError::kBadId : CandumpError::kMissingHash;
  }
  std::string_view id_text = text.substr(0, hash);
  std::string_view rest = text.substr(hash + 1);
  if (id_text.size() != 3 && id_text.size() != 8) return CandumpError::kBadId;
  uint32_t id = 0;
  for (char c : id_text) {
    const int v = hex_value(c);
    if (v < 0) return CandumpError::kBadId;
    id = id << 4 | static_cast<uint32_t>(v);
  }
  if (id_text.size() == 3) {
    if (id > kStandardIdMask) return CandumpError::kBadId;
  } else if (id & kCanErrFlag) {
    frame->error = true;
    id &= ~kCanErrFlag;
    if (id > kExtendedIdMask) return CandumpError::kBadId;
  } else {
    if (id > kExtendedIdMask) return CandumpError::kBadId;
    frame->extended = true;
  }
  frame->id = id;

  if (!rest.empty() && rest.front() == '#') {  // CAN FD (or CAN XL, "###")
    if (frame->error) return CandumpError::kBadId;
    rest.remove_prefix(1);
    if (!rest.empty() && rest.front() == '#') return CandumpError::kUnsupported;
    if (rest.empty()) return CandumpError::kBadFlags;
    const int flags = hex_value(rest.front());
    if (flags < 0) return CandumpError::kBadFlags;
    frame->fd = true;
    frame->brs = flags & 0x1;
    frame->esi = flags & 0x2;
    return parse_data(rest.substr(1), frame, kFdMaxLen);
  }
  if (!rest.empty() && (rest.front() == 'R' || rest.front() == 'r')) {
    if (frame->error) return CandumpError::kBadData;
    frame->rtr = true;
    rest.remove_prefix(1);
    if (rest.empty()) return CandumpError::kNone;
    const int len = hex_value(rest.front());
    if (rest.size() > 1 && rest[1] == '_') rest = rest.substr(0, 1);  // "R8_9" len8_dlc form
    if (rest.size() != 1 || len < 0 || len > 8) return CandumpError::kBadData;
    frame->len = static_cast<uint8_t>(len);
    return CandumpError::kNone;
  }
  return parse_data(rest, frame, kClassicMaxLen);
}

CandumpError parse_candump_line(std::string_view line, CandumpRecord* record) {
  std::string_view s = trim(line);
  if (s.empty() || s.front() == '#') return CandumpError::kEmpty;
  std::string_view ts = next_token(&s);
  record->has_timestamp = parse_timestamp(ts, &record->timestamp_us);
  if (!record->has_timestamp) return CandumpError::kBadTimestamp;
  record->iface = next_token(&s);
  if (record->iface.empty()) return CandumpError::kMissingIface;
  std::string_view frame_text = next_token(&s);
  if (frame_text.empty()) return CandumpError::kMissingIface;
  std::string_view tail = next_token(&s);
  if (!(tail.empty() || tail == "R" || tail == "T") || !trim(s).empty())
    return CandumpError::kBadData;
  return parse_frame_text(frame_text, &record->frame);
}

std::size_t format_frame_text(const CanFrame& f, std::span<char> out) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  if (out.size() < 2 * kFdMaxLen + 16) return 0;
  int n = 0;
  if (f.error) {
    n = std::snprintf(out.data(), out.size(), "%08X#", f.id | kCanErrFlag);
  } else if (f.extended) {
    n = std::snprintf(out.data(), out.size(), "%08X#", f.id);
  } else {
    n = std::snprintf(out.data(), out.size(), "%03X#", f.id);
  }
  std::size_t pos = static_cast<std::size_t>(n);
  if (f.rtr) {
    out[pos++] = 'R';
    if (f.len > 0) out[pos++] = kHex[f.len & 0xF];
    out[pos] = '\0';
    return pos;
  }
  if (f.fd) {
    out[pos++] = '#';
    out[pos++] = kHex[(f.brs ? 1 : 0) | (f.esi ? 2 : 0)];
  }
  for (std::size_t i = 0; i < f.len && i < kFdMaxLen; ++i) {
    out[pos++] = kHex[f.data[i] >> 4];
    out[pos++] = kHex[f.data[i] & 0xF];
  }
  out[pos] = '\0';
  return pos;
}

std::size_t format_candump_line(const CanFrame& frame, uint64_t timestamp_us,
                                std::string_view iface, std::span<char> out) {
  if (out.size() < kCandumpLineMax || iface.size() > 32) return 0;
  const int n = std::snprintf(out.data(), out.size(), "(%010llu.%06llu) %.*s ",
                              static_cast<unsigned long long>(timestamp_us / 1000000),
                              static_cast<unsigned long long>(timestamp_us % 1000000),
                              static_cast<int>(iface.size()), iface.data());
  const std::size_t pos = static_cast<std::size_t>(n);
  const std::size_t m = format_frame_text(frame, out.subspan(pos));
  return m == 0 ? 0 : pos + m;
}

std::string format_candump_line(const CanFrame& frame, uint64_t timestamp_us,
                                std::string_view iface) {
  char buf[kCandumpLineMax];
  return std::string(buf, format_candump_line(frame, timestamp_us, iface, buf));
}

CandumpReader::Status CandumpReader::next(CandumpRecord* record) {
  for (;;) {
    line_ = {};
    switch (lines_.next(&line_)) {
      case LineReader::Status::kLine:
        break;
      case LineReader::Status::kTooLong:
        error_ = CandumpError::kLineTooLong;
        ++bad_lines_;
        return Status::kBadLine;
      case LineReader::Status::kEof:
        return Status::kEof;
      case LineReader::Status::kError:
        read_error_ = lines_.error_number();
        return Status::kEof;
      case LineReader::Status::kWait:
        if (wait_) return Status::kWait;
        continue;  // a signal interrupted a blocking read: go on reading
    }
    const CandumpError e = parse_candump_line(line_, record);
    if (e == CandumpError::kEmpty) continue;
    if (e != CandumpError::kNone) {
      error_ = e;
      ++bad_lines_;
      return Status::kBadLine;
    }
    ++records_;
    return Status::kRecord;
  }
}

}  // namespace skinbus::bus
