#include "skinbus/view/server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <list>
#include <map>
#include <sstream>

#include "skinbus/view/http_request.h"
#include "skinbus/view/websocket.h"

namespace skinbus::view {
namespace {

using Clock = std::chrono::steady_clock;

constexpr std::size_t kReadChunkBytes = 16384;

Error io_error(const std::string& what) {
  return make_error(ErrorCode::kIo, what + ": " + std::strerror(errno));
}

std::string status_text(int code) {
  switch (code) {
    case 200:
      return "OK";
    case 400:
      return "Bad Request";
    case 404:
      return "Not Found";
    case 405:
      return "Method Not Allowed";
    case 503:
      return "Service Unavailable";
    default:
      return "Error";
  }
}

std::string response(int code, const std::string& content_type, const std::string& body) {
  std::ostringstream s;
  s << "HTTP/1.1 " << code << ' ' << status_text(code) << "\r\n"
    << "Content-Type: " << content_type << "\r\n"
    << "Content-Length: " << body.size() << "\r\n"
    << "Cache-Control: no-cache\r\n"
    << "X-Content-Type-Options: nosniff\r\n"
    << "Connection: close\r\n\r\n"
    << body;
  return s.str();
}

}  // namespace

std::string content_type_for(std::string_view name) {
  static const std::map<std::string, std::string, std::less<>> kTypes = {
      {".html", "text/html; charset=utf-8"},
      {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},
      {".json", "application/json"},
      {".urdf", "application/xml"},
      {".xml", "application/xml"},
      {".png", "image/png"},
      {".svg", "image/svg+xml"},
      {".stl", "model/stl"},
      {".dae", "model/vnd.collada+xml"},
  };
  const std::size_t dot = name.rfind('.');
  if (dot != std::string_view::npos) {
    const auto it = kTypes.find(name.substr(dot));
    if (it != kTypes.end()) return it->second;
  }
  return "application/octet-stream";
}

struct Server::Impl {
  struct Connection {
    int fd = -1;
    uint64_t id = 0;        // for send_to()
    bool loopback = false;  // the peer is on this machine (127.0.0.0/8)
    bool websocket = false;
    bool closing = false;  // close once `out` is sent
    std::string in;        // the request head so far (HTTP)
    std::string out;       // bytes to send
    std::size_t out_sent = 0;
    FrameReader frames;
    Clock::time_point opened;
    explicit Connection(std::size_t max_message_bytes) : frames(max_message_bytes) {}
    std::size_t pending() const { return out.size() - out_sent; }
  };

  ServerOptions options;
  int listen_fd = -1;
  uint16_t port = 0;
  std::map<std::string, std::pair<std::string, std::string>> documents;  // path -> (type, body)
  std::map<std::string, std::string> folders;                            // prefix -> folder
  std::string stream_path = "/ws";
  std::string subprotocol;  // "" when none is negotiated
  std::function<std::vector<std::string>()> greeting;
  std::function<void(uint64_t, std::string_view, bool)> message_handler;
  uint64_t next_id = 1;
  std::list<Connection> connections;
  ServerStats stats;

  ~Impl() {
    for (auto& c : connections) ::close(c.fd);
    if (listen_fd >= 0) ::close(listen_fd);
  }

  void accept_all() {
    for (;;) {
      sockaddr_in peer{};
      socklen_t peer_len = sizeof peer;
      const int fd = ::accept4(listen_fd, reinterpret_cast<sockaddr*>(&peer), &peer_len,
                               SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) return;  // EAGAIN, or an error of one connection: nothing to do
      if (static_cast<int>(connections.size()) >= options.max_connections) {
        ++stats.connections_refused;
        ::close(fd);
        continue;
      }
      const int one = 1;
      ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      connections.emplace_back(options.max_message_bytes);
      connections.back().fd = fd;
      connections.back().id = next_id++;
      connections.back().loopback =
          peer.sin_family == AF_INET && (ntohl(peer.sin_addr.s_addr) >> 24) == 127;
      connections.back().opened = Clock::now();
    }
  }

  void answer(Connection& c, int code, const std::string& type, const std::string& body) {
    (code == 200 ? stats.http_requests : stats.http_errors) += 1;
    c.out += response(code, type, body);
    c.closing = true;
  }

