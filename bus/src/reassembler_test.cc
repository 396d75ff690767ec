#include "skinbus/bus/reassembler.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <random>
#include <set>

#include "testing.h"

namespace skinbus::bus {
namespace {

using testing::encode_frames;
using testing::random_message;

TEST(ReassemblerTest, InOrderFdAndClassic) {
  std::mt19937_64 rng(1);
  for (FrameKind kind : {FrameKind::kFd, FrameKind::kClassic}) {
    Reassembler r;
    const Message m = random_message(rng, MessageClass::kSample, kind, 7, 0);
    const auto frames = encode_frames(m);
    for (std::size_t i = 0; i < frames.size(); ++i) {
      const FeedResult res = r.feed(frames[i], 1000 + i);
      if (i + 1 < frames.size()) {
        EXPECT_EQ(res.status, FeedStatus::kPending);
      } else {
        ASSERT_EQ(res.status, FeedStatus::kMessage);
        EXPECT_EQ(*res.message, m);
      }
    }
    EXPECT_EQ(r.stats().samples, 1u);
    EXPECT_EQ(r.slots_in_use(), 0u);
  }
}

TEST(ReassemblerTest, CountsGapsReordersAndDuplicates) {
  std::mt19937_64 rng(2);
  Reassembler r;
  auto send = [&](uint8_t seq, uint64_t t) {
    FeedResult last;
    for (const CanFrame& f :
         encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, seq))) {
      last = r.feed(f, t);
    }
    return last;
  };
  EXPECT_EQ(send(10, 0).status, FeedStatus::kMessage);
  const FeedResult gap = send(14, 100);
  EXPECT_EQ(gap.status, FeedStatus::kMessage);
  EXPECT_EQ(gap.missing_before, 0u);  // 11-13 may only be late: not lost within the timeout
  EXPECT_EQ(r.stats().gaps, 0u);
  EXPECT_EQ(send(12, 200).status, FeedStatus::kMessage);  // late, still delivered
  EXPECT_EQ(r.stats().reorders, 1u);

  const Message m = random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, 15);
  const auto frames = encode_frames(m);
  EXPECT_EQ(r.feed(frames[1], 300).status, FeedStatus::kPending);
  EXPECT_EQ(r.feed(frames[1], 301).status, FeedStatus::kDuplicate);
  EXPECT_EQ(r.feed(frames[0], 302).status, FeedStatus::kMessage);
  EXPECT_EQ(r.stats().reorders, 2u);  // part 0 after part 1
  // The whole message again, or one part of it: recognised by its bytes, not emitted twice.
  EXPECT_EQ(r.feed(frames[0], 400).status, FeedStatus::kDuplicate);
  EXPECT_EQ(r.feed(frames[1], 401).status, FeedStatus::kDuplicate);
  EXPECT_EQ(r.stats().duplicates, 3u);
  EXPECT_EQ(r.stats().stale_parts, 0u);
  EXPECT_EQ(r.slots_in_use(), 0u);
  EXPECT_EQ(r.stats().samples, 4u);
  // 11 and 13 never came: lost once the timeout passed, reported with the sender's next message.
  EXPECT_EQ(r.stats().gaps, 0u);
  const FeedResult next = send(16, 100 + 50001);
  EXPECT_EQ(next.missing_before, 2u);
  EXPECT_EQ(r.stats().gaps, 2u);
}

