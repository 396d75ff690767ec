// skinbus/view/http_request.h: the head of an HTTP/1.1 request, as a small local server needs it:
// the method, the path (query split off, percent-decoding refused), the headers it reads.
#pragma once

#include <cstddef>
#include <map>
#include <string>
#include <string_view>

#include "skinbus/common/result.h"

namespace skinbus::view {

// The largest request head the server reads (request line and headers).
inline constexpr std::size_t kMaxRequestHeadBytes = 8192;

struct HttpRequest {
  std::string method;                          // "GET", ...
  std::string path;                            // "/api/scene" (no query)
  std::string query;                           // after '?', "" when none
  std::map<std::string, std::string> headers;  // names lower-case, values trimmed
  // The value of header `name` (lower-case), "" when absent.
  std::string header(const std::string& name) const;
  // True when the request asks for a WebSocket (Upgrade: websocket, Connection: upgrade, a key).
  bool is_websocket_upgrade() const;
};

// The length of the head in `bytes` (through the blank line), or 0 when the blank line has not
// arrived yet. kOutOfRange when no blank line is within kMaxRequestHeadBytes.
Result<std::size_t> request_head_length(std::string_view bytes);

// Parses a head (request_head_length's bytes). kParse for anything that is not a plain
// "METHOD /path HTTP/1.x" with "Name: value" lines; the message names what was wrong. A path
// must start with '/' and hold no "..", '\\', '%' or control characters: the server maps paths
// onto folders and serves nothing else.
Result<HttpRequest> parse_request_head(std::string_view head);

}  // namespace skinbus::view
