#include "skinbus/view/server.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <tuple>

#include "skinbus/view/websocket.h"

namespace skinbus::view {
namespace {

// A client socket on the loopback; reads are non-blocking and gathered in `received`.
class TestClient {
 public:
  explicit TestClient(uint16_t port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  }
  ~TestClient() { ::close(fd_); }
  bool connected() const { return connected_; }
  void send(const std::string& bytes) {
    ASSERT_EQ(::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL),
              static_cast<ssize_t>(bytes.size()));
  }
  // Reads what has arrived. False once the server closed the connection.
  bool read_available() {
    char buf[65536];
    for (;;) {
      const ssize_t n = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
      if (n == 0) return open_ = false;
      if (n < 0) return open_;
      received.append(buf, static_cast<std::size_t>(n));
    }
  }
  bool open() const { return open_; }
  std::string received;

 private:
  int fd_ = -1;
  bool connected_ = false;
  bool open_ = true;
};

// Polls the server and reads every client until `done` holds (or 5 s pass).
bool pump(Server& server, std::vector<TestClient*> clients, const std::function<bool()>& done) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (std::chrono::steady_clock::now() < end) {
    EXPECT_TRUE(server.poll(2).ok());
    for (auto* c : clients) c->read_available();
    if (done()) return true;
  }
  return false;
}

const std::string kUpgrade =
    "GET /ws HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";

std::string masked(uint8_t first_byte, const std::string& payload) {
  std::string f{static_cast<char>(first_byte)};
  const uint8_t mask[4] = {9, 8, 7, 6};
  if (payload.size() < 126) {
    f.push_back(static_cast<char>(0x80 | payload.size()));
  } else {
    f += {static_cast<char>(0x80 | 126), static_cast<char>(payload.size() >> 8),
          static_cast<char>(payload.size() & 0xff)};
  }
  f.append(reinterpret_cast<const char*>(mask), 4);
  for (std::size_t i = 0; i < payload.size(); ++i) f.push_back(payload[i] ^ mask[i % 4]);
  return f;
}

std::unique_ptr<Server> make_server(ServerOptions options = {}) {
  options.port = 0;
  auto s = Server::create(options);
  EXPECT_TRUE(s.ok()) << s.error().to_string();
  return std::move(s).value();
}

bool contains(const std::string& s, const std::string& what) {
  return s.find(what) != std::string::npos;
}

TEST(ViewServer, ServesDocumentsAndFilesAndNothingElse) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("view_server_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir / "lib");
  std::ofstream(dir / "index.html") << "<p>page</p>";
  std::ofstream(dir / "lib" / "a.js") << "export const a = 1;";
  auto server = make_server();
  server->add_document("/api/scene", "application/json", "{\"type\":\"scene\"}");
  server->add_folder("/", dir.string());
  server->add_folder("/lib/", (dir / "lib").string());

  struct Case {
    std::string request, status, body;
  };
  const std::vector<Case> cases = {
      {"GET /api/scene HTTP/1.1\r\n\r\n", "200 OK", "{\"type\":\"scene\"}"},
      {"GET / HTTP/1.1\r\n\r\n", "200 OK", "<p>page</p>"},
      {"GET /lib/a.js HTTP/1.1\r\n\r\n", "200 OK", "export const a = 1;"},
      {"GET /missing.js HTTP/1.1\r\n\r\n", "404", ""},
      {"GET /../../etc/passwd HTTP/1.1\r\n\r\n", "400", ""},
      {"POST /api/scene HTTP/1.1\r\n\r\n", "405", ""},
      {"GET /ws HTTP/1.1\r\n\r\n", "400", ""},  // the stream without an upgrade
      {"garbage\r\n\r\n", "400", ""},
  };
  for (const auto& c : cases) {
    TestClient client(server->port());
    ASSERT_TRUE(client.connected());
    client.send(c.request);
    ASSERT_TRUE(pump(*server, {&client}, [&] { return !client.open(); })) << c.request;
    EXPECT_TRUE(contains(client.received, "HTTP/1.1 " + c.status)) << c.request << client.received;
    EXPECT_TRUE(contains(client.received, c.body)) << c.request;
  }
  TestClient js(server->port());
  js.send("GET /lib/a.js HTTP/1.1\r\n\r\n");
  ASSERT_TRUE(pump(*server, {&js}, [&] { return !js.open(); }));
  EXPECT_TRUE(contains(js.received, "Content-Type: text/javascript"));
  EXPECT_EQ(server->stats().http_requests, 4u);
  EXPECT_EQ(server->stats().http_errors, 5u);
  std::filesystem::remove_all(dir);
}