// Reordering within the reassembly window is not loss: a swapped pair, and a log whose lines were
// shuffled (times going backwards), lose nothing; a real loss is still counted once.
TEST(ReassemblerTest, ReorderingWithinTheWindowIsNotLoss) {
  std::mt19937_64 rng(5);
  Reassembler r;
  uint32_t reported = 0;
  auto send = [&](uint8_t seq, uint64_t t) {
    for (const CanFrame& f :
         encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kFd, 4, seq))) {
      const FeedResult res = r.feed(f, t);
      if (res.status == FeedStatus::kMessage) reported += res.missing_before;
    }
  };
  // 0 1 3 2 4 5 ... at 41.7 Hz, with the swapped pair's times swapped too (a shuffled log).
  std::vector<int> order;
  for (int s = 0; s < 200; ++s) order.push_back(s);
  for (int s = 3; s + 1 < 200; s += 10) std::swap(order[s], order[s + 1]);
  for (int s : order) send(static_cast<uint8_t>(s), 1000000 + static_cast<uint64_t>(s) * 24000);
  r.expire(1000000 + 300 * 24000);
  EXPECT_EQ(r.stats().gaps, 0u);
  EXPECT_EQ(reported, 0u);
  EXPECT_EQ(r.stats().resyncs, 0u);
  EXPECT_EQ(r.stats().reorders, 20u);
  // Two messages really lost in the middle of the next stretch: counted once, after the timeout.
  for (int s = 200; s < 260; ++s) {
    if (s == 230 || s == 231) continue;
    send(static_cast<uint8_t>(s), 1000000 + static_cast<uint64_t>(s) * 24000);
  }
  EXPECT_EQ(r.stats().gaps, 2u);
  EXPECT_EQ(reported, 2u);
  // The end of a stream: a gap confirmed by expire() alone is handed over on request.
  send(static_cast<uint8_t>(262), 1000000 + 262 * 24000);
  r.expire(1000000 + 400 * 24000);
  EXPECT_EQ(r.stats().gaps, 4u);
  EXPECT_EQ(r.take_unreported_losses(MessageClass::kSample, 4), 2u);
  EXPECT_EQ(r.take_unreported_losses(MessageClass::kSample, 4), 0u);
}

// After a silence, a sequence that looks "behind" is a restart or a loss of 128+ messages,
// not a late message: the gap is counted forward and later messages are not reorders.
TEST(ReassemblerTest, LongLossAndRestartResynchronise) {
  std::mt19937_64 rng(11);
  Reassembler r;
  uint64_t t = 0;
  auto send = [&](uint8_t seq) {
    FeedResult last;
    for (const CanFrame& f :
         encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, seq))) {
      last = r.feed(f, t);
    }
    t += 24000;  // 41.7 Hz
    return last;
  };
  int s = 0;
  for (; s < 10; ++s) send(static_cast<uint8_t>(s));
  t += 200 * 24000;  // 200 samples lost
  s += 200;
  const FeedResult after = send(static_cast<uint8_t>(s++));
  EXPECT_EQ(after.missing_before, 200u);
  for (int k = 0; k < 20; ++k) send(static_cast<uint8_t>(s++));
  EXPECT_EQ(r.stats().gaps, 200u);
  EXPECT_EQ(r.stats().reorders, 0u);
  EXPECT_EQ(r.stats().resyncs, 1u);
  // A reboot: sequence 0 again after a second of silence, and a second one right after 100
  // messages, whose 0 lies "behind": delivered either way, never a reorder.
  t += 1000000;
  EXPECT_EQ(send(0).status, FeedStatus::kMessage);
  for (int k = 1; k < 100; ++k) send(static_cast<uint8_t>(k));
  t += 1000000;
  EXPECT_EQ(send(0).status, FeedStatus::kMessage);
  EXPECT_EQ(send(1).status, FeedStatus::kMessage);
  EXPECT_EQ(r.stats().reorders, 0u);
  EXPECT_EQ(r.stats().resyncs, 2u);
}

