// skinbus/view/foxglove.h: the server side of the Foxglove WebSocket protocol v1 (subprotocol
// "foxglove.websocket.v1"), as skinbus-view --foxglove-port speaks it to Foxglove and Lichtblick
// (docs/foxglove.md): channels the server advertises, every client's subscriptions, and the
// messages of the protocol a server without client publishing, parameters or services needs.
//
// What goes over the wire:
// - on connecting, the client gets `serverInfo` (no capabilities) and one `advertise` naming every
//   channel (JSON text messages; server_info_json(), advertise_json());
// - the client sends `subscribe` ({"op":"subscribe","subscriptions":[{"id":S,"channelId":C}]})
//   and `unsubscribe` ({"op":"unsubscribe","subscriptionIds":[S]}); anything else, and any
//   subscription that cannot be taken (an unknown channel, an ID in use, a channel this client
//   already subscribes), is answered with a `status` message (level 1 warning, 2 error) and
//   otherwise ignored;
// - each message of a channel goes to each subscription to it as one binary Message Data frame:
//   opcode 0x01, the subscription ID (uint32, little-endian), the message's time (uint64
//   nanoseconds, little-endian), then the message (here JSON text: every channel's encoding is
//   "json", its schema a JSON Schema, schemaEncoding "jsonschema").
//
// Bounds: a client holds at most one subscription a channel (the protocol's rule), so at most
// channels().size(); clients are the Server's (max_clients). The latest message of every channel
// is kept (one copy) and sent at once to a new subscription, so a client that subscribes late sees
// the current state without waiting for the next change.
//
// Single-threaded, like Server: every call from the loop that polls the server. Errors are values
// (status messages to the client); nothing throws.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace skinbus::view {

class Server;

// The WebSocket subprotocol of the Foxglove WebSocket protocol v1 (Server::set_subprotocol).
inline constexpr char kFoxgloveSubprotocol[] = "foxglove.websocket.v1";

// Status levels of the protocol's `status` message.
enum class FoxgloveStatusLevel : int { kInfo = 0, kWarning = 1, kError = 2 };

struct FoxgloveChannel {
  uint32_t id = 0;          // 1, 2, ... in the order the channels were added
  std::string topic;        // e.g. "/skin/contacts"
  std::string schema_name;  // e.g. "foxglove.SceneUpdate" (how Foxglove recognises the message)
  std::string schema;       // JSON Schema text; messages are JSON ("json" encoding)
};

struct FoxgloveSubscription {
  uint64_t client = 0;   // the client's connection (Server page ID)
  uint32_t id = 0;       // the subscription ID the client chose
  uint32_t channel = 0;  // FoxgloveChannel::id
};

// Appends one binary Message Data frame's payload (the WebSocket frame around it is the
// Server's): 0x01, `subscription_id` and `timestamp_ns` little-endian, then `message`.
void append_foxglove_message_data(uint32_t subscription_id, uint64_t timestamp_ns,
                                  std::string_view message, std::string* out);

// A `status` message: {"op":"status","level":L,"message":"..."}.
std::string foxglove_status_json(FoxgloveStatusLevel level, std::string_view message);

class FoxgloveProtocol {
 public:
  // `server_name`: serverInfo's name (free text the client may show).
  explicit FoxgloveProtocol(std::string server_name);

  // Adds a channel; returns its ID. Channels are added before clients connect (clients learn
  // them once, from the advertise message they get on connecting).
  uint32_t add_channel(std::string topic, std::string schema_name, std::string schema);
  const std::vector<FoxgloveChannel>& channels() const { return channels_; }
  // The ID of the channel on `topic`, or 0.
  uint32_t find_channel(std::string_view topic) const;

  // The messages every client gets on connecting, in this order (Server::set_greeting).
  std::string server_info_json() const;
  std::string advertise_json() const;

  // What handle() asks of the caller: texts to send back to that client (status messages), and
  // the subscriptions it took (each owed the channel's latest message).
  struct Reply {
    std::vector<std::string> texts;
    std::vector<FoxgloveSubscription> subscribed;
  };
  // One text message of client `client`. Never fails: what cannot be taken is answered.
  Reply handle(uint64_t client, std::string_view text);
  // Drops every subscription of `client` (it has gone).
  void forget(uint64_t client);

  // The subscriptions to `channel`, oldest first.
  std::vector<FoxgloveSubscription> subscribers(uint32_t channel) const;
  std::size_t subscription_count() const { return subscriptions_.size(); }

  // With a Server (view/server.h), whose page IDs are the clients:
  // handle() and its reply: the status texts to the client, the channel's latest message (if
  // any) to each new subscription. A client that has gone is forgotten.
  void on_message(Server& server, uint64_t client, std::string_view text);
  // Sends `message` (JSON) stamped `timestamp_ns` to every subscription to `channel` and keeps it
  // as the channel's latest. Forgets the clients that have gone (Server::send_binary_to false:
  // closed, or dropped for not reading). Returns how many subscriptions it was sent to. Costs one
  // frame (message + 13 bytes) copied per subscription.
  int publish(Server& server, uint32_t channel, uint64_t timestamp_ns, std::string_view message);

  // Counters: subscribe/unsubscribe requests taken, and client messages refused with a status.
  uint64_t subscribes() const { return subscribes_; }
  uint64_t refusals() const { return refusals_; }

 private:
  struct Latest {
    bool set = false;
    uint64_t timestamp_ns = 0;
    std::string message;
  };
  bool send(Server& server, const FoxgloveSubscription& s, uint64_t timestamp_ns,
            std::string_view message);

  std::string server_name_;
  std::vector<FoxgloveChannel> channels_;
  std::vector<Latest> latest_;  // per channel (index id - 1)
  std::vector<FoxgloveSubscription> subscriptions_;
  std::string frame_;  // reused Message Data buffer
  uint64_t subscribes_ = 0, refusals_ = 0;
};

}  // namespace skinbus::view
