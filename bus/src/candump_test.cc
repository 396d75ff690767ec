#include "skinbus/bus/candump.h"

#include <gtest/gtest.h>

#include <cerrno>

#include <cstdio>
#include <random>
#include <string>

#include "testing.h"

namespace skinbus::bus {
namespace {

TEST(CandumpTest, ParsesEveryFrameForm) {
  CandumpRecord r;
  ASSERT_EQ(parse_candump_line("(1436509052.249713) vcan0 044#2A366C2BBA\n", &r),
            CandumpError::kNone);
  EXPECT_EQ(r.timestamp_us, 1436509052249713ull);
  EXPECT_EQ(r.iface, "vcan0");
  EXPECT_EQ(r.frame.id, 0x044u);
  EXPECT_FALSE(r.frame.extended);
  EXPECT_FALSE(r.frame.fd);
  EXPECT_EQ(r.frame.len, 5);
  EXPECT_EQ(r.frame.data[4], 0xBA);

  ASSERT_EQ(parse_candump_line("(0000000001.000001) can1 1F334455#0102", &r), CandumpError::kNone);
  EXPECT_TRUE(r.frame.extended);
  EXPECT_EQ(r.frame.id, 0x1F334455u);
  EXPECT_EQ(r.timestamp_us, 1000001u);

  ASSERT_EQ(parse_candump_line("(1.5) can0 5A1##100112233445566778899AABBCCDDEEFF00112233", &r),
            CandumpError::kNone);
  EXPECT_TRUE(r.frame.fd);
  EXPECT_TRUE(r.frame.brs);
  EXPECT_FALSE(r.frame.esi);
  EXPECT_EQ(r.frame.len, 20);
  EXPECT_EQ(r.timestamp_us, 1500000u);

  ASSERT_EQ(parse_candump_line("(1.000000) can0 5A1##3", &r), CandumpError::kNone);
  EXPECT_TRUE(r.frame.esi);
  EXPECT_EQ(r.frame.len, 0);

  ASSERT_EQ(parse_candump_line("(1.000000) can0 123#R", &r), CandumpError::kNone);
  EXPECT_TRUE(r.frame.rtr);
  ASSERT_EQ(parse_candump_line("(1.000000) can0 123#R3", &r), CandumpError::kNone);
  EXPECT_EQ(r.frame.len, 3);

  ASSERT_EQ(parse_candump_line("(1.000000) can0 20000004#0004000000000000", &r),
            CandumpError::kNone);
  EXPECT_TRUE(r.frame.error);
  EXPECT_EQ(r.frame.id, 0x4u);

  ASSERT_EQ(parse_candump_line("(1.000000) can0 123#1122334455667788_9", &r), CandumpError::kNone);
  EXPECT_EQ(r.frame.len, 8);
  ASSERT_EQ(parse_candump_line("(1.000000) can0 123#11 R", &r), CandumpError::kNone);  // candump -x
}

TEST(CandumpTest, RejectsWithAReason) {
  CandumpRecord r;
  EXPECT_EQ(parse_candump_line("", &r), CandumpError::kEmpty);
  EXPECT_EQ(parse_candump_line("   # comment", &r), CandumpError::kEmpty);
  EXPECT_EQ(parse_candump_line("1436509052.249713 vcan0 044#2A", &r), CandumpError::kBadTimestamp);
  EXPECT_EQ(parse_candump_line("(14365x9052.249713) vcan0 044#2A", &r),
            CandumpError::kBadTimestamp);
  EXPECT_EQ(parse_candump_line("(1.0)", &r), CandumpError::kMissingIface);
  EXPECT_EQ(parse_candump_line("(1.0) can0", &r), CandumpError::kMissingIface);
  EXPECT_EQ(parse_candump_line("(1.0) can0 44#2A", &r), CandumpError::kBadId);
  EXPECT_EQ(parse_candump_line("(1.0) can0 844#2A", &r), CandumpError::kBadId);  // > 0x7FF
  EXPECT_EQ(parse_candump_line("(1.0) can0 4FFFFFFF#2A", &r), CandumpError::kBadId);
  EXPECT_EQ(parse_candump_line("(1.0) can0 0442A", &r), CandumpError::kMissingHash);
  EXPECT_EQ(parse_candump_line("(1.0) can0 044#2", &r), CandumpError::kBadData);
  EXPECT_EQ(parse_candump_line("(1.0) can0 044#2G", &r), CandumpError::kBadData);
  EXPECT_EQ(parse_candump_line("(1.0) can0 044#112233445566778899", &r),
            CandumpError::kBadData);  // 9 bytes
  EXPECT_EQ(parse_candump_line("(1.0) can0 044##1112233445566778899", &r),
            CandumpError::kBadData);  // FD len 9
  EXPECT_EQ(parse_candump_line("(1.0) can0 044##", &r), CandumpError::kBadFlags);
  EXPECT_EQ(parse_candump_line("(1.0) can0 044##X00", &r), CandumpError::kBadFlags);
  EXPECT_EQ(parse_candump_line("(1.0) can0 044###00", &r), CandumpError::kUnsupported);
  EXPECT_EQ(parse_candump_line("(1.0) can0 044#11 extra words", &r), CandumpError::kBadData);
}

TEST(CandumpTest, FormatsLikeCandump) {
  CanFrame f;
  ASSERT_EQ(parse_frame_text("185##1202A", &f), CandumpError::kNone);
  EXPECT_EQ(format_candump_line(f, 1436509052249713ull, "can0"),
            "(1436509052.249713) can0 185##1202A");
  ASSERT_EQ(parse_frame_text("1F334455#DE.AD.BE.EF", &f), CandumpError::kNone);
  EXPECT_EQ(format_candump_line(f, 1000001, "vcan0"),
            "(0000000001.000001) vcan0 1F334455#DEADBEEF");
  ASSERT_EQ(parse_frame_text("123#R", &f), CandumpError::kNone);
  EXPECT_EQ(format_candump_line(f, 0, "x"), "(0000000000.000000) x 123#R");
}

TEST(CandumpTest, RandomRoundTrip) {
  std::mt19937_64 rng(testing::test_seed("CandumpTest.RandomRoundTrip"));
  for (int i = 0; i < 20000; ++i) {
    CanFrame f;
    const int kind = static_cast<int>(rng() % 4);
    f.extended = kind == 1;
    f.fd = kind == 2;
    f.error = kind == 3;
    f.id = static_cast<uint32_t>(
        rng() & (f.extended || f.error ? kExtendedIdMask & ~kCanErrFlag : kStandardIdMask));
    if (f.fd) {
      f.brs = rng() % 2;
      f.esi = rng() % 2;
      static constexpr uint8_t kLens[] = {0, 1, 5, 8, 12, 16, 20, 24, 32, 48, 64};
      f.len = kLens[rng() % std::size(kLens)];
    } else {
      f.len = static_cast<uint8_t>(rng() % 9);
    }
    for (std::size_t b = 0; b < f.len; ++b) f.data[b] = static_cast<uint8_t>(rng());
    const uint64_t ts = rng() % 4000000000000000ull;
    const std::string line = format_candump_line(f, ts, "can0");
    CandumpRecord r;
    ASSERT_EQ(parse_candump_line(line, &r), CandumpError::kNone) << line;
    EXPECT_EQ(r.frame, f) << line;
    EXPECT_EQ(r.timestamp_us, ts);
  }
}

TEST(CandumpTest, ReaderCountsBadLinesAndKeepsGoing) {
  const char text[] =
      "(1.000000) can0 123#11\n"
      "garbage\n"
      "\n"
      "(1.000001) can0 124#22\n"
      "(1.000002) can0 125#2\n"
      "(1.000003) can0 126#33";  // no final newline
  std::FILE* f = fmemopen(const_cast<char*>(text), sizeof text - 1, "r");
  ASSERT_NE(f, nullptr);
  CandumpReader reader(f);
  CandumpRecord r;
  std::vector<uint32_t> ids;
  std::vector<uint64_t> bad_lines;
  for (;;) {
    const auto st = reader.next(&r);
    if (st == CandumpReader::Status::kEof) break;
    if (st == CandumpReader::Status::kBadLine) {
      bad_lines.push_back(reader.line_number());
      continue;
    }
    ids.push_back(r.frame.id);
  }
  std::fclose(f);
  EXPECT_EQ(ids, (std::vector<uint32_t>{0x123, 0x124, 0x126}));
  EXPECT_EQ(bad_lines, (std::vector<uint64_t>{2, 5}));
  EXPECT_EQ(reader.bad_lines(), 2u);
  EXPECT_EQ(reader.records(), 3u);
}

TEST(CandumpTest, ReaderSkipsOverlongLinesAndCountsThem) {
  // A line of 10 MB of zeros between two good lines: one bad line with its number, nothing kept.
  std::string text = "(1.000000) can0 123#11\n";
  text += std::string(10'000'000, '0') + "\n";
  text += "(1.000001) can0 124#22\n";
  std::FILE* f = fmemopen(text.data(), text.size(), "r");
  ASSERT_NE(f, nullptr);
  CandumpReader reader(f);
  CandumpRecord r;
  ASSERT_EQ(reader.next(&r), CandumpReader::Status::kRecord);
  ASSERT_EQ(reader.next(&r), CandumpReader::Status::kBadLine);
  EXPECT_EQ(reader.error(), CandumpError::kLineTooLong);
  EXPECT_EQ(candump_error_name(reader.error()), "line_too_long");
  EXPECT_EQ(reader.line_number(), 2u);
  ASSERT_EQ(reader.next(&r), CandumpReader::Status::kRecord);
  EXPECT_EQ(r.frame.id, 0x124u);
  EXPECT_EQ(reader.line_number(), 3u);
  EXPECT_EQ(reader.next(&r), CandumpReader::Status::kEof);
  EXPECT_EQ(reader.read_error(), 0);
  std::fclose(f);
}

TEST(CandumpTest, ReaderReportsAFailedReadInsteadOfAnEmptyLog) {
  std::FILE* f = std::fopen("/", "r");  // a directory opens, and every read fails
  ASSERT_NE(f, nullptr);
  CandumpReader reader(f);
  CandumpRecord r;
  EXPECT_EQ(reader.next(&r), CandumpReader::Status::kEof);
  EXPECT_EQ(reader.read_error(), EISDIR);
  std::fclose(f);
}

}  // namespace
}  // namespace skinbus::bus
