#include "skinbus/view/field_tap.h"

#include <cmath>
#include <cstdlib>
#include <nlohmann/json.hpp>

#include "skinbus/bus/codec.h"

namespace skinbus::view {

FieldTap::FieldTap(const FieldTapOptions& options) : options_(options) {}

void FieldTap::feed(const bus::CanFrame& frame, uint64_t rx_us, std::string_view iface) {
  std::lock_guard lock(mutex_);
  ++stats_.frames;
  auto it = reassemblers_.find(iface);
  if (it == reassemblers_.end()) {
    if (static_cast<int>(reassemblers_.size()) >= options_.max_interfaces) {
      ++stats_.ignored_buses;
      return;
    }
    it = reassemblers_.emplace(std::string(iface), std::make_unique<bus::Reassembler>()).first;
  }
  const bus::FeedResult r = it->second->feed(frame, rx_us);
  if (r.status == bus::FeedStatus::kRejected || r.status == bus::FeedStatus::kIntegrityFailure) {
    ++stats_.rejected;
    return;
  }
  if (r.status != bus::FeedStatus::kMessage) return;
  const auto* sample = std::get_if<bus::Sample>(&r.message->body);
  if (sample == nullptr) return;
  ++stats_.samples;
  nlohmann::json field = nlohmann::json::array(), saturated = nlohmann::json::array();
  int16_t largest_lsb = 0;
  for (int s = 0; s < bus::kSensorCount; ++s) {
    const bool faulty = sample->fault_mask & (1u << s);
    if (sample->saturation_mask & (1u << s)) saturated.push_back(s);
    for (int a = 0; a < bus::kAxisCount; ++a) {
      const int16_t lsb = sample->field_lsb[static_cast<std::size_t>(3 * s + a)];
      if (faulty) {
        field.push_back(nullptr);
        continue;
      }
      field.push_back(lsb * bus::kFieldUtPerLsb);
      largest_lsb = std::max<int16_t>(largest_lsb, static_cast<int16_t>(std::abs(lsb)));
    }
  }
  Patch& p = patches_[{it->first, r.message->node}];
  p.json = nlohmann::json{{"type", "fields"},
                          {"stamp_us", rx_us},
                          {"interface", it->first},
                          {"node", r.message->node},
                          {"tared", (sample->flags & bus::sample_flags::kTared) != 0},
                          {"field_ut", field},
                          {"saturated", saturated}}
               .dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  p.fresh = true;
  p.above = largest_lsb * bus::kFieldUtPerLsb >= options_.show_ut;
}

void FieldTap::take_updates(uint64_t now_us, std::vector<std::string>* out) {
  std::lock_guard lock(mutex_);
  const auto min_gap_us = static_cast<uint64_t>(1e6 / options_.max_rate_hz);
  for (auto& [key, p] : patches_) {
    if (!p.fresh || (!p.above && !p.shown)) continue;  // idle and already cleared
    if (p.above && p.shown && now_us - p.last_sent_us < min_gap_us) continue;
    out->push_back(p.json);
    ++stats_.updates;
    p.fresh = false;
    p.shown = p.above;
    p.last_sent_us = now_us;
  }
}

FieldTapStats FieldTap::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

}  // namespace skinbus::view
