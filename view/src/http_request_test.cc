#include "skinbus/view/http_request.h"

#include <gtest/gtest.h>

namespace skinbus::view {
namespace {

TEST(HttpRequest, ParsesABrowsersUpgrade) {
  const std::string head =
      "GET /ws?x=1 HTTP/1.1\r\nHost: localhost:8080\r\nUpgrade: websocket\r\n"
      "Connection: keep-alive, Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
      "Sec-WebSocket-Version: 13\r\n\r\n";
  auto length = request_head_length(head + "trailing");
  ASSERT_TRUE(length.ok());
  EXPECT_EQ(*length, head.size());
  auto r = parse_request_head(head);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  EXPECT_EQ(r->method, "GET");
  EXPECT_EQ(r->path, "/ws");
  EXPECT_EQ(r->query, "x=1");
  EXPECT_EQ(r->header("host"), "localhost:8080");
  EXPECT_TRUE(r->is_websocket_upgrade());
}

TEST(HttpRequest, AHeadWithoutItsBlankLineIsNotYetComplete) {
  auto length = request_head_length("GET / HTTP/1.1\r\nHost: x\r\n");
  ASSERT_TRUE(length.ok());
  EXPECT_EQ(*length, 0u);
  auto too_long = request_head_length(std::string(kMaxRequestHeadBytes, 'a'));
  ASSERT_FALSE(too_long.ok());
  EXPECT_EQ(too_long.error().code, ErrorCode::kOutOfRange);
}

TEST(HttpRequest, RefusesPathsThatCouldLeaveTheServedFolders) {
  for (const char* path :
       {"/../etc/passwd", "/node_modules/..%2f..", "/a\\b", "relative", "/%2e%2e/x"}) {
    auto r = parse_request_head(std::string("GET ") + path + " HTTP/1.1\r\n\r\n");
    ASSERT_FALSE(r.ok()) << path;
    EXPECT_EQ(r.error().code, ErrorCode::kParse) << path;
  }
}

TEST(HttpRequest, RefusesMalformedHeads) {
  for (const char* head : {"GET /\r\n\r\n", "GET / HTTP/2\r\n\r\n", "get / HTTP/1.1\r\n\r\n",
                           "GET  / HTTP/1.1\r\n\r\n", "GET / HTTP/1.1\r\nNoColon\r\n\r\n",
                           "GET / HTTP/1.1\r\n: v\r\n\r\n", "GET / HTTP/1.1\r\nA B: v\r\n\r\n",
                           "GET /\x01 HTTP/1.1\r\n\r\n"}) {
    EXPECT_FALSE(parse_request_head(head).ok()) << head;
  }
  auto r = parse_request_head("GET / HTTP/1.1\r\nUpgrade: websocket\r\n\r\n");
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->is_websocket_upgrade());  // no Connection: upgrade, no key
}

}  // namespace
}  // namespace skinbus::view
