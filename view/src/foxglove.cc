#include "skinbus/view/foxglove.h"

#include <algorithm>
#include <nlohmann/json.hpp>

#include "skinbus/view/server.h"

namespace skinbus::view {
namespace {

std::string dump(const nlohmann::json& j) {
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

// A uint32 field of `j` (an ID), or false when absent or out of range.
bool get_u32(const nlohmann::json& j, const char* key, uint32_t* out) {
  const auto it = j.find(key);
  if (it == j.end() || !it->is_number_integer()) return false;
  if (it->is_number_unsigned()) {
    const auto v = it->get<uint64_t>();
    if (v > UINT32_MAX) return false;
    *out = static_cast<uint32_t>(v);
    return true;
  }
  const auto v = it->get<int64_t>();
  if (v < 0 || v > static_cast<int64_t>(UINT32_MAX)) return false;
  *out = static_cast<uint32_t>(v);
  return true;
}

}  // namespace

void append_foxglove_message_data(uint32_t subscription_id, uint64_t timestamp_ns,
                                  std::string_view message, std::string* out) {
  out->push_back(static_cast<char>(0x01));
  for (int i = 0; i < 4; ++i)
    out->push_back(static_cast<char>((subscription_id >> (8 * i)) & 0xff));
  for (int i = 0; i < 8; ++i) out->push_back(static_cast<char>((timestamp_ns >> (8 * i)) & 0xff));
  out->append(message);
}

std::string foxglove_status_json(FoxgloveStatusLevel level, std::string_view message) {
  return dump({{"op", "status"}, {"level", static_cast<int>(level)}, {"message", message}});
}

FoxgloveProtocol::FoxgloveProtocol(std::string server_name)
    : server_name_(std::move(server_name)) {}

uint32_t FoxgloveProtocol::add_channel(std::string topic, std::string schema_name,
                                       std::string schema) {
  FoxgloveChannel c;
  c.id = static_cast<uint32_t>(channels_.size() + 1);
  c.topic = std::move(topic);
  c.schema_name = std::move(schema_name);
  c.schema = std::move(schema);
  channels_.push_back(std::move(c));
  latest_.emplace_back();
  return channels_.back().id;
}

uint32_t FoxgloveProtocol::find_channel(std::string_view topic) const {
  for (const auto& c : channels_) {
    if (c.topic == topic) return c.id;
  }
  return 0;
}

std::string FoxgloveProtocol::server_info_json() const {
  return dump({{"op", "serverInfo"},
               {"name", server_name_},
               {"capabilities", nlohmann::json::array()},
               {"metadata", nlohmann::json::object()}});
}

std::string FoxgloveProtocol::advertise_json() const {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& c : channels_) {
    list.push_back({{"id", c.id},
                    {"topic", c.topic},
                    {"encoding", "json"},
                    {"schemaName", c.schema_name},
                    {"schema", c.schema},
                    {"schemaEncoding", "jsonschema"}});
  }
  return dump({{"op", "advertise"}, {"channels", list}});
}

FoxgloveProtocol::Reply FoxgloveProtocol::handle(uint64_t client, std::string_view text) {
  Reply reply;
  auto refuse = [&](FoxgloveStatusLevel level, const std::string& why) {
    ++refusals_;
    reply.texts.push_back(foxglove_status_json(level, why));
  };
  const auto j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object() || !j.contains("op") || !j["op"].is_string()) {
    refuse(FoxgloveStatusLevel::kError, "not a JSON object with an \"op\"");
    return reply;
  }
  const std::string op = j["op"].get<std::string>();
  if (op == "subscribe") {
    const auto it = j.find("subscriptions");
    if (it == j.end() || !it->is_array()) {
      refuse(FoxgloveStatusLevel::kError, "subscribe: no \"subscriptions\" array");
      return reply;
    }
    for (const auto& s : *it) {
      FoxgloveSubscription sub;
      sub.client = client;
      if (!s.is_object() || !get_u32(s, "id", &sub.id) || !get_u32(s, "channelId", &sub.channel)) {
        refuse(FoxgloveStatusLevel::kError,
               "subscribe: a subscription needs an id and a channelId");
        continue;
      }
      if (sub.channel == 0 || sub.channel > channels_.size()) {
        refuse(FoxgloveStatusLevel::kError, "subscribe: no channel " + std::to_string(sub.channel));
        continue;
      }
      const bool taken = std::any_of(subscriptions_.begin(), subscriptions_.end(), [&](auto& o) {
        return o.client == client && (o.id == sub.id || o.channel == sub.channel);
      });
      if (taken) {
        refuse(FoxgloveStatusLevel::kError, "subscribe: subscription " + std::to_string(sub.id) +
                                                " or channel " + std::to_string(sub.channel) +
                                                " is already subscribed");
        continue;
      }
      subscriptions_.push_back(sub);
      reply.subscribed.push_back(sub);
      ++subscribes_;
    }
  } else if (op == "unsubscribe") {
    const auto it = j.find("subscriptionIds");
    if (it == j.end() || !it->is_array()) {
      refuse(FoxgloveStatusLevel::kError, "unsubscribe: no \"subscriptionIds\" array");
      return reply;
    }
    for (const auto& v : *it) {
      const auto n = v.is_number_unsigned() ? v.get<uint64_t>() : UINT64_MAX;
      const auto before = subscriptions_.size();
      std::erase_if(subscriptions_, [&](auto& o) { return o.client == client && o.id == n; });
      if (subscriptions_.size() == before) {
        refuse(FoxgloveStatusLevel::kWarning, "unsubscribe: no subscription " + v.dump());
      } else {
        ++subscribes_;
      }
    }
  } else {
    refuse(FoxgloveStatusLevel::kError,
           "'" + op + "' is not supported: this server only streams (subscribe, unsubscribe)");
  }
  return reply;
}