TEST(ViewServer, APageGetsTheGreetingThenEveryBroadcast) {
  auto server = make_server();
  server->set_greeting([] { return std::vector<std::string>{"{\"type\":\"hello\"}"}; });
  TestClient page(server->port());
  page.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&page}, [&] { return contains(page.received, "hello"); }));
  EXPECT_TRUE(contains(page.received, "HTTP/1.1 101"));
  EXPECT_TRUE(contains(page.received, "Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo="));
  EXPECT_EQ(server->stats().clients, 1);
  page.received.clear();
  server->broadcast("{\"type\":\"contacts\"}");
  std::string frame;
  append_text_frame("{\"type\":\"contacts\"}", &frame);
  ASSERT_TRUE(pump(*server, {&page}, [&] { return page.received == frame; }));
  // A ping is answered; a text message is counted and ignored (read-only).
  page.received.clear();
  page.send(masked(0x89, "p1"));
  page.send(masked(0x81, "{\"type\":\"command\",\"command\":\"tare\"}"));
  ASSERT_TRUE(pump(*server, {&page}, [&] { return page.received == std::string("\x8a\x02p1"); }));
  ASSERT_TRUE(pump(*server, {&page}, [&] { return server->stats().client_messages == 1; }));
  // A close is answered with a close, and the page is gone.
  page.send(masked(0x88, std::string("\x03\xe8", 2)));
  ASSERT_TRUE(pump(*server, {&page}, [&] { return !page.open(); }));
  EXPECT_EQ(server->stats().clients, 0);
}

TEST(ViewServer, APagesMessageReachesTheHandlerWhichAnswersThatPageAlone) {
  auto server = make_server();
  std::vector<std::tuple<uint64_t, std::string, bool>> got;
  server->set_message_handler([&](uint64_t page, std::string_view text, bool loopback) {
    got.emplace_back(page, std::string(text), loopback);
    server->send_to(page, "answer");
  });
  TestClient asker(server->port()), other(server->port());
  asker.send(kUpgrade);
  other.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&asker, &other}, [&] { return server->stats().clients == 2; }));
  asker.received.clear();
  other.received.clear();
  asker.send(masked(0x81, "{\"type\":\"command\"}"));
  ASSERT_TRUE(pump(*server, {&asker}, [&] { return contains(asker.received, "answer"); }));
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(std::get<1>(got[0]), "{\"type\":\"command\"}");
  EXPECT_TRUE(std::get<2>(got[0]));  // 127.0.0.1
  ASSERT_TRUE(server->poll(20).ok());
  other.read_available();
  EXPECT_FALSE(contains(other.received, "answer"));
  server->send_to(987654, "nobody");  // a page that is not there: nothing happens
}

TEST(ViewServer, FramesSentWithTheUpgradeAreRead) {
  auto server = make_server();
  TestClient page(server->port());
  page.send(kUpgrade + masked(0x89, "p1") + masked(0x81, "{}"));
  ASSERT_TRUE(pump(*server, {&page}, [&] { return contains(page.received, "\x8a\x02p1"); }));
  EXPECT_EQ(server->stats().client_messages, 1u);
  TestClient bad(server->port());
  bad.send(kUpgrade + "\x81\x02hi");  // unmasked, in the upgrade's packet
  ASSERT_TRUE(pump(*server, {&bad}, [&] { return !bad.open(); }));
  EXPECT_EQ(server->stats().protocol_errors, 1u);
}

