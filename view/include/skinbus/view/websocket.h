// skinbus/view/websocket.h: the parts of the WebSocket protocol (RFC 6455) a server that streams
// to browsers and other clients needs: the handshake's accept key and subprotocol choice, server
// frames (unmasked text, binary and close) and an incremental reader of client frames (masked,
// bounded).
//
// No allocation beyond the vectors a caller hands in; no socket: server.h does the I/O.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace skinbus::view {

// Sec-WebSocket-Accept for a client's Sec-WebSocket-Key: base64(SHA-1(key + the RFC's GUID)).
std::string websocket_accept_key(std::string_view client_key);

// SHA-1 of `data` (20 bytes), and standard base64 with padding: the handshake's two primitives.
std::string sha1(std::string_view data);
std::string base64(std::string_view bytes);

// Whether the Sec-WebSocket-Protocol header `offered` (a comma-separated list of tokens, as a
// client sends it; spaces around the commas allowed) names `subprotocol` exactly.
bool offers_subprotocol(std::string_view offered, std::string_view subprotocol);

// Close status codes (RFC 6455 section 7.4.1) the server sends.
enum CloseCode : uint16_t {
  kCloseNormal = 1000,
  kCloseGoingAway = 1001,
  kCloseProtocolError = 1002,
  kCloseUnsupportedData = 1003,  // a binary frame: the server reads text (JSON) only
  kCloseTooBig = 1009,
};

// Appends one unfragmented, unmasked server frame to *out.
void append_text_frame(std::string_view text, std::string* out);
void append_binary_frame(std::string_view bytes, std::string* out);
void append_close_frame(uint16_t code, std::string* out);
void append_pong_frame(std::string_view payload, std::string* out);

// One complete client message or control frame.
struct ClientFrame {
  enum class Kind : uint8_t { kText, kBinary, kClose, kPing, kPong };
  Kind kind = Kind::kText;
  std::string payload;  // unmasked
};

// Reads client frames from a byte stream, fed in whatever pieces the socket gives. Every client
// frame must be masked (RFC 6455 5.1) and carry at most `max_payload_bytes`; fragmented messages
// are reassembled up to the same bound. A violation is final: the reader reports the close code
// to send and reads nothing more.
class FrameReader {
 public:
  explicit FrameReader(std::size_t max_payload_bytes) : max_payload_bytes_(max_payload_bytes) {}

  enum class Step : uint8_t {
    kNeedMore,  // no complete frame buffered yet
    kFrame,     // *frame holds the next frame
    kError,     // the client broke the protocol: close with close_code() and stop reading
  };
  // Appends `bytes` to the buffer; callers feed what one read gave, then call next() until it
  // returns kNeedMore or kError, so the buffer holds at most one read and one partial frame.
  void feed(std::span<const uint8_t> bytes);
  Step next(ClientFrame* frame);

  uint16_t close_code() const { return close_code_; }
  // Bytes buffered and not yet returned as a frame.
  std::size_t buffered_bytes() const { return buffer_.size(); }

 private:
  Step fail(uint16_t code);

  std::size_t max_payload_bytes_;
  std::vector<uint8_t> buffer_;
  std::string fragments_;  // a fragmented message so far
  bool in_fragmented_ = false;
  ClientFrame::Kind fragmented_kind_ = ClientFrame::Kind::kText;
  uint16_t close_code_ = 0;
};

}  // namespace skinbus::view
