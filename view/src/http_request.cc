#include "skinbus/view/http_request.h"

#include <algorithm>
#include <cctype>

#include "skinbus/common/error_format.h"

namespace skinbus::view {
namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

// True when the comma-separated header value holds `token` (case-insensitive).
bool has_token(const std::string& value, std::string_view token) {
  std::string_view rest = value;
  while (!rest.empty()) {
    const std::size_t comma = rest.find(',');
    if (lower(trim(rest.substr(0, comma))) == token) return true;
    if (comma == std::string_view::npos) break;
    rest.remove_prefix(comma + 1);
  }
  return false;
}

Error bad(const std::string& what) {
  return make_error(ErrorCode::kParse, "HTTP request: " + what);
}

}  // namespace

std::string HttpRequest::header(const std::string& name) const {
  const auto it = headers.find(name);
  return it == headers.end() ? std::string() : it->second;
}

bool HttpRequest::is_websocket_upgrade() const {
  return has_token(header("upgrade"), "websocket") && has_token(header("connection"), "upgrade") &&
         !header("sec-websocket-key").empty();
}

Result<std::size_t> request_head_length(std::string_view bytes) {
  const std::size_t end = bytes.find("\r\n\r\n");
  if (end != std::string_view::npos && end + 4 <= kMaxRequestHeadBytes) return end + 4;
  if (end != std::string_view::npos || bytes.size() >= kMaxRequestHeadBytes) {
    return errorf(ErrorCode::kOutOfRange, "HTTP request: the head is over %zu bytes",
                  kMaxRequestHeadBytes);
  }
  return std::size_t{0};
}

Result<HttpRequest> parse_request_head(std::string_view head) {
  if (head.size() > kMaxRequestHeadBytes) return bad("the head is too long");
  for (char c : head) {
    if ((static_cast<unsigned char>(c) < 0x20 && c != '\r' && c != '\n' && c != '\t') ||
        c == 0x7f) {
      return bad("a control character in the head");
    }
  }
  HttpRequest r;
  std::size_t line_end = head.find("\r\n");
  if (line_end == std::string_view::npos) return bad("no request line");
  const std::string_view line = head.substr(0, line_end);
  const std::size_t sp1 = line.find(' ');
  const std::size_t sp2 = sp1 == std::string_view::npos ? sp1 : line.find(' ', sp1 + 1);
  if (sp2 == std::string_view::npos || line.find(' ', sp2 + 1) != std::string_view::npos) {
    return bad("the request line is not 'METHOD PATH VERSION'");
  }
  r.method = std::string(line.substr(0, sp1));
  std::string_view target = line.substr(sp1 + 1, sp2 - sp1 - 1);
  const std::string_view version = line.substr(sp2 + 1);
  if (version != "HTTP/1.1" && version != "HTTP/1.0") return bad("not HTTP/1.0 or 1.1");
  if (r.method.empty() ||
      !std::all_of(r.method.begin(), r.method.end(), [](char c) { return c >= 'A' && c <= 'Z'; })) {
    return bad("a bad method");
  }
  const std::size_t q = target.find('?');
  if (q != std::string_view::npos) {
    r.query = std::string(target.substr(q + 1));
    target = target.substr(0, q);
  }
  if (target.empty() || target.front() != '/') return bad("the path does not start with '/'");
  if (target.find("..") != std::string_view::npos ||
      target.find_first_of("\\%") != std::string_view::npos) {
    return bad("the path holds '..', '\\' or '%'");
  }
  r.path = std::string(target);

  std::string_view rest = head.substr(line_end + 2);
  while (!rest.empty()) {
    line_end = rest.find("\r\n");
    if (line_end == std::string_view::npos) return bad("a header line without CRLF");
    const std::string_view h = rest.substr(0, line_end);
    rest.remove_prefix(line_end + 2);
    if (h.empty()) break;  // the blank line ending the head
    const std::size_t colon = h.find(':');
    if (colon == 0 || colon == std::string_view::npos) return bad("a header line without a name");
    const std::string_view name = h.substr(0, colon);
    if (name.find_first_of(" \t") != std::string_view::npos) return bad("a space in a header name");
    r.headers[lower(name)] = std::string(trim(h.substr(colon + 1)));
  }
  return r;
}

}  // namespace skinbus::view
