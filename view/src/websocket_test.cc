#include "skinbus/view/websocket.h"

#include <gtest/gtest.h>

#include <random>

#include "skinbus/common/test_seed.h"

namespace skinbus::view {
namespace {

std::vector<uint8_t> bytes(std::initializer_list<int> list) {
  std::vector<uint8_t> out;
  for (int b : list) out.push_back(static_cast<uint8_t>(b));
  return out;
}

// A client frame as a browser sends it: masked with `mask`.
std::vector<uint8_t> client_frame(uint8_t first_byte, const std::string& payload,
                                  const uint8_t mask[4]) {
  std::vector<uint8_t> f{first_byte};
  const std::size_t n = payload.size();
  if (n < 126) {
    f.push_back(static_cast<uint8_t>(0x80 | n));
  } else if (n <= 0xffff) {
    f.insert(f.end(), {0x80 | 126, static_cast<uint8_t>(n >> 8), static_cast<uint8_t>(n)});
  } else {
    f.push_back(0x80 | 127);
    for (int s = 56; s >= 0; s -= 8) f.push_back(static_cast<uint8_t>(uint64_t{n} >> s));
  }
  f.insert(f.end(), mask, mask + 4);
  for (std::size_t i = 0; i < n; ++i) f.push_back(static_cast<uint8_t>(payload[i]) ^ mask[i % 4]);
  return f;
}

TEST(WebSocket, AcceptKeyIsTheRfcExample) {
  // RFC 6455 section 1.3.
  EXPECT_EQ(websocket_accept_key("dGhlIHNhbXBsZSBub25jZQ=="), "s3pPLMBiTxaQ9kYGzzhZRbK+xOo=");
}

TEST(WebSocket, Sha1AndBase64MatchTheirStandardsVectors) {
  // FIPS 180 "abc" and the two-block message; RFC 4648 section 10.
  EXPECT_EQ(base64(sha1("abc")), base64(std::string("\xa9\x99\x3e\x36\x47\x06\x81\x6a\xba\x3e"
                                                    "\x25\x71\x78\x50\xc2\x6c\x9c\xd0\xd8\x9d",
                                                    20)));
  EXPECT_EQ(base64(sha1("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq")),
            base64(std::string("\x84\x98\x3e\x44\x1c\x3b\xd2\x6e\xba\xae\x4a\xa1\xf9\x51\x29\xe5"
                               "\xe5\x46\x70\xf1",
                               20)));
  EXPECT_EQ(base64(""), "");
  EXPECT_EQ(base64("f"), "Zg==");
  EXPECT_EQ(base64("fo"), "Zm8=");
  EXPECT_EQ(base64("foo"), "Zm9v");
  EXPECT_EQ(base64("foobar"), "Zm9vYmFy");
}

TEST(WebSocket, ServerFramesAreTheRfcExamples) {
  std::string out;
  append_text_frame("Hello", &out);  // RFC 6455 section 5.7: a single-frame unmasked text message
  EXPECT_EQ(out, std::string("\x81\x05Hello"));
  out.clear();
  append_text_frame(std::string(256, 'x'), &out);  // 16-bit length
  EXPECT_EQ(out.substr(0, 4), std::string("\x81\x7e\x01\x00", 4));
  out.clear();
  append_text_frame(std::string(65536, 'x'), &out);  // 64-bit length
  EXPECT_EQ(out.substr(0, 10), std::string("\x81\x7f\x00\x00\x00\x00\x00\x01\x00\x00", 10));
  out.clear();
  append_close_frame(kCloseTooBig, &out);
  EXPECT_EQ(out, std::string("\x88\x02\x03\xf1", 4));
}

TEST(WebSocket, ReadsTheRfcMaskedHello) {
  FrameReader r(4096);
  // RFC 6455 section 5.7: a single-frame masked text message.
  r.feed(bytes({0x81, 0x85, 0x37, 0xfa, 0x21, 0x3d, 0x7f, 0x9f, 0x4d, 0x51, 0x58}));
  ClientFrame f;
  ASSERT_EQ(r.next(&f), FrameReader::Step::kFrame);
  EXPECT_EQ(f.kind, ClientFrame::Kind::kText);
  EXPECT_EQ(f.payload, "Hello");
  EXPECT_EQ(r.next(&f), FrameReader::Step::kNeedMore);
}

TEST(WebSocket, RandomFramesInRandomPiecesRoundTrip) {
  std::mt19937_64 rng(test_seed("RandomFramesInRandomPiecesRoundTrip"));
  for (int round = 0; round < 200; ++round) {
    std::vector<uint8_t> stream;
    std::vector<std::string> sent;
    const int messages = 1 + static_cast<int>(rng() % 6);
    for (int m = 0; m < messages; ++m) {
      const std::size_t n = std::vector<std::size_t>{0, 1, 125, 126, 127, 1000, 4096}[rng() % 7];
      std::string payload(n, '\0');
      for (auto& c : payload) c = static_cast<char>(rng());
      const uint8_t mask[4] = {static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng()),
                               static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng())};
      if (n > 2 && rng() % 2) {  // in two fragments, a ping between them
        const std::size_t cut = 1 + rng() % (n - 1);
        auto a = client_frame(0x01, payload.substr(0, cut), mask);
        auto ping = client_frame(0x89, "p", mask);
        auto b = client_frame(0x80, payload.substr(cut), mask);
        stream.insert(stream.end(), a.begin(), a.end());
        stream.insert(stream.end(), ping.begin(), ping.end());
        stream.insert(stream.end(), b.begin(), b.end());
        sent.push_back("\x89p");
      } else {
        auto f = client_frame(0x81, payload, mask);
        stream.insert(stream.end(), f.begin(), f.end());
      }
      sent.push_back(payload);
    }
    FrameReader r(4096);
    std::vector<std::string> got;
    std::size_t at = 0;
    while (at < stream.size()) {
      const std::size_t piece = std::min<std::size_t>(stream.size() - at, 1 + rng() % 700);
      r.feed({stream.data() + at, piece});
      at += piece;
      ClientFrame f;
      FrameReader::Step step;
      while ((step = r.next(&f)) == FrameReader::Step::kFrame) {
        got.push_back(f.kind == ClientFrame::Kind::kPing ? "\x89" + f.payload : f.payload);
      }
      ASSERT_EQ(step, FrameReader::Step::kNeedMore) << "round " << round;
    }
    EXPECT_EQ(got, sent) << "round " << round;
    EXPECT_EQ(r.buffered_bytes(), 0u);
  }
}