void FoxgloveProtocol::forget(uint64_t client) {
  std::erase_if(subscriptions_, [&](auto& o) { return o.client == client; });
}

std::vector<FoxgloveSubscription> FoxgloveProtocol::subscribers(uint32_t channel) const {
  std::vector<FoxgloveSubscription> out;
  for (const auto& s : subscriptions_) {
    if (s.channel == channel) out.push_back(s);
  }
  return out;
}

bool FoxgloveProtocol::send(Server& server, const FoxgloveSubscription& s, uint64_t timestamp_ns,
                            std::string_view message) {
  frame_.clear();
  append_foxglove_message_data(s.id, timestamp_ns, message, &frame_);
  return server.send_binary_to(s.client, frame_);
}

void FoxgloveProtocol::on_message(Server& server, uint64_t client, std::string_view text) {
  const Reply reply = handle(client, text);
  bool gone = false;
  for (const auto& t : reply.texts) gone = !server.send_to(client, t) || gone;
  for (const auto& s : reply.subscribed) {
    const Latest& l = latest_[s.channel - 1];
    if (l.set) gone = !send(server, s, l.timestamp_ns, l.message) || gone;
  }
  if (gone) forget(client);
}

int FoxgloveProtocol::publish(Server& server, uint32_t channel, uint64_t timestamp_ns,
                              std::string_view message) {
  if (channel == 0 || channel > channels_.size()) return 0;
  Latest& l = latest_[channel - 1];
  l.set = true;
  l.timestamp_ns = timestamp_ns;
  l.message.assign(message);
  int sent = 0;
  std::vector<uint64_t> gone;
  for (const auto& s : subscriptions_) {
    if (s.channel != channel) continue;
    if (send(server, s, timestamp_ns, message)) {
      ++sent;
    } else {
      gone.push_back(s.client);
    }
  }
  for (uint64_t c : gone) forget(c);
  return sent;
}

}  // namespace skinbus::view
