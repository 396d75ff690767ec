#include "skinbus/view/websocket.h"

#include <array>
#include <cstring>

namespace skinbus::view {
namespace {

uint32_t rotl(uint32_t x, int n) {
  return (x << n) | (x >> (32 - n));
}

void append_header(uint8_t opcode, std::size_t length, std::string* out) {
  out->push_back(static_cast<char>(0x80 | opcode));  // FIN, no extension bits
  if (length < 126) {
    out->push_back(static_cast<char>(length));
  } else if (length <= 0xffff) {
    out->push_back(static_cast<char>(126));
    out->push_back(static_cast<char>(length >> 8));
    out->push_back(static_cast<char>(length & 0xff));
  } else {
    out->push_back(static_cast<char>(127));
    for (int shift = 56; shift >= 0; shift -= 8) {
      out->push_back(static_cast<char>((static_cast<uint64_t>(length) >> shift) & 0xff));
    }
  }
}

}  // namespace

std::string sha1(std::string_view data) {
  uint32_t h[5] = {0x67452301u, 0xEFCDAB89u, 0x98BADCFEu, 0x10325476u, 0xC3D2E1F0u};
  std::string msg(data);
  const uint64_t bit_length = static_cast<uint64_t>(data.size()) * 8;
  msg.push_back(static_cast<char>(0x80));
  while (msg.size() % 64 != 56) msg.push_back('\0');
  for (int shift = 56; shift >= 0; shift -= 8) {
    msg.push_back(static_cast<char>((bit_length >> shift) & 0xff));
  }
  for (std::size_t block = 0; block < msg.size(); block += 64) {
    std::array<uint32_t, 80> w{};
    for (int i = 0; i < 16; ++i) {
      const auto* b = reinterpret_cast<const uint8_t*>(msg.data() + block + 4 * i);
      w[i] = (uint32_t{b[0]} << 24) | (uint32_t{b[1]} << 16) | (uint32_t{b[2]} << 8) | b[3];
    }
    for (int i = 16; i < 80; ++i) w[i] = rotl(w[i - 3] ^ w[i - 8] ^ w[i - 14] ^ w[i - 16], 1);
    uint32_t a = h[0], b = h[1], c = h[2], d = h[3], e = h[4];
    for (int i = 0; i < 80; ++i) {
      uint32_t f, k;
      if (i < 20) {
        f = (b & c) | (~b & d);
        k = 0x5A827999u;
      } else if (i < 40) {
        f = b ^ c ^ d;
        k = 0x6ED9EBA1u;
      } else if (i < 60) {
        f = (b & c) | (b & d) | (c & d);
        k = 0x8F1BBCDCu;
      } else {
        f = b ^ c ^ d;
        k = 0xCA62C1D6u;
      }
      const uint32_t t = rotl(a, 5) + f + e + k + w[i];
      e = d;
      d = c;
      c = rotl(b, 30);
      b = a;
      a = t;
    }
    h[0] += a;
    h[1] += b;
    h[2] += c;
    h[3] += d;
    h[4] += e;
  }
  std::string digest(20, '\0');
  for (int i = 0; i < 20; ++i)
    digest[i] = static_cast<char>((h[i / 4] >> (24 - 8 * (i % 4))) & 0xff);
  return digest;
}

std::string base64(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  for (std::size_t i = 0; i < bytes.size(); i += 3) {
    const std::size_t n = std::min<std::size_t>(3, bytes.size() - i);
    uint32_t v = 0;
    for (std::size_t j = 0; j < 3; ++j) {
      v = (v << 8) | (j < n ? static_cast<uint8_t>(bytes[i + j]) : 0u);
    }
    for (std::size_t j = 0; j < 4; ++j) {
      out.push_back(j <= n ? kAlphabet[(v >> (18 - 6 * j)) & 0x3f] : '=');
    }
  }
  return out;
}

std::string websocket_accept_key(std::string_view client_key) {
  std::string s(client_key);
  s += "258EAFA5-E914-47DA-95CA-C5AB0DC85B11";  // RFC 6455 section 1.3
  return base64(sha1(s));
}

void append_text_frame(std::string_view text, std::string* out) {
  append_header(0x1, text.size(), out);
  out->append(text);
}

void append_binary_frame(std::string_view bytes, std::string* out) {
  append_header(0x2, bytes.size(), out);
  out->append(bytes);
}

bool offers_subprotocol(std::string_view offered, std::string_view subprotocol) {
  while (!offered.empty()) {
    const std::size_t comma = offered.find(',');
    std::string_view token = offered.substr(0, comma);
    while (!token.empty() && (token.front() == ' ' || token.front() == '\t'))
      token.remove_prefix(1);
    while (!token.empty() && (token.back() == ' ' || token.back() == '\t')) token.remove_suffix(1);
    if (!token.empty() && token == subprotocol) return true;
    if (comma == std::string_view::npos) break;
    offered.remove_prefix(comma + 1);
  }
  return false;
}

void append_close_frame(uint16_t code, std::string* out) {
  append_header(0x8, 2, out);
  out->push_back(static_cast<char>(code >> 8));
  out->push_back(static_cast<char>(code & 0xff));
}

void append_pong_frame(std::string_view payload, std::string* out) {
  append_header(0xA, payload.size(), out);
  out->append(payload);
}

void FrameReader::feed(std::span<const uint8_t> bytes) {
  if (close_code_ == 0) buffer_.insert(buffer_.end(), bytes.begin(), bytes.end());
}

FrameReader::Step FrameReader::fail(uint16_t code) {
  close_code_ = code;
  buffer_.clear();
  fragments_.clear();
  return Step::kError;
}

FrameReader::Step FrameReader::next(ClientFrame* frame) {
  if (close_code_ != 0) return Step::kError;
  // One frame a turn; a fragment that does not end its message is kept and the loop goes on.
  for (;;) {
    if (buffer_.size() < 2) return Step::kNeedMore;
    const bool fin = buffer_[0] & 0x80;
    const uint8_t opcode = buffer_[0] & 0x0f;
    if (buffer_[0] & 0x70) return fail(kCloseProtocolError);     // no extension was negotiated
    if (!(buffer_[1] & 0x80)) return fail(kCloseProtocolError);  // clients must mask
    uint64_t length = buffer_[1] & 0x7f;
    std::size_t header = 2;
    if (length == 126) {
      if (buffer_.size() < 4) return Step::kNeedMore;
      length = (uint64_t{buffer_[2]} << 8) | buffer_[3];
      header = 4;
    } else if (length == 127) {
      if (buffer_.size() < 10) return Step::kNeedMore;
      length = 0;
      for (int i = 0; i < 8; ++i) length = (length << 8) | buffer_[2 + i];
      header = 10;
    }
    const bool control = opcode & 0x8;
    if (control && (length > 125 || !fin)) return fail(kCloseProtocolError);
    if (length > max_payload_bytes_) return fail(kCloseTooBig);
    if (buffer_.size() < header + 4 + length) return Step::kNeedMore;
    const uint8_t* mask = buffer_.data() + header;
    std::string payload(static_cast<std::size_t>(length), '\0');
    for (std::size_t i = 0; i < length; ++i) {
      payload[i] = static_cast<char>(buffer_[header + 4 + i] ^ mask[i % 4]);
    }
    buffer_.erase(buffer_.begin(),
                  buffer_.begin() + static_cast<std::ptrdiff_t>(header + 4 + length));

    ClientFrame::Kind kind;
    switch (opcode) {
      case 0x0:  // continuation
        if (!in_fragmented_) return fail(kCloseProtocolError);
        if (fragments_.size() + payload.size() > max_payload_bytes_) return fail(kCloseTooBig);
        fragments_ += payload;
        if (!fin) continue;  // the next fragment
        in_fragmented_ = false;
        frame->kind = fragmented_kind_;
        frame->payload = std::move(fragments_);
        fragments_.clear();
        return Step::kFrame;
      case 0x1:
        kind = ClientFrame::Kind::kText;
        break;
      case 0x2:
        kind = ClientFrame::Kind::kBinary;
        break;
      case 0x8:
        kind = ClientFrame::Kind::kClose;
        break;
      case 0x9:
        kind = ClientFrame::Kind::kPing;
        break;
      case 0xA:
        kind = ClientFrame::Kind::kPong;
        break;
      default:
        return fail(kCloseProtocolError);
    }
    if (!control) {
      if (in_fragmented_) return fail(kCloseProtocolError);  // a new message inside another
      if (!fin) {
        in_fragmented_ = true;
        fragmented_kind_ = kind;
        fragments_ = std::move(payload);
        continue;  // the next fragment
      }
    }
    frame->kind = kind;
    frame->payload = std::move(payload);
    return Step::kFrame;
  }
}

}  // namespace skinbus::view