TEST(WebSocket, ProtocolViolationsCloseWithTheirCodes) {
  const uint8_t mask[4] = {1, 2, 3, 4};
  struct Case {
    const char* what;
    std::vector<uint8_t> frame;
    uint16_t code;
  };
  std::vector<Case> cases = {
      {"unmasked", bytes({0x81, 0x02, 'h', 'i'}), kCloseProtocolError},
      {"reserved bit", client_frame(0xC1, "hi", mask), kCloseProtocolError},
      {"unknown opcode", client_frame(0x83, "hi", mask), kCloseProtocolError},
      {"over the bound", client_frame(0x81, std::string(4097, 'x'), mask), kCloseTooBig},
      {"a 2^63-byte length", bytes({0x81, 0xff, 0x7f, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff}),
       kCloseTooBig},
      {"a fragmented ping", client_frame(0x09, "p", mask), kCloseProtocolError},
      {"a continuation with nothing to continue", client_frame(0x80, "x", mask),
       kCloseProtocolError},
  };
  auto big_ping = client_frame(0x89, std::string(126, 'p'), mask);
  cases.push_back({"a control frame over 125 bytes", big_ping, kCloseProtocolError});
  auto first = client_frame(0x01, std::string(3000, 'a'), mask);
  auto second = client_frame(0x80, std::string(3000, 'b'), mask);
  first.insert(first.end(), second.begin(), second.end());
  cases.push_back({"fragments adding up over the bound", first, kCloseTooBig});
  for (const auto& c : cases) {
    FrameReader r(4096);
    r.feed(c.frame);
    ClientFrame f;
    EXPECT_EQ(r.next(&f), FrameReader::Step::kError) << c.what;
    EXPECT_EQ(r.close_code(), c.code) << c.what;
    r.feed(client_frame(0x81, "after", mask));  // nothing is read after a violation
    EXPECT_EQ(r.next(&f), FrameReader::Step::kError) << c.what;
    EXPECT_EQ(r.buffered_bytes(), 0u) << c.what;
  }
}

TEST(WebSocketSubprotocol, AnOfferNamesItExactlyAmongOthers) {
  EXPECT_TRUE(offers_subprotocol("foxglove.websocket.v1", "foxglove.websocket.v1"));
  EXPECT_TRUE(offers_subprotocol("chat ,  foxglove.websocket.v1 ", "foxglove.websocket.v1"));
  EXPECT_FALSE(offers_subprotocol("foxglove.websocket.v10", "foxglove.websocket.v1"));
  EXPECT_FALSE(offers_subprotocol("", "foxglove.websocket.v1"));
  EXPECT_FALSE(offers_subprotocol(",,", ""));
  std::string frame;
  append_binary_frame(std::string("\x01\x00", 2), &frame);
  EXPECT_EQ(frame, std::string("\x82\x02\x01\x00", 4));
}

}  // namespace
}  // namespace skinbus::view
