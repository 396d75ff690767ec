// skinbus/bus/reassembler.h: frames in, whole messages out, in bounded memory.
//
// One Reassembler serves one bus (all nodes, all classes). Frames may arrive shuffled,
// duplicated, dropped or stale; a message is emitted only when all its parts are present and
// its CRC matches, so a complete message is never lost and a corrupt one never emitted.
//
// Memory: `Config::slots` slots of kMaxPayloadLen bytes each plus a fixed per-sender table,
// all allocated in the constructor. `feed` never allocates, never throws, and costs O(slots in
// use) for the slot look-up plus O(payload) when a message completes.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/protocol.h"

namespace skinbus::bus {

struct ReassemblyStats {
  uint64_t frames = 0;              // frames fed
  uint64_t messages = 0;            // valid messages emitted, all classes
  uint64_t samples = 0;             // of which samples
  uint64_t integrity_failures = 0;  // complete payloads that failed the CRC or held bad values
  uint64_t gaps = 0;                // messages lost between two emitted ones (per sender, class):
                                    // missing for longer than the timeout (a message that arrives
                                    // late within it is a reorder, not a loss)
  uint64_t duplicates = 0;          // frames carrying a part already held or already emitted
  uint64_t reorders = 0;            // parts after a later part, or messages after a later message
  uint64_t resyncs = 0;             // a sender's sequence jumped back after a silence (restart,
                                    // or 128+ messages lost): counted forward as gaps
  uint64_t restarts = 0;            // a node's heartbeat uptime went backwards: it restarted, and
                                    // its sequence history was forgotten (no gaps, no duplicates)
  uint64_t stale_parts = 0;         // parts dropped because their message timed out incomplete
  uint64_t evictions = 0;           // incomplete messages dropped because every slot was busy
  uint64_t conflicts = 0;           // a part seen twice with different bytes (message dropped)
  uint64_t rejected = 0;            // frames parse_frame refused (any reason but kForeign)
  uint64_t foreign = 0;             // frames of other protocols (extended, RTR, error frames)
  std::array<uint64_t, kDecodeErrorCount> by_error{};  // rejected + foreign, by DecodeError

  // Sums statistics (of several buses).
  ReassemblyStats& operator+=(const ReassemblyStats& o) {
    frames += o.frames;
    messages += o.messages;
    samples += o.samples;
    integrity_failures += o.integrity_failures;
    gaps += o.gaps;
    duplicates += o.duplicates;
    reorders += o.reorders;
    resyncs += o.resyncs;
    restarts += o.restarts;
    stale_parts += o.stale_parts;
    evictions += o.evictions;
    conflicts += o.conflicts;
    rejected += o.rejected;
    foreign += o.foreign;
    for (std::size_t e = 0; e < by_error.size(); ++e) by_error[e] += o.by_error[e];
    return *this;
  }
};

enum class FeedStatus : uint8_t {
  kMessage,           // `message` holds a complete, valid message
  kPending,           // part stored, message not complete yet
  kDuplicate,         // dropped: already held or already emitted
  kRejected,          // dropped: `error` says why (kForeign for other protocols)
  kIntegrityFailure,  // a message completed but failed its CRC or value checks; dropped
};

struct FeedResult {
  FeedStatus status = FeedStatus::kPending;
  DecodeError error = DecodeError::kNone;
  const Message* message = nullptr;  // valid until the next call to feed()
  // kMessage: messages of this sender+class found lost since its previous message. A gap of up to
  // Reassembler::kPendingGaps messages is held for the timeout in case they arrive late
  // (reordered frames), and reported with the first message of the sender after that; a larger
  // gap (or a resynchronisation) at once.
  uint32_t missing_before = 0;
};

class Reassembler {
 public:
  struct Config {
    std::size_t slots = 64;       // incomplete messages held at once (all senders)
    uint32_t timeout_us = 50000;  // an incomplete message older than this is dropped as stale
  };

  Reassembler() : Reassembler(Config{}) {}
  explicit Reassembler(const Config& config);

  // Feeds one frame received at `rx_time_us` (host monotonic clock; must not go backwards by
  // more than the timeout). See FeedResult.
  FeedResult feed(const CanFrame& frame, uint64_t rx_time_us);

