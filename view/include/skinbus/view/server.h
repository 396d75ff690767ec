// skinbus/view/server.h: a small HTTP + WebSocket server for the web view (docs/view.md): static
// files and in-memory documents over HTTP/1.1 (one request a connection), and a text stream
// broadcast to every connected page over WebSocket, or messages (text or binary) sent to one page
// (the Foxglove WebSocket protocol's per-subscription data, docs/foxglove.md).
//
// Single-threaded: the owner calls poll() in its loop (and broadcast() between polls); no thread,
// no callback into the owner but the greeting. Bounded in everything a client controls: at most
// `max_clients` pages and `max_connections` sockets at once, a request head of 8 KiB, a client
// frame of `max_message_bytes`, `max_backlog_bytes` queued for a page that does not read (then it
// is disconnected), and 10 s for a request to arrive. Messages from pages go to the message
// handler, if one is set (else they are counted and ignored), with whether they come from this
// machine. Binds to the loopback address by default.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::view {

struct ServerOptions {
  std::string bind_address = "127.0.0.1";    // an IPv4 address; "0.0.0.0" serves every interface
  uint16_t port = 8080;                      // 0: a free port the kernel picks (see Server::port)
  int max_clients = 16;                      // WebSocket pages at once; more get HTTP 503
  int max_connections = 64;                  // sockets at once (pages and plain requests)
  std::size_t max_message_bytes = 4096;      // a client frame over this closes the connection
  std::size_t max_backlog_bytes = 4u << 20;  // queued for one page; over this it is dropped
  int request_timeout_ms = 10000;            // a request head must arrive within this
};

struct ServerStats {
  uint64_t http_requests = 0;         // answered with a document or a file (200)
  uint64_t http_errors = 0;           // answered 4xx/5xx (bad request, not found, refused,
                                      // an upgrade without the subprotocol)
  uint64_t clients_connected = 0;     // WebSocket handshakes accepted, ever
  uint64_t clients_refused = 0;       // WebSocket handshakes refused (max_clients reached)
  uint64_t clients_dropped_slow = 0;  // disconnected for not reading (max_backlog_bytes)
  uint64_t protocol_errors = 0;       // connections closed for a malformed or oversized frame
  uint64_t client_messages = 0;       // text messages from pages
  uint64_t connections_refused = 0;   // sockets closed at once (max_connections reached)
  uint64_t timeouts = 0;              // requests that did not arrive in time
  uint64_t messages_broadcast = 0;    // broadcast() calls
  int clients = 0;                    // pages connected now
};

class Server {
 public:
  // Binds and listens. kIo (with errno's text) when the address is taken or cannot be bound;
  // kInvalidArgument for an address that is not IPv4 or limits below 1.
  static Result<std::unique_ptr<Server>> create(const ServerOptions& options);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  uint16_t port() const;  // the port listened on (the kernel's pick when options.port was 0)

  // GET `path` answers `body` (copied) with `content_type`. Replaces an earlier document.
  void add_document(const std::string& path, const std::string& content_type,
                    const std::string& body);
  // GET `url_prefix` + rest answers the file `folder` + "/" + rest ("/" alone: index.html), if it
  // is a regular file. `url_prefix` starts and ends with '/'; the longest matching prefix wins.
  void add_folder(const std::string& url_prefix, const std::string& folder);
  // The path of the WebSocket stream (default "/ws").
  void set_stream_path(const std::string& path);
  // Called for every page that connects: the messages it gets first (the latest state).
  void set_greeting(std::function<std::vector<std::string>()> greeting);
  // The WebSocket subprotocol the stream speaks (RFC 6455 Sec-WebSocket-Protocol), e.g.
  // "foxglove.websocket.v1". When set, an upgrade must offer it (else HTTP 400) and the answer
  // selects it; empty (the default): no subprotocol is negotiated and any offer is ignored.
  void set_subprotocol(const std::string& subprotocol);

  // Called (from poll()) for every text message a page sends: `page` names its connection (for
  // send_to()), `loopback` says whether it comes from this machine (127.0.0.0/8; an SSH tunnel
  // arrives there too). Without a handler, messages are counted and ignored.
  void set_message_handler(
      std::function<void(uint64_t page, std::string_view text, bool loopback)> handler);
  // Queues `text` as one text message (UTF-8) to page `page`, or `bytes` as one binary message;
  // the socket takes it on the next poll() or broadcast(). False when that page has gone (closed,
  // never was, or closing): a caller keeping per-page state forgets the page then. A page whose
  // queue would pass max_backlog_bytes is dropped instead (counted in clients_dropped_slow) and
  // false is returned. Page IDs are never reused. Costs one copy of the message.
  bool send_to(uint64_t page, std::string_view text);
  bool send_binary_to(uint64_t page, std::string_view bytes);

  // Queues `text` as one message to every connected page and sends what the sockets take now.
  void broadcast(std::string_view text);
  // One turn: accepts, reads requests and frames, answers, sends queued bytes, closes what is
  // done. Waits at most `timeout_ms` for something to happen. kIo only when poll() itself fails.
  Status poll(int timeout_ms);

  ServerStats stats() const;

 private:
  struct Impl;
  explicit Server(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// The Content-Type the server sends for a file name (by extension; octet-stream otherwise).
std::string content_type_for(std::string_view file_name);

}  // namespace skinbus::view