TEST(ViewServer, BadFramesCloseThatPageOnlyAndPagesAreBounded) {
  ServerOptions options;
  options.max_clients = 2;
  auto server = make_server(options);
  TestClient good(server->port()), bad(server->port());
  good.send(kUpgrade);
  bad.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&good, &bad}, [&] { return server->stats().clients == 2; }));
  TestClient third(server->port());
  third.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&third}, [&] { return !third.open(); }));
  EXPECT_TRUE(contains(third.received, "HTTP/1.1 503"));
  EXPECT_EQ(server->stats().clients_refused, 1u);

  bad.received.clear();
  bad.send(masked(0x81, std::string(5000, 'x')));  // over max_message_bytes
  ASSERT_TRUE(pump(*server, {&bad}, [&] { return !bad.open(); }));
  EXPECT_EQ(bad.received, std::string("\x88\x02\x03\xf1", 4));  // close 1009
  EXPECT_EQ(server->stats().protocol_errors, 1u);
  good.received.clear();
  server->broadcast("still here");
  ASSERT_TRUE(pump(*server, {&good}, [&] { return contains(good.received, "still here"); }));
  EXPECT_EQ(server->stats().clients, 1);

  TestClient binary(server->port());
  binary.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&binary}, [&] { return server->stats().clients == 2; }));
  binary.received.clear();
  binary.send(masked(0x82, "\x01\x02"));
  ASSERT_TRUE(pump(*server, {&binary}, [&] { return !binary.open(); }));
  EXPECT_EQ(binary.received, std::string("\x88\x02\x03\xeb", 4));  // close 1003
}

TEST(ViewServer, APageThatDoesNotReadIsDroppedAtItsBacklog) {
  ServerOptions options;
  options.max_backlog_bytes = 256 * 1024;
  auto server = make_server(options);
  TestClient reader(server->port()), sleeper(server->port());
  reader.send(kUpgrade);
  sleeper.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&reader, &sleeper}, [&] { return server->stats().clients == 2; }));
  const std::string message(32 * 1024, 'm');
  std::size_t read_bytes = 0;
  for (int i = 0; i < 2000 && server->stats().clients_dropped_slow == 0; ++i) {
    server->broadcast(message);
    ASSERT_TRUE(server->poll(0).ok());
    reader.read_available();  // the sleeper never reads
    read_bytes += reader.received.size();
    reader.received.clear();
  }
  EXPECT_EQ(server->stats().clients_dropped_slow, 1u);
  EXPECT_EQ(server->stats().clients, 1);
  EXPECT_GT(read_bytes, 0u);
}

TEST(ViewServer, MessagesToOnePageAreBoundedByItsBacklogToo) {
  ServerOptions options;
  options.max_backlog_bytes = 64 * 1024;
  auto server = make_server(options);
  TestClient sleeper(server->port());
  sleeper.send(kUpgrade);
  ASSERT_TRUE(pump(*server, {&sleeper}, [&] { return server->stats().clients == 1; }));
  const uint64_t page = 1;  // the first connection
  const std::string message(16 * 1024, 'm');
  int sent = 0;
  while (sent < 100 && server->send_binary_to(page, message)) ++sent;  // nothing polled: queued
  EXPECT_EQ(sent, 3);  // the fourth would pass 64 KiB
  EXPECT_EQ(server->stats().clients_dropped_slow, 1u);
  EXPECT_FALSE(server->send_to(page, "gone"));
  ASSERT_TRUE(pump(*server, {&sleeper}, [&] { return server->stats().clients == 0; }));
  EXPECT_FALSE(server->send_binary_to(987654, "nobody"));
}

TEST(ViewServer, ManyPagesComingAndGoingLeaveNothingBehind) {
  auto server = make_server();
  for (int round = 0; round < 50; ++round) {
    std::vector<std::unique_ptr<TestClient>> pages;
    std::vector<TestClient*> raw;
    for (int i = 0; i < 8; ++i) {
      pages.push_back(std::make_unique<TestClient>(server->port()));
      pages.back()->send(i % 3 == 0 ? std::string("GET /ws HTTP/1.1\r\nHost") : kUpgrade);
      raw.push_back(pages.back().get());
    }
    ASSERT_TRUE(pump(*server, raw, [&] { return server->stats().clients >= 5; }));
    server->broadcast("x");
    pages.clear();  // every page leaves, some in the middle of their request
    ASSERT_TRUE(pump(*server, {}, [&] { return server->stats().clients == 0; }));
  }
  EXPECT_EQ(server->stats().clients_connected, 50u * 5u);
}

TEST(ViewServer, RefusesABadAddressAndAPortInUse) {
  ServerOptions options;
  options.bind_address = "localhost";
  auto bad = Server::create(options);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, ErrorCode::kInvalidArgument);
  auto first = make_server();
  options.bind_address = "127.0.0.1";
  options.port = first->port();
  auto taken = Server::create(options);
  ASSERT_FALSE(taken.ok());
  EXPECT_EQ(taken.error().code, ErrorCode::kIo);
}

}  // namespace
}  // namespace skinbus::view