// A restarted node sends the same first heartbeats as at its last start (same sequence, same
// content). Its uptime going backwards marks the restart: nothing of the new start is taken for
// a duplicate or a gap.
TEST(ReassemblerTest, RestartIsRecognisedByTheHeartbeatUptime) {
  Reassembler r;
  uint64_t t = 1000;
  auto send = [&](const Message& m) {
    std::array<CanFrame, kMaxParts> frames;
    const EncodeResult e = encode(m, frames);
    FeedResult last;
    for (std::size_t i = 0; i < e.frames; ++i) last = r.feed(frames[i], t += 100);
    return last;
  };
  auto boot = [&](int seconds) {
    int emitted = 0;
    for (int s = 0; s < seconds; ++s) {
      Heartbeat hb;
      hb.uptime_s = static_cast<uint32_t>(s);
      hb.hardware_uid = 42;
      emitted += send(Message{9, static_cast<uint8_t>(s), FrameKind::kFd, hb}).status ==
                 FeedStatus::kMessage;
      for (int k = 0; k < 5; ++k) {
        Sample smp;
        smp.timestamp_us = static_cast<uint32_t>(s * 1000 + k);
        emitted += send(Message{9, static_cast<uint8_t>(5 * s + k), FrameKind::kFd, smp}).status ==
                   FeedStatus::kMessage;
      }
      t += 1000000;
    }
    return emitted;
  };
  EXPECT_EQ(boot(4), 24);
  EXPECT_EQ(boot(3), 18);  // restarted after 4 s: heartbeats 0..2 again, identical
  EXPECT_EQ(r.stats().restarts, 1u);
  EXPECT_EQ(r.stats().duplicates, 0u);
  EXPECT_EQ(r.stats().gaps, 0u);
  // A real repeat of the last heartbeat is still a duplicate, not a restart.
  Heartbeat hb;
  hb.uptime_s = 2;
  hb.hardware_uid = 42;
  EXPECT_EQ(send(Message{9, 2, FrameKind::kFd, hb}).status, FeedStatus::kDuplicate);
  EXPECT_EQ(r.stats().restarts, 1u);
}

TEST(ReassemblerTest, StalePartsTimeOut) {
  std::mt19937_64 rng(3);
  Reassembler r(Reassembler::Config{8, 50000});
  const auto frames =
      encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kClassic, 3, 1));
  for (std::size_t i = 0; i + 1 < frames.size(); ++i) r.feed(frames[i], 0);
  EXPECT_EQ(r.slots_in_use(), 1u);
  r.expire(50001);
  EXPECT_EQ(r.slots_in_use(), 0u);
  EXPECT_EQ(r.stats().stale_parts, frames.size() - 1);
  // The last part alone, after the timeout, never completes a message.
  EXPECT_EQ(r.feed(frames.back(), 50002).status, FeedStatus::kPending);
  EXPECT_EQ(r.stats().samples, 0u);
}

TEST(ReassemblerTest, MixedUpPartsAreCaughtByTheCrc) {
  std::mt19937_64 rng(4);
  Reassembler r;
  // Two different samples sent with the same node and sequence number: part 0 of one and part 1
  // of the other reassemble to a payload whose CRC cannot match.
  const auto a = encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, 5));
  const auto b = encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, 5));
  EXPECT_EQ(r.feed(a[0], 0).status, FeedStatus::kPending);
  const FeedResult res = r.feed(b[1], 1);
  EXPECT_EQ(res.status, FeedStatus::kIntegrityFailure);
  EXPECT_EQ(res.error, DecodeError::kBadCrc);
  EXPECT_EQ(r.stats().integrity_failures, 1u);
  EXPECT_EQ(r.stats().messages, 0u);
}

TEST(ReassemblerTest, ConflictingPartDropsTheMessage) {
  std::mt19937_64 rng(5);
  Reassembler r;
  const auto a =
      encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kClassic, 3, 5));
  const auto b =
      encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kClassic, 3, 5));
  r.feed(a[0], 0);
  EXPECT_EQ(r.feed(b[0], 1).status, FeedStatus::kIntegrityFailure);
  EXPECT_EQ(r.stats().conflicts, 1u);
  EXPECT_EQ(r.slots_in_use(), 0u);
}