  // Drops incomplete messages older than the timeout at `now_us`. feed() calls this as needed;
  // call it yourself when the bus goes quiet so stale parts are counted.
  void expire(uint64_t now_us);

  // Forgets every incomplete message and the per-sender sequence history (statistics stay).
  void reset();

  // Gaps of at most this many messages wait for the timeout before they count as lost.
  static constexpr std::size_t kPendingGaps = 8;

  // Messages of (class, node) found lost and not yet reported in a FeedResult (a gap confirmed by
  // expire() with no later message of that sender): returned and cleared, for a caller that
  // counts losses per sender at the end of a stream.
  uint32_t take_unreported_losses(MessageClass c, uint8_t node);

  const ReassemblyStats& stats() const { return stats_; }
  std::size_t slots_in_use() const { return in_use_; }

 private:
  struct Slot {
    bool used = false;
    MessageClass message_class = MessageClass::kSample;
    uint8_t node = 0;
    uint8_t seq = 0;
    FrameKind kind = FrameKind::kFd;
    uint8_t part_count = 0;
    uint8_t highest_part = 0;
    uint32_t have = 0;  // bit i: part i present
    uint64_t first_rx_us = 0;
    std::array<uint8_t, kMaxPayloadLen> payload{};
  };
  // Per (sender, class): the sequence history used for gap, reorder and duplicate detection.
  // A repeat is recognised by (sequence, payload CRC) among the last kRecent messages. A node
  // that restarts sends the same first heartbeats as at its last start (same sequence, same
  // content): a heartbeat whose uptime is below the node's previous one marks the restart, and
  // the node's history is forgotten before the duplicate check.
  static constexpr std::size_t kRecent = 16;
  struct Sender {
    bool valid = false;
    uint8_t last_seq = 0;
    uint8_t ring_pos = 0;
    uint64_t last_rx_us = 0;
    std::array<uint8_t, kRecent> recent_seq{};
    std::array<uint16_t, kRecent> recent_crc{};
    std::array<bool, kRecent> recent_used{};
    // Sequences missing in a small gap, each with the time after which it counts as lost.
    std::array<uint8_t, kPendingGaps> pending_seq{};
    std::array<uint64_t, kPendingGaps> pending_deadline_us{};
    uint8_t pending = 0;
    uint32_t lost_unreported = 0;  // confirmed lost, not yet in a FeedResult
    // The last multi-part message emitted, so a stray repeat of one of its parts is recognised
    // as a duplicate by its bytes (not by sequence alone).
    bool have_last = false;
    FrameKind last_kind = FrameKind::kFd;
    std::array<uint8_t, kMaxPayloadLen> last_payload{};
  };

  FeedResult complete(MessageClass c, uint8_t node, uint8_t seq, FrameKind kind,
                      const uint8_t* payload, std::size_t len, uint64_t rx_time_us);
  Slot* find_slot(MessageClass c, uint8_t node, uint8_t seq, FrameKind kind);
  Slot* allocate_slot(uint64_t rx_time_us);
  void release(Slot& s, bool stale);
  Sender& sender(MessageClass c, uint8_t node) {
    return senders_[static_cast<std::size_t>(node) * kMessageClassCount +
                    static_cast<std::size_t>(c)];
  }

  // Forgets the sequence history of every class of `node` (it restarted); what was pending as
  // missing counts as lost.
  void forget_node(uint8_t node);
  // Moves the pending gaps of `snd` whose deadline passed at `now_us` (all with force) to lost.
  void confirm_gaps(Sender& snd, uint64_t now_us, bool force);
  // True when `rx_us` is not later than `last_us` + the timeout (an earlier time counts as within:
  // a log's lines may be out of order).
  bool within_timeout(uint64_t rx_us, uint64_t last_us) const {
    return rx_us <= last_us || rx_us - last_us <= config_.timeout_us;
  }

  Config config_;
  std::vector<Slot> slots_;
  std::vector<Sender> senders_;
  std::vector<uint32_t> last_uptime_s_;  // per node: uptime of its last heartbeat, or kNoUptime
  static constexpr uint32_t kNoUptime = UINT32_MAX;
  std::size_t in_use_ = 0;
  std::size_t senders_pending_ = 0;  // senders with pending gaps
  uint64_t last_expire_us_ = 0;
  Message out_;
  ReassemblyStats stats_;
};

}  // namespace skinbus::bus
