#include "skinbus/bus/reassembler.h"

#include <algorithm>

#include <bit>
#include <cstring>

namespace skinbus::bus {

Reassembler::Reassembler(const Config& config)
    : config_(config),
      slots_(config.slots == 0 ? 1 : config.slots),
      senders_(static_cast<std::size_t>(kNodeMask + 1) * kMessageClassCount),
      last_uptime_s_(static_cast<std::size_t>(kNodeMask + 1), kNoUptime) {}

void Reassembler::confirm_gaps(Sender& snd, uint64_t now_us, bool force) {
  if (snd.pending == 0) return;
  std::size_t keep = 0;
  for (std::size_t i = 0; i < snd.pending; ++i) {
    if (force || now_us > snd.pending_deadline_us[i]) {
      ++snd.lost_unreported;
      ++stats_.gaps;
    } else {
      snd.pending_seq[keep] = snd.pending_seq[i];
      snd.pending_deadline_us[keep] = snd.pending_deadline_us[i];
      ++keep;
    }
  }
  snd.pending = static_cast<uint8_t>(keep);
  if (keep == 0) --senders_pending_;
}

uint32_t Reassembler::take_unreported_losses(MessageClass c, uint8_t node) {
  Sender& snd = sender(c, node & kNodeMask);
  const uint32_t n = snd.lost_unreported;
  snd.lost_unreported = 0;
  return n;
}

void Reassembler::forget_node(uint8_t node) {
  for (int c = 0; c < kMessageClassCount; ++c) {
    Sender& snd = sender(static_cast<MessageClass>(c), node);
    confirm_gaps(snd, 0, /*force=*/true);
    const uint32_t lost = snd.lost_unreported;
    snd = Sender{};
    snd.lost_unreported = lost;
  }
}

void Reassembler::reset() {
  for (Slot& s : slots_) s.used = false;
  for (Sender& s : senders_) {
    confirm_gaps(s, 0, /*force=*/true);
    const uint32_t lost = s.lost_unreported;
    s = Sender{};
    s.lost_unreported = lost;
  }
  std::fill(last_uptime_s_.begin(), last_uptime_s_.end(), kNoUptime);
  in_use_ = 0;
}

Reassembler::Slot* Reassembler::find_slot(MessageClass c, uint8_t node, uint8_t seq,
                                          FrameKind kind) {
  if (in_use_ == 0) return nullptr;
  for (Slot& s : slots_) {
    if (s.used && s.node == node && s.seq == seq && s.message_class == c && s.kind == kind)
      return &s;
  }
  return nullptr;
}

void Reassembler::release(Slot& s, bool stale) {
  if (stale) stats_.stale_parts += static_cast<uint64_t>(std::popcount(s.have));
  s.used = false;
  --in_use_;
}

Reassembler::Slot* Reassembler::allocate_slot(uint64_t rx_time_us) {
  if (in_use_ == slots_.size()) expire(rx_time_us);
  Slot* oldest = nullptr;
  for (Slot& s : slots_) {
    if (!s.used) {
      s.used = true;
      ++in_use_;
      return &s;
    }
    if (oldest == nullptr || s.first_rx_us < oldest->first_rx_us) oldest = &s;
  }
  // Every slot busy with a message still inside its timeout: drop the oldest, loudly.
  ++stats_.evictions;
  stats_.stale_parts += static_cast<uint64_t>(std::popcount(oldest->have));
  return oldest;  // stays used; the caller re-initialises it
}

void Reassembler::expire(uint64_t now_us) {
  last_expire_us_ = now_us;
  if (senders_pending_ > 0) {
    for (Sender& snd : senders_) confirm_gaps(snd, now_us, /*force=*/false);
  }
  if (in_use_ == 0) return;
  for (Slot& s : slots_) {
    if (s.used && now_us > s.first_rx_us && now_us - s.first_rx_us > config_.timeout_us) {
      release(s, /*stale=*/true);
    }
  }
}

FeedResult Reassembler::complete(MessageClass c, uint8_t node, uint8_t seq, FrameKind kind,
                                 const uint8_t* payload, std::size_t len, uint64_t rx_time_us) {
  FeedResult r;
  const DecodeError e = deserialize_payload(c, {payload, len}, &out_.body);
  if (e != DecodeError::kNone) {
    ++stats_.integrity_failures;
    ++stats_.by_error[static_cast<std::size_t>(e)];
    r.status = FeedStatus::kIntegrityFailure;
    r.error = e;
    return r;
  }
  out_.node = node;
  out_.seq = seq;
  out_.kind = kind;

  // The CRC the payload carries (multi-part) or one computed over it (single frame).
  const uint16_t crc = is_multi_part(c)
                           ? static_cast<uint16_t>(payload[len - 2] | payload[len - 1] << 8)
                           : crc16_ccitt({payload, len});
  if (c == MessageClass::kHeartbeat) {
    const uint32_t up = std::get<Heartbeat>(out_.body).uptime_s;
    uint32_t& last = last_uptime_s_[node & kNodeMask];
    if (last != kNoUptime && up < last) {
      ++stats_.restarts;
      forget_node(node);
    }
    last = up;
  }
  Sender& snd = sender(c, node);
  for (std::size_t i = 0; i < kRecent; ++i) {
    if (snd.recent_used[i] && snd.recent_seq[i] == seq && snd.recent_crc[i] == crc) {
      ++stats_.duplicates;
      r.status = FeedStatus::kDuplicate;
      return r;
    }
  }
  confirm_gaps(snd, rx_time_us, /*force=*/false);
  if (snd.valid) {
    const auto ahead = static_cast<uint8_t>(seq - snd.last_seq);
    if (ahead == 0) {
      snd.last_seq = seq;  // same sequence, other content: a restart or a wrap while quiet
    } else if (ahead < 128) {
      const uint32_t missing = ahead - 1u;
      if (missing > 0 && missing + snd.pending <= kPendingGaps) {
        // Perhaps only reordered: lost if still missing after the timeout.
        if (snd.pending == 0) ++senders_pending_;
        for (uint32_t k = 1; k <= missing; ++k) {
          snd.pending_seq[snd.pending] = static_cast<uint8_t>(snd.last_seq + k);
          snd.pending_deadline_us[snd.pending] = rx_time_us + config_.timeout_us;
          ++snd.pending;
        }
      } else {
        snd.lost_unreported += missing;
        stats_.gaps += missing;
      }
      snd.last_seq = seq;
    } else if (within_timeout(rx_time_us, snd.last_rx_us)) {
      ++stats_.reorders;  // an older message completed late: emitted, history unchanged
      for (std::size_t i = 0; i < snd.pending; ++i) {
        if (snd.pending_seq[i] != seq) continue;
        // It was waiting as missing: not lost after all.
        snd.pending_seq[i] = snd.pending_seq[snd.pending - 1u];
        snd.pending_deadline_us[i] = snd.pending_deadline_us[snd.pending - 1u];
        if (--snd.pending == 0) --senders_pending_;
        break;
      }
    } else {
      // Behind, but after a silence longer than any reordering can last: the sender restarted
      // or 128 or more messages were lost. Take its sequence as the new reference; the jump is
      // counted forward (mod 256) as missing messages.
      ++stats_.resyncs;
      confirm_gaps(snd, rx_time_us, /*force=*/true);
      snd.lost_unreported += ahead - 1u;
      stats_.gaps += ahead - 1u;
      snd.last_seq = seq;
    }
  } else {
    snd.valid = true;
    snd.last_seq = seq;
  }
  r.missing_before = snd.lost_unreported;
  snd.lost_unreported = 0;
  if (snd.last_seq == seq) snd.last_rx_us = rx_time_us;
  snd.recent_seq[snd.ring_pos] = seq;
  snd.recent_crc[snd.ring_pos] = crc;
  snd.recent_used[snd.ring_pos] = true;
  snd.ring_pos = static_cast<uint8_t>((snd.ring_pos + 1) % kRecent);
  if (is_multi_part(c) && snd.last_seq == seq) {
    snd.have_last = true;
    snd.last_kind = kind;
    std::memcpy(snd.last_payload.data(), payload, len);
  }

  ++stats_.messages;
  if (c == MessageClass::kSample) ++stats_.samples;
  r.status = FeedStatus::kMessage;
  r.message = &out_;
  return r;
}

FeedResult Reassembler::feed(const CanFrame& frame, uint64_t rx_time_us) {
  ++stats_.frames;
  if (rx_time_us - last_expire_us_ > config_.timeout_us / 4 && rx_time_us > last_expire_us_) {
    expire(rx_time_us);
  }

  FrameView v;
  if (DecodeError e = parse_frame(frame, &v); e != DecodeError::kNone) {
    ++stats_.by_error[static_cast<std::size_t>(e)];
    if (e == DecodeError::kForeign) {
      ++stats_.foreign;
    } else {
      ++stats_.rejected;
    }
    return FeedResult{FeedStatus::kRejected, e, nullptr, 0};
  }

  const MessageClass c = v.message_class;
  const uint8_t seq = v.header.seq;
  if (v.part_count == 1) {
    return complete(c, v.node, seq, v.kind, v.part_data, v.part_len, rx_time_us);
  }

  Slot* s = find_slot(c, v.node, seq, v.kind);
  if (s == nullptr) {
    // A stray repeat of one part of the message this sender emitted last: the same sequence,
    // kind and bytes, within the timeout. (By sequence alone it could be a restarted node's
    // new message, which must not be dropped.)
    const Sender& snd = sender(c, v.node);
    if (snd.have_last && snd.last_seq == seq && snd.last_kind == v.kind &&
        within_timeout(rx_time_us, snd.last_rx_us) &&
        std::memcmp(snd.last_payload.data() + v.payload_offset, v.part_data, v.part_len) == 0) {
      ++stats_.duplicates;
      return FeedResult{FeedStatus::kDuplicate, DecodeError::kNone, nullptr, 0};
    }
    s = allocate_slot(rx_time_us);
    s->message_class = c;
    s->node = v.node;
    s->seq = seq;
    s->kind = v.kind;
    s->part_count = v.part_count;
    s->highest_part = v.header.part;
    s->have = 0;
    s->first_rx_us = rx_time_us;
  }

  const uint32_t bit = 1u << v.header.part;
  uint8_t* dst = s->payload.data() + v.payload_offset;
  if (s->have & bit) {
    if (std::memcmp(dst, v.part_data, v.part_len) == 0) {
      ++stats_.duplicates;
      return FeedResult{FeedStatus::kDuplicate, DecodeError::kNone, nullptr, 0};
    }
    // Two different parts under one (sender, class, sequence): the message cannot be trusted.
    ++stats_.conflicts;
    ++stats_.integrity_failures;
    release(*s, /*stale=*/false);
    return FeedResult{FeedStatus::kIntegrityFailure, DecodeError::kBadCrc, nullptr, 0};
  }
  if (v.header.part < s->highest_part) ++stats_.reorders;
  if (v.header.part > s->highest_part) s->highest_part = v.header.part;
  std::memcpy(dst, v.part_data, v.part_len);
  s->have |= bit;
  if (s->have != (1u << s->part_count) - 1u) return FeedResult{};

  FeedResult r = complete(c, v.node, seq, v.kind, s->payload.data(), payload_len(c), rx_time_us);
  release(*s, /*stale=*/false);
  return r;
}

}  // namespace skinbus::bus