TEST(ReassemblerTest, BoundedSlotsEvictTheOldest) {
  std::mt19937_64 rng(6);
  Reassembler r(Reassembler::Config{4, 1000000});
  for (uint8_t node = 1; node <= 6; ++node) {
    r.feed(encode_frames(random_message(rng, MessageClass::kSample, FrameKind::kFd, node, 0))[0],
           node);
  }
  EXPECT_EQ(r.slots_in_use(), 4u);
  EXPECT_EQ(r.stats().evictions, 2u);
  EXPECT_EQ(r.stats().stale_parts, 2u);
}

TEST(ReassemblerTest, RestartedSenderIsNotADuplicate) {
  std::mt19937_64 rng(7);
  Reassembler r;
  auto send = [&](const Message& m, uint64_t t) {
    FeedResult last;
    for (const CanFrame& f : encode_frames(m)) last = r.feed(f, t);
    return last.status;
  };
  for (uint8_t s = 0; s < 5; ++s)
    send(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, s), s);
  // The node reboots and starts again at sequence 0 with new content.
  EXPECT_EQ(send(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, 0), 10),
            FeedStatus::kMessage);
  EXPECT_EQ(send(random_message(rng, MessageClass::kSample, FrameKind::kFd, 3, 1), 11),
            FeedStatus::kMessage);
}