  void serve_file(Connection& c, const std::string& path) {
    const std::string* folder = nullptr;
    std::size_t prefix_length = 0;
    for (const auto& [prefix, dir] : folders) {  // the longest matching prefix wins
      if (path.compare(0, prefix.size(), prefix) == 0 &&
          (folder == nullptr || prefix.size() > prefix_length)) {
        folder = &dir;
        prefix_length = prefix.size();
      }
    }
    if (folder == nullptr) return answer(c, 404, "text/plain", "not found\n");
    std::string file = path.substr(prefix_length);
    if (file.empty() || file.back() == '/') file += "index.html";
    const std::string full = *folder + "/" + file;
    struct stat st {};
    if (::stat(full.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) {
      return answer(c, 404, "text/plain", "not found\n");
    }
    std::ifstream in(full, std::ios::binary);
    std::ostringstream body;
    body << in.rdbuf();
    if (!in.good() && !in.eof()) return answer(c, 404, "text/plain", "not readable\n");
    answer(c, 200, content_type_for(file), body.str());
  }

  void upgrade(Connection& c, const HttpRequest& request) {
    if (stats.clients >= options.max_clients) {
      ++stats.clients_refused;
      return answer(c, 503, "text/plain", "too many pages connected\n");
    }
    if (!subprotocol.empty() &&
        !offers_subprotocol(request.header("sec-websocket-protocol"), subprotocol)) {
      return answer(c, 400, "text/plain",
                    "this stream speaks the WebSocket subprotocol " + subprotocol +
                        " (Sec-WebSocket-Protocol)\n");
    }
    c.out +=
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        "Sec-WebSocket-Accept: " +
        websocket_accept_key(request.header("sec-websocket-key")) + "\r\n";
    if (!subprotocol.empty()) c.out += "Sec-WebSocket-Protocol: " + subprotocol + "\r\n";
    c.out += "\r\n";
    c.websocket = true;
    ++stats.clients;
    ++stats.clients_connected;
    if (greeting) {
      for (const auto& m : greeting()) append_text_frame(m, &c.out);
    }
  }

  void handle_request(Connection& c, std::string_view head) {
    auto request = parse_request_head(head);
    if (!request.ok()) return answer(c, 400, "text/plain", request.error().message + "\n");
    if (request->method != "GET") return answer(c, 405, "text/plain", "GET only\n");
    if (request->path == stream_path) {
      if (!request->is_websocket_upgrade()) {
        return answer(c, 400, "text/plain", "a WebSocket upgrade is expected here\n");
      }
      return upgrade(c, *request);
    }
    const auto doc = documents.find(request->path);
    if (doc != documents.end()) return answer(c, 200, doc->second.first, doc->second.second);
    serve_file(c, request->path);
  }

  void protocol_error(Connection& c, uint16_t code) {
    ++stats.protocol_errors;
    append_close_frame(code, &c.out);
    c.closing = true;
  }

  // Reads what the socket has. False when the connection is over (closed or failed).
  bool read(Connection& c) {
    char buf[kReadChunkBytes];
    const ssize_t n = ::recv(c.fd, buf, sizeof buf, MSG_DONTWAIT);
    if (n == 0) return false;
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    if (c.closing) return true;  // an answer is on its way; what follows is not read
    std::string_view bytes(buf, static_cast<std::size_t>(n));
    std::string after_head;
    if (!c.websocket) {
      c.in.append(bytes);
      const auto length = request_head_length(c.in);
      if (!length.ok()) {
        answer(c, 400, "text/plain", length.error().message + "\n");
        return true;
      }
      if (*length == 0) return true;
      handle_request(c, std::string_view(c.in).substr(0, *length));
      if (!c.websocket) return true;
      // A client may send its first frames in the same packet as its upgrade.
      after_head = c.in.substr(*length);
      c.in.clear();
      bytes = after_head;
    }
    read_frames(c, bytes);
    return true;
  }

  void read_frames(Connection& c, std::string_view bytes) {
    c.frames.feed({reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()});
    ClientFrame frame;
    for (;;) {
      const auto step = c.frames.next(&frame);
      if (step == FrameReader::Step::kNeedMore) return;
      if (step == FrameReader::Step::kError) return protocol_error(c, c.frames.close_code());
      if (frame.kind == ClientFrame::Kind::kText) {
        ++stats.client_messages;
        if (message_handler) message_handler(c.id, frame.payload, c.loopback);
      } else if (frame.kind == ClientFrame::Kind::kBinary) {
        return protocol_error(c, kCloseUnsupportedData);
      } else if (frame.kind == ClientFrame::Kind::kPing) {
        append_pong_frame(frame.payload, &c.out);
      } else if (frame.kind == ClientFrame::Kind::kClose) {
        append_close_frame(kCloseNormal, &c.out);
        c.closing = true;
        return;
      }
    }
  }

  // Sends what the socket takes. False when the connection failed.
  bool write(Connection& c) {
    while (c.pending() > 0) {
      const ssize_t n =
          ::send(c.fd, c.out.data() + c.out_sent, c.pending(), MSG_DONTWAIT | MSG_NOSIGNAL);
      if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
      c.out_sent += static_cast<std::size_t>(n);
    }
    c.out.clear();
    c.out_sent = 0;
    return true;
  }

  // Queues one frame for page `page` (see Server::send_to). A page over its backlog is not closed
  // here (send_to may run inside poll()'s walk over the connections): its queue is emptied and it
  // is marked closing, so poll() closes it.
  bool send_frame_to(uint64_t page, std::string_view payload, bool binary) {
    for (auto& c : connections) {
      if (c.id != page) continue;
      if (!c.websocket || c.closing) return false;
      if (c.pending() + payload.size() > options.max_backlog_bytes) {
        ++stats.clients_dropped_slow;
        c.out.clear();
        c.out_sent = 0;
        c.closing = true;
        return false;
      }
      binary ? append_binary_frame(payload, &c.out) : append_text_frame(payload, &c.out);
      return true;
    }
    return false;
  }

  void close(std::list<Connection>::iterator it) {
    if (it->websocket) --stats.clients;
    ::close(it->fd);
    connections.erase(it);
  }
};

Server::Server(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Server::~Server() = default;

Result<std::unique_ptr<Server>> Server::create(const ServerOptions& options) {
  if (options.max_clients < 1 || options.max_connections < 1 || options.max_message_bytes < 1 ||
      options.max_backlog_bytes < 1 || options.request_timeout_ms < 1) {
    return make_error(ErrorCode::kInvalidArgument, "view server: every limit must be at least 1");
  }
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(options.port);
  if (::inet_pton(AF_INET, options.bind_address.c_str(), &addr.sin_addr) != 1) {
    return make_error(ErrorCode::kInvalidArgument,
                      "view server: '" + options.bind_address + "' is not an IPv4 address");
  }
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->listen_fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (impl->listen_fd < 0) return io_error("view server: socket");
  const int one = 1;
  ::setsockopt(impl->listen_fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (::bind(impl->listen_fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    return io_error("view server: bind " + options.bind_address + ":" +
                    std::to_string(options.port));
  }
  if (::listen(impl->listen_fd, 64) != 0) return io_error("view server: listen");
  socklen_t len = sizeof addr;
  ::getsockname(impl->listen_fd, reinterpret_cast<sockaddr*>(&addr), &len);
  impl->port = ntohs(addr.sin_port);
  return std::unique_ptr<Server>(new Server(std::move(impl)));
}

uint16_t Server::port() const {
  return impl_->port;
}

void Server::add_document(const std::string& path, const std::string& content_type,
                          const std::string& body) {
  impl_->documents[path] = {content_type, body};
}

void Server::add_folder(const std::string& url_prefix, const std::string& folder) {
  impl_->folders[url_prefix] = folder;
}

void Server::set_stream_path(const std::string& path) {
  impl_->stream_path = path;
}

void Server::set_greeting(std::function<std::vector<std::string>()> greeting) {
  impl_->greeting = std::move(greeting);
}

void Server::set_message_handler(
    std::function<void(uint64_t page, std::string_view text, bool loopback)> handler) {
  impl_->message_handler = std::move(handler);
}

void Server::set_subprotocol(const std::string& subprotocol) {
  impl_->subprotocol = subprotocol;
}

bool Server::send_to(uint64_t page, std::string_view text) {
  return impl_->send_frame_to(page, text, /*binary=*/false);
}

bool Server::send_binary_to(uint64_t page, std::string_view bytes) {
  return impl_->send_frame_to(page, bytes, /*binary=*/true);
}

void Server::broadcast(std::string_view text) {
  ++impl_->stats.messages_broadcast;
  for (auto it = impl_->connections.begin(); it != impl_->connections.end();) {
    auto& c = *it;
    if (!c.websocket || c.closing) {
      ++it;
      continue;
    }
    if (c.pending() + text.size() > impl_->options.max_backlog_bytes) {
      ++impl_->stats.clients_dropped_slow;
      impl_->close(it++);
      continue;
    }
    append_text_frame(text, &c.out);
    if (!impl_->write(c)) {
      impl_->close(it++);
      continue;
    }
    ++it;
  }
}

Status Server::poll(int timeout_ms) {
  auto& s = *impl_;
  std::vector<pollfd> fds;
  fds.reserve(s.connections.size() + 1);
  fds.push_back({s.listen_fd, POLLIN, 0});
  for (const auto& c : s.connections) {
    fds.push_back({c.fd, static_cast<short>(POLLIN | (c.pending() > 0 ? POLLOUT : 0)), 0});
  }
  const int n = ::poll(fds.data(), fds.size(), timeout_ms);
  if (n < 0) return errno == EINTR ? Status::Ok() : Status(io_error("view server: poll"));
  if (fds[0].revents & POLLIN) s.accept_all();
  const auto now = Clock::now();
  std::size_t i = 1;
  for (auto it = s.connections.begin(); it != s.connections.end(); ++i) {
    auto& c = *it;
    bool alive = true;
    const short revents = i < fds.size() && fds[i].fd == c.fd ? fds[i].revents : 0;
    if (revents & (POLLIN | POLLHUP | POLLERR)) alive = s.read(c);
    if (alive) alive = s.write(c);
    if (alive && c.closing && c.pending() == 0) alive = false;
    if (alive && !c.websocket &&
        now - c.opened > std::chrono::milliseconds(s.options.request_timeout_ms)) {
      ++s.stats.timeouts;
      alive = false;
    }
    if (alive) {
      ++it;
    } else {
      s.close(it++);
    }
  }
  return Status::Ok();
}

ServerStats Server::stats() const {
  return impl_->stats;
}

}  // namespace skinbus::view
