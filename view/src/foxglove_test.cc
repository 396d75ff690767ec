#include "skinbus/view/foxglove.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>

#include "skinbus/view/foxglove_json.h"
#include "skinbus/view/server.h"
#include "skinbus/view/websocket.h"

namespace skinbus::view {
namespace {

using Json = nlohmann::json;

// -- the protocol's state ------------------------------------------------------------------------

FoxgloveProtocol three_channels() {
  FoxgloveProtocol p("skinbus-view test");
  EXPECT_EQ(p.add_channel("/skin/contacts", kSceneUpdateSchemaName, foxglove_scene_update_schema()),
            1u);
  EXPECT_EQ(p.add_channel("/tf", kFrameTransformsSchemaName, foxglove_frame_transforms_schema()),
            2u);
  EXPECT_EQ(
      p.add_channel("/skin/patch_status", kPatchStatusSchemaName, skinbus_patch_status_schema()),
      3u);
  return p;
}

TEST(Foxglove, MessageDataIsOpcodeSubscriptionTimeAndPayloadLittleEndian) {
  std::string out;
  append_foxglove_message_data(0x01020304u, 0x1122334455667788ull, "{}", &out);
  const std::string expected("\x01\x04\x03\x02\x01\x88\x77\x66\x55\x44\x33\x22\x11{}", 15);
  EXPECT_EQ(out, expected);
}

TEST(Foxglove, ServerInfoAndAdvertiseNameEveryChannelWithItsSchema) {
  const auto p = three_channels();
  const auto info = Json::parse(p.server_info_json());
  EXPECT_EQ(info["op"], "serverInfo");
  EXPECT_EQ(info["name"], "skinbus-view test");
  EXPECT_TRUE(info["capabilities"].empty());
  const auto ad = Json::parse(p.advertise_json());
  EXPECT_EQ(ad["op"], "advertise");
  ASSERT_EQ(ad["channels"].size(), 3u);
  for (const auto& c : ad["channels"]) {
    EXPECT_EQ(c["encoding"], "json");
    EXPECT_EQ(c["schemaEncoding"], "jsonschema");
    const auto schema = Json::parse(c["schema"].get<std::string>());  // valid JSON
    EXPECT_EQ(schema["title"], c["schemaName"]);
  }
  EXPECT_EQ(ad["channels"][0]["topic"], "/skin/contacts");
  EXPECT_EQ(ad["channels"][0]["schemaName"], "foxglove.SceneUpdate");
  EXPECT_EQ(ad["channels"][1]["schemaName"], "foxglove.FrameTransforms");
  EXPECT_EQ(p.find_channel("/tf"), 2u);
  EXPECT_EQ(p.find_channel("/nope"), 0u);
}

TEST(Foxglove, SubscriptionsAreTakenPerClientAndWhatCannotBeIsAnswered) {
  auto p = three_channels();
  auto r = p.handle(7, R"({"op":"subscribe","subscriptions":[{"id":0,"channelId":1},)"
                       R"({"id":5,"channelId":3}]})");
  EXPECT_TRUE(r.texts.empty());
  ASSERT_EQ(r.subscribed.size(), 2u);
  EXPECT_EQ(r.subscribed[1].id, 5u);
  EXPECT_EQ(r.subscribed[1].channel, 3u);
  // Another client may use the same IDs.
  EXPECT_EQ(p.handle(8, R"({"op":"subscribe","subscriptions":[{"id":0,"channelId":1}]})")
                .subscribed.size(),
            1u);
  EXPECT_EQ(p.subscribers(1).size(), 2u);
  // Refused, each with a status: an ID in use, a channel subscribed twice, an unknown channel,
  // a malformed entry, not JSON, an operation the server does not offer.
  for (const char* bad : {R"({"op":"subscribe","subscriptions":[{"id":0,"channelId":2}]})",
                          R"({"op":"subscribe","subscriptions":[{"id":9,"channelId":1}]})",
                          R"({"op":"subscribe","subscriptions":[{"id":9,"channelId":4}]})",
                          R"({"op":"subscribe","subscriptions":[{"id":-1,"channelId":2}]})",
                          R"({"op":"subscribe"})", "not json", R"(["op"])",
                          R"({"op":"advertise","channels":[]})", R"({"op":"getParameters"})"}) {
    const auto reply = p.handle(7, bad);
    EXPECT_TRUE(reply.subscribed.empty()) << bad;
    ASSERT_EQ(reply.texts.size(), 1u) << bad;
    const auto status = Json::parse(reply.texts[0]);
    EXPECT_EQ(status["op"], "status");
    EXPECT_EQ(status["level"], 2) << bad;
  }
  EXPECT_EQ(p.subscription_count(), 3u);
  r = p.handle(7, R"({"op":"unsubscribe","subscriptionIds":[0,42]})");
  ASSERT_EQ(r.texts.size(), 1u);  // 42 was never subscribed: a warning
  EXPECT_EQ(Json::parse(r.texts[0])["level"], 1);
  EXPECT_EQ(p.subscribers(1).size(), 1u);
  EXPECT_EQ(p.subscribers(1)[0].client, 8u);
  p.forget(8);
  EXPECT_TRUE(p.subscribers(1).empty());
  EXPECT_EQ(p.subscription_count(), 1u);  // client 7's /skin/patch_status
}

// -- the messages --------------------------------------------------------------------------------

TEST(Foxglove, ContactsAreSpheresInTheBaseFrameAndEndedTracksAreDeleted) {
  ContactSceneEncoder enc;
  std::vector<SceneContact> c(2);
  c[0].track_id = 3;
  c[0].position_mm[0] = 116.8;
  c[0].position_mm[1] = -244.25;
  c[0].position_mm[2] = 1228.125;
  c[0].depth_mm = 2;
  c[0].force_n = 3.5;
  c[0].node = 1;
  c[0].link = "left_forearm_link";
  c[1].track_id = 4;
  auto j = Json::parse(enc.encode(1'795'267'568'586'650, "pelvis", c));
  ASSERT_EQ(j["entities"].size(), 2u);
  EXPECT_TRUE(j["deletions"].empty());
  const auto& e = j["entities"][0];
  EXPECT_EQ(e["id"], "contact/3");
  EXPECT_EQ(e["frame_id"], "pelvis");
  EXPECT_EQ(e["timestamp"]["sec"], 1'795'267'568u);
  EXPECT_EQ(e["timestamp"]["nsec"], 586'650'000u);
  const auto& s = e["spheres"][0];
  EXPECT_DOUBLE_EQ(s["pose"]["position"]["x"].get<double>(), 0.1168);
  EXPECT_DOUBLE_EQ(s["pose"]["position"]["y"].get<double>(), -0.24425);
  EXPECT_DOUBLE_EQ(s["pose"]["position"]["z"].get<double>(), 1.228125);
  EXPECT_DOUBLE_EQ(s["size"]["x"].get<double>(), 0.022);  // 2 * (5 + 3 * 2) mm
  EXPECT_DOUBLE_EQ(contact_sphere_diameter_mm(-1), 10);
  EXPECT_DOUBLE_EQ(contact_sphere_diameter_mm(9), 40);
  EXPECT_EQ(e["metadata"][0]["key"], "track_id");
  EXPECT_EQ(e["metadata"][0]["value"], "3");
  EXPECT_TRUE(e["arrows"].empty());  // no shear
  // A contact with a shear force: an arrow from the sphere's surface along it.
  {
    ContactSceneEncoder sheared;
    std::vector<SceneContact> one(1);
    one[0].track_id = 9;
    one[0].depth_mm = 2;  // sphere radius 11 mm
    one[0].has_shear = true;
    one[0].shear_n[1] = -1.2;
    one[0].shear_n[2] = 1.6;  // 2 N along (0, -0.6, 0.8)
    const auto a = Json::parse(sheared.encode(1'000'000, "pelvis", one))["entities"][0]["arrows"];
    ASSERT_EQ(a.size(), 1u);
    const auto& pose = a[0]["pose"];
    EXPECT_NEAR(pose["position"]["y"].get<double>(), -0.6 * 0.011, 1e-12);
    EXPECT_NEAR(pose["position"]["z"].get<double>(), 0.8 * 0.011, 1e-12);
    const Eigen::Quaterniond q(
        pose["orientation"]["w"].get<double>(), pose["orientation"]["x"].get<double>(),
        pose["orientation"]["y"].get<double>(), pose["orientation"]["z"].get<double>());
    EXPECT_LT((q * Eigen::Vector3d::UnitX() - Eigen::Vector3d(0, -0.6, 0.8)).norm(), 1e-12);
    EXPECT_NEAR(a[0]["shaft_length"].get<double>() + a[0]["head_length"].get<double>(), 0.024,
                1e-12);        // 12 mm a newton
    one[0].has_shear = false;  // the host did not estimate it: no arrow
    EXPECT_TRUE(
        Json::parse(sheared.encode(2'000'000, "pelvis", one))["entities"][0]["arrows"].empty());
  }
  // Track 3 ends: deleted by ID; track 4 goes on.
  c.erase(c.begin());
  j = Json::parse(enc.encode(1'795'267'568'600'000, "pelvis", c));
  ASSERT_EQ(j["deletions"].size(), 1u);
  EXPECT_EQ(j["deletions"][0]["type"], 0);
  EXPECT_EQ(j["deletions"][0]["id"], "contact/3");
  EXPECT_EQ(j["deletions"][0]["timestamp"]["nsec"], 600'000'001u);
  ASSERT_EQ(j["entities"].size(), 1u);
  j = Json::parse(enc.encode(1'795'267'568'700'000, "pelvis", {}));
  EXPECT_EQ(j["deletions"].size(), 1u);
  EXPECT_TRUE(j["entities"].empty());
}

const char* kArmUrdf = R"(<robot name="arm">
  <link name="base"/><link name="upper"/><link name="fore"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/>
    <origin xyz="0 0.2 1.0" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="elbow" type="fixed">
    <parent link="upper"/><child link="fore"/><origin xyz="0.3 0 0" rpy="0 0 1.5707963267948966"/>
  </joint>
</robot>)";

TEST(Foxglove, TransformsAreEveryLinkFromItsParent) {
  auto robot = body_map::RobotModel::from_urdf_string(kArmUrdf);
  ASSERT_TRUE(robot.ok()) << robot.error().to_string();
  std::vector<body_map::Pose> poses(robot->link_count());
  const double q[] = {0.5};
  ASSERT_TRUE(robot->forward_kinematics(q, poses).ok());
  const auto j = Json::parse(frame_transforms_json(2'000'001, *robot, poses));
  ASSERT_EQ(j["transforms"].size(), 2u);
  const auto& shoulder = j["transforms"][0];
  EXPECT_EQ(shoulder["parent_frame_id"], "base");
  EXPECT_EQ(shoulder["child_frame_id"], "upper");
  EXPECT_EQ(shoulder["timestamp"]["sec"], 2u);
  EXPECT_EQ(shoulder["timestamp"]["nsec"], 1000u);
  EXPECT_NEAR(shoulder["translation"]["y"].get<double>(), 0.2, 1e-12);
  EXPECT_NEAR(shoulder["translation"]["z"].get<double>(), 1.0, 1e-12);
  EXPECT_NEAR(shoulder["rotation"]["y"].get<double>(), std::sin(0.25), 1e-12);  // 0.5 rad about y
  EXPECT_NEAR(shoulder["rotation"]["w"].get<double>(), std::cos(0.25), 1e-12);
  const auto& elbow = j["transforms"][1];
  EXPECT_EQ(elbow["parent_frame_id"], "upper");
  EXPECT_NEAR(elbow["translation"]["x"].get<double>(), 0.3, 1e-12);
  EXPECT_NEAR(elbow["rotation"]["z"].get<double>(), std::sqrt(0.5), 1e-12);
}

TEST(Foxglove, PatchesAreSurfacesOnTheirLinksColouredByState) {
  body_map::SkinMap map;
  map.patches.resize(2);
  map.patches[0].node_id = 1;
  map.patches[0].hardware_uid = 0x5b00000000000001ull;
  map.patches[0].link = "fore";
  map.patches[0].geometry.kind = body_map::SurfaceKind::kCylinder;
  map.patches[0].geometry.radius_mm = 45;
  map.patches[1].node_id = 2;
  map.patches[1].link = "base";
  map.patches[1].pose_on_link.translation_mm = {0, 0, 100};
  const std::vector<std::string> states = {"online"};  // patch 2: no status yet
  const auto j = Json::parse(patches_scene_update_json(5, map, states));
  ASSERT_EQ(j["entities"].size(), 2u);
  const auto& cyl = j["entities"][0];
  EXPECT_EQ(cyl["id"], "patch/1");
  EXPECT_EQ(cyl["frame_id"], "fore");
  EXPECT_TRUE(cyl["frame_locked"].get<bool>());
  const auto& tri = cyl["triangles"][0];
  EXPECT_EQ(tri["points"].size(), 26u);        // 13 across the arc x 2 along the axis
  EXPECT_EQ(tri["indices"].size(), 12u * 6u);  // two triangles a cell
  EXPECT_NEAR(tri["color"]["g"].get<double>(), 0xcc / 255.0, 1e-12);  // online: green
  for (const auto& pt : tri["points"]) {  // every point 1.5 mm out of the 45 mm surface
    const double x = pt["x"].get<double>(), z = pt["z"].get<double>() + 0.045;
    EXPECT_NEAR(std::hypot(x, z), 0.0465, 1e-12);
  }
  const auto& flat = j["entities"][1];
  EXPECT_EQ(flat["frame_id"], "base");
  EXPECT_EQ(flat["triangles"][0]["points"].size(), 4u);
  EXPECT_NEAR(flat["triangles"][0]["points"][0]["z"].get<double>(), 0.1015, 1e-12);
  EXPECT_NEAR(flat["triangles"][0]["points"][0]["x"].get<double>(), -0.07, 1e-12);
  EXPECT_EQ(flat["metadata"][3]["key"], "state");
  EXPECT_EQ(flat["metadata"][3]["value"], "unknown");
}

// -- with the server, over a socket --------------------------------------------------------------

class Client {
 public:
  explicit Client(uint16_t port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
  }
  ~Client() { ::close(fd_); }
  void send(const std::string& bytes) { ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL); }
  void send_text(const std::string& text) {  // one masked text frame (mask 0: payload as is)
    std::string f{static_cast<char>(0x81)};
    f.push_back(static_cast<char>(0x80 | text.size()));
    f.append(4, '\0');
    send(f + text);
  }
  void read_available() {
    char buf[65536];
    for (;;) {
      const ssize_t n = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
      if (n <= 0) return;
      in.append(buf, static_cast<std::size_t>(n));
    }
  }
  // The next complete server frame after the HTTP head: (opcode, payload); false when none yet.
  bool next_frame(int* opcode, std::string* payload) {
    if (!head_done) {
      const auto end = in.find("\r\n\r\n");
      if (end == std::string::npos) return false;
      head = in.substr(0, end + 4);
      in.erase(0, end + 4);
      head_done = true;
    }
    if (in.size() < 2) return false;
    std::size_t len = static_cast<uint8_t>(in[1]) & 0x7f, at = 2;
    if (len == 126) {
      if (in.size() < 4) return false;
      len = (std::size_t{static_cast<uint8_t>(in[2])} << 8) | static_cast<uint8_t>(in[3]);
      at = 4;
    } else if (len == 127) {
      if (in.size() < 10) return false;
      len = 0;
      for (int i = 0; i < 8; ++i) len = (len << 8) | static_cast<uint8_t>(in[2 + i]);
      at = 10;
    }
    if (in.size() < at + len) return false;
    *opcode = static_cast<uint8_t>(in[0]) & 0x0f;
    *payload = in.substr(at, len);
    in.erase(0, at + len);
    return true;
  }
  std::string in, head;
  bool head_done = false;

 private:
  int fd_ = -1;
};

std::string upgrade(const std::string& protocols) {
  return "GET / HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
         "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n" +
         (protocols.empty() ? "" : "Sec-WebSocket-Protocol: " + protocols + "\r\n") + "\r\n";
}

// Polls until `client` has a frame (or 5 s pass).
bool next(Server& server, Client& client, int* opcode, std::string* payload) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (std::chrono::steady_clock::now() < end) {
    EXPECT_TRUE(server.poll(2).ok());
    client.read_available();
    if (client.next_frame(opcode, payload)) return true;
  }
  return false;
}

TEST(Foxglove, AClientSubscribesAndGetsTheLatestThenEveryMessageAsBinaryFrames) {
  auto p = three_channels();
  ServerOptions options;
  options.port = 0;
  auto server = Server::create(options);
  ASSERT_TRUE(server.ok());
  auto& s = **server;
  s.set_stream_path("/");
  s.set_subprotocol(kFoxgloveSubprotocol);
  s.set_greeting([&] {
    return std::vector<std::string>{p.server_info_json(), p.advertise_json()};
  });
  s.set_message_handler([&](uint64_t c, std::string_view text, bool) { p.on_message(s, c, text); });
  // Before anyone subscribes: kept as the latest, sent to nobody.
  EXPECT_EQ(p.publish(s, 2, 1000, R"({"transforms":[]})"), 0);

  Client plain(s.port());  // no subprotocol offered: refused
  plain.send(upgrade(""));
  int op = 0;
  std::string payload;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (plain.in.find("\r\n\r\n") == std::string::npos &&
         std::chrono::steady_clock::now() < until) {
    ASSERT_TRUE(s.poll(2).ok());
    plain.read_available();
  }
  EXPECT_EQ(plain.in.rfind("HTTP/1.1 400", 0), 0u) << plain.in;

  Client c(s.port());
  c.send(upgrade("other, foxglove.websocket.v1"));
  ASSERT_TRUE(next(s, c, &op, &payload));
  EXPECT_NE(c.head.find("Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n"), std::string::npos);
  EXPECT_EQ(op, 1);
  EXPECT_EQ(Json::parse(payload)["op"], "serverInfo");
  ASSERT_TRUE(next(s, c, &op, &payload));
  EXPECT_EQ(Json::parse(payload)["op"], "advertise");

  c.send_text(R"({"op":"subscribe","subscriptions":[{"id":7,"channelId":2}]})");
  ASSERT_TRUE(next(s, c, &op, &payload));  // the latest /tf at once
  EXPECT_EQ(op, 2);
  std::string expected;
  append_foxglove_message_data(7, 1000, R"({"transforms":[]})", &expected);
  EXPECT_EQ(payload, expected);
  EXPECT_EQ(p.publish(s, 2, 2000, "{}"), 1);
  EXPECT_EQ(p.publish(s, 1, 2000, "{}"), 0);  // not subscribed
  ASSERT_TRUE(next(s, c, &op, &payload));
  expected.clear();
  append_foxglove_message_data(7, 2000, "{}", &expected);
  EXPECT_EQ(payload, expected);

  c.send_text(R"({"op":"getParameters"})");
  ASSERT_TRUE(next(s, c, &op, &payload));
  EXPECT_EQ(op, 1);
  EXPECT_EQ(Json::parse(payload)["op"], "status");
}

TEST(Foxglove, AClientThatLeavesIsForgottenAtTheNextMessage) {
  auto p = three_channels();
  ServerOptions options;
  options.port = 0;
  auto server = Server::create(options);
  ASSERT_TRUE(server.ok());
  auto& s = **server;
  s.set_stream_path("/");
  s.set_subprotocol(kFoxgloveSubprotocol);
  s.set_message_handler([&](uint64_t c, std::string_view text, bool) { p.on_message(s, c, text); });
  {
    Client c(s.port());
    c.send(upgrade(kFoxgloveSubprotocol));
    c.send_text(R"({"op":"subscribe","subscriptions":[{"id":1,"channelId":1}]})");
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (p.subscription_count() == 0 && std::chrono::steady_clock::now() < until) {
      ASSERT_TRUE(s.poll(2).ok());
    }
    ASSERT_EQ(p.subscription_count(), 1u);
  }
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (s.stats().clients > 0 && std::chrono::steady_clock::now() < until) {
    ASSERT_TRUE(s.poll(2).ok());
  }
  EXPECT_EQ(p.publish(s, 1, 1, "{}"), 0);
  EXPECT_EQ(p.subscription_count(), 0u);
}

}  // namespace
}  // namespace skinbus::view