// The property the protocol promises: frames shuffled (within a window), dropped and duplicated;
// every message all of whose frames arrived in time is emitted exactly once and intact, and
// nothing else is emitted.
TEST(ReassemblerTest, RandomShuffleDropDuplicate) {
  const uint64_t seed = testing::test_seed("ReassemblerTest.RandomShuffleDropDuplicate");
  std::mt19937_64 rng(seed);
  for (int round = 0; round < 40; ++round) {
    const FrameKind kind = round % 2 ? FrameKind::kFd : FrameKind::kClassic;
    const double drop_p = (round % 4) * 0.02;
    const double dup_p = (round % 3) * 0.05;
    const int window = 1 + static_cast<int>(rng() % 24);
    // Every third round corrupts one byte of one part of some multi-part messages: the CRC must
    // catch each.
    const double corrupt_p = round % 3 == 2 ? 0.03 : 0.0;

    struct Tx {
      CanFrame frame;
      int msg;
    };
    std::vector<Message> sent;
    std::vector<Tx> wire;
    std::map<uint64_t, uint8_t> next_seq;
    for (int i = 0; i < 300; ++i) {
      const auto c = static_cast<MessageClass>(rng() % kMessageClassCount);
      const auto node = static_cast<uint8_t>(1 + rng() % 8);
      // One sequence counter per real sender: every SYNC comes from the host (node 127).
      const uint64_t key =
          static_cast<uint64_t>(c) << 8 | (c == MessageClass::kSync ? kNodeBroadcast : node);
      const Message m = random_message(rng, c, kind, node, next_seq[key]++);
      sent.push_back(m);
      for (const CanFrame& f : encode_frames(m)) wire.push_back({f, i});
    }
    // Shuffle within a sliding window, then drop and duplicate.
    for (std::size_t i = 0; i < wire.size(); ++i) {
      const std::size_t j = std::min(wire.size() - 1, i + rng() % window);
      std::swap(wire[i], wire[j]);
    }
    std::vector<Tx> rx;
    std::set<int> corrupted;
    std::uniform_real_distribution<double> p(0, 1);
    for (const Tx& t : wire) {
      if (p(rng) < drop_p) continue;
      rx.push_back(t);
      if (p(rng) < dup_p) rx.push_back(t);
      // At most one corrupted part a message: CRC-16 catches every error burst of up to 16 bits,
      // but two corrupted bytes in different parts slip through one time in 65536.
      if (corrupt_p > 0 && is_multi_part(sent[t.msg].message_class()) && !corrupted.count(t.msg) &&
          p(rng) < corrupt_p) {
        CanFrame& f = rx.back().frame;
        const std::size_t parts = part_count(sent[t.msg].message_class(), kind);
        const std::size_t part = f.data[0] & 0x1F;
        const std::size_t carried = std::min(
            part_len(kind), payload_len(sent[t.msg].message_class()) - part * part_len(kind));
        f.data[kHeaderLen + rng() % carried] ^= static_cast<uint8_t>(1 + rng() % 255);
        corrupted.insert(t.msg);
        (void)parts;
      }
    }
    std::map<int, int> frames_arrived;
    {
      std::set<std::pair<int, int>> seen_parts;
      for (const Tx& t : rx) {
        if (seen_parts.insert({t.msg, t.frame.data[0] & 0x1F}).second) ++frames_arrived[t.msg];
      }
    }

    Reassembler r(Reassembler::Config{64, 1000000});
    std::map<int, int> emitted;
    uint64_t t_us = 0;
    for (const Tx& t : rx) {
      const FeedResult res = r.feed(t.frame, t_us += 10);
      ASSERT_NE(res.status, FeedStatus::kRejected);
      if (corrupt_p == 0) {
        ASSERT_NE(res.status, FeedStatus::kIntegrityFailure)
            << "seed " << seed << " round " << round;
      }
      if (res.status != FeedStatus::kMessage) continue;
      // Find which sent message this is: it must equal one exactly.
      const Message& got = *res.message;
      bool matched = false;
      for (int i = 0; i < static_cast<int>(sent.size()); ++i) {
        if (sent[i] == got) {
          ++emitted[i];
          matched = true;
          break;
        }
      }
      ASSERT_TRUE(matched) << "emitted a message that was never sent; seed " << seed;
    }
    for (int i = 0; i < static_cast<int>(sent.size()); ++i) {
      const int needed = static_cast<int>(part_count(sent[i].message_class(), kind));
      if (corrupted.count(i)) {
        EXPECT_LE(emitted[i], 1) << "seed " << seed;  // only its clean copy could complete it
      } else if (frames_arrived[i] == needed) {
        EXPECT_EQ(emitted[i], 1) << "message " << i << " complete but emitted " << emitted[i]
                                 << " times; seed " << seed << " round " << round;
      } else {
        EXPECT_EQ(emitted[i], 0) << "incomplete message emitted; seed " << seed;
      }
    }
    // The statistics agree with what happened.
    int total = 0;
    for (const auto& [i, n] : emitted) total += n;
    EXPECT_EQ(r.stats().messages, static_cast<uint64_t>(total));
    EXPECT_EQ(r.stats().frames, rx.size());
    // A corrupted message whose every part arrived but that was never emitted was stopped by a
    // check, and the check counted it. (A corrupted part of a message that misses other parts
    // just waits in its slot, and one that arrives after its clean twin completed the message
    // is a late duplicate: neither is counted here.)
    bool stopped = false;
    for (int i : corrupted) {
      const int needed = static_cast<int>(part_count(sent[i].message_class(), kind));
      stopped = stopped || (frames_arrived[i] == needed && emitted[i] == 0);
    }
    if (stopped) {
      EXPECT_GT(r.stats().integrity_failures + r.stats().conflicts + r.stats().stale_parts, 0u)
          << "seed " << seed << " round " << round;
    }
  }
}

TEST(ReassemblerTest, ForeignAndMalformedAreCountedNotFatal) {
  Reassembler r;
  CanFrame ext;
  ext.extended = true;
  ext.id = 0x1F334455;
  ext.len = 2;
  EXPECT_EQ(r.feed(ext, 0).error, DecodeError::kForeign);
  CanFrame junk;
  junk.id = 0x185;
  junk.len = 1;
  EXPECT_EQ(r.feed(junk, 1).error, DecodeError::kBadLength);
  EXPECT_EQ(r.stats().foreign, 1u);
  EXPECT_EQ(r.stats().rejected, 1u);
  EXPECT_EQ(r.stats().by_error[static_cast<int>(DecodeError::kBadLength)], 1u);
}

}  // namespace
}  // namespace skinbus::bus
