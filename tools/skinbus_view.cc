// skinbus-view: the skin in 3D in a browser. Serves the web view (view/web: the robot from its
// URDF posed by the joint states, the patches on their links, the contacts) on localhost, fed
// from the DDS topics skinbus-host publishes; docs/view.md.
//
//   skinbus-view --map skin.yaml                  # then open http://localhost:8080/
//   skinbus-view --map skin.yaml --port 0 --duration 30
#include <CLI/CLI.hpp>

#include <array>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "skinbus/body_map/joint_map.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/dds/dds.h"
#include "skinbus/host/contacts_json.h"
#include "skinbus/view/field_tap.h"
#include "skinbus/view/foxglove.h"
#include "skinbus/view/foxglove_json.h"
#include "skinbus/view/page_command.h"
#include "skinbus/view/scene_json.h"
#include "skinbus/view/server.h"
#include "tool_util.h"

using namespace skinbus;

namespace {

// Reads the bus into `tap` until stopped: candump -L lines from `candump_path` ("-": standard
// input), or SocketCAN `interfaces`. Ends quietly at the end of a log; a read error is printed.
void read_bus(const std::string& candump_path, const std::vector<std::string>& interfaces,
              view::FieldTap* tap) {
  try {
    if (!candump_path.empty()) {
      std::FILE* in =
          candump_path == "-" ? stdin : tools::open_input_stream(candump_path, "candump log");
      bus::CandumpReader reader(in, /*wait_ms=*/100);
      bus::CandumpRecord rec;
      while (!tools::stop_requested()) {
        const auto st = reader.next(&rec);
        if (st == bus::CandumpReader::Status::kEof) break;
        if (st == bus::CandumpReader::Status::kRecord) {
          tap->feed(rec.frame, rec.has_timestamp ? rec.timestamp_us : bus::realtime_now_us(),
                    rec.iface);
        }
      }
      return;
    }
    bus::SocketCanOptions opts;
    opts.fd = true;
    std::vector<std::unique_ptr<bus::SocketCanPort>> ports;
    bus::CanPoller poller;
    for (const std::string& name : interfaces) {
      auto port = bus::SocketCanPort::open(name, opts);
      if (!port.ok()) throw std::runtime_error(port.error().message);
      if (Status st = poller.add(port->get()); !st.ok())
        throw std::runtime_error(st.error().message);
      ports.push_back(std::move(port).value());
    }
    while (!tools::stop_requested()) {
      auto r = poller.poll(
          50,
          [&](bus::SocketCanPort& port, const bus::CanFrame& f, const bus::RxMeta& meta) {
            tap->feed(f, meta.timestamp_us, port.name());
          },
          [&](bus::SocketCanPort& port, const Error& e) {
            std::fprintf(stderr, "skinbus-view: %s: %s\n", port.name().c_str(), e.message.c_str());
          });
      if (!r.ok()) throw std::runtime_error(r.error().message);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "skinbus-view: the bus: %s (the sensor panel stays empty)\n", e.what());
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-view: the robot skin in 3D, in a web browser. Subscribes to the topics "
      "skinbus-host\n"
      "publishes (rt/skin/contacts, rt/skin/patch_status) and to rt/joint_states, and serves a\n"
      "page over HTTP and WebSocket that draws:\n"
      "  - the robot from the skin map's URDF, posed live by the joint states;\n"
      "  - every patch on its link as the surface it is, coloured by its state;\n"
      "  - every contact at its body-frame position, sized by depth and coloured by force, with\n"
      "    its track ID and a trail; the patches' counters, the events, a stalled-stream banner.\n"
      "The page and its libraries are served from this machine (nothing from the internet);\n"
      "read-only unless --allow-commands (below). Binds to 127.0.0.1: on a robot, open\n"
      "it through an SSH tunnel (docs/guides/web_view.md).\n\n"
      "With -i (or --candump) it also reads the bus: a selected patch's panel shows its 16\n"
      "sensors' field change (tared on the patch) as a heat map with in-plane arrows.\n\n"
      "Examples:\n"
      "  skinbus-view --map skin.yaml                 # http://localhost:8080/\n"
      "  skinbus-view --map skin.yaml -i can0         # and the sensors' fields from can0\n"
      "  ssh -L 8080:localhost:8080 robot            # then open http://localhost:8080/ here\n"
      "  skinbus-view --map skin.yaml --recording out/demo/host.jsonl\n"
      "      # then http://localhost:8080/?replay=/recording.jsonl\n\n"
      "Read-only by default: a page's commands are refused. With --allow-commands, a page on\n"
      "this machine (or through an SSH tunnel, which arrives on it) may tare a patch or set its\n"
      "mode; they go on the bus given with -i, and as candump -L lines to --commands-out.\n\n"
      "Foxglove / Lichtblick: with --foxglove-port it also serves the Foxglove WebSocket\n"
      "protocol (foxglove.websocket.v1, JSON messages) on that port: open Foxglove or\n"
      "Lichtblick, 'Open connection', 'Foxglove WebSocket', ws://localhost:8765. Channels:\n"
      "  /skin/contacts      foxglove.SceneUpdate: a sphere per contact (base frame, sized by\n"
      "                      depth), and every patch as its surface on its link, by state\n"
      "  /tf                 foxglove.FrameTransforms: every link from its parent (URDF, posed\n"
      "                      by the joint states)\n"
      "  /skin/patch_status  skinbus.PatchStatusArray: the host's status, as --json writes it\n"
      "  skinbus-view --map skin.yaml --foxglove-port 8765   # ws://localhost:8765\n"
      "Read-only (no client publishing, parameters or services); loopback only unless\n"
      "--foxglove-bind. docs/foxglove.md.\n\n"
      "Exit status: 0; 1 when DDS, the map or the port failed; 2 on bad arguments."};
  std::string map_path, ns, bind = "127.0.0.1", recording;
  std::string web_root = SKINBUS_VIEW_WEB_DIR;
  int domain = -1, port = 8080, max_pages = 16;
  double duration_s = 0, joint_rate_hz = 30;
  bool quiet = false;
  std::vector<std::string> interfaces;
  std::string candump_path, commands_out;
  bool allow_commands = false;
  int foxglove_port = -1;
  std::string foxglove_bind = "127.0.0.1";
  app.add_option("--map", map_path, "skin map (YAML): the patches and the robot")->required();
  app.add_option("--namespace", ns, "the host's --namespace (topics rt/NS/skin/...)");
  app.add_option("--domain", domain, "DDS domain ID (default: Cyclone DDS's)");
  app.add_option("--port", port, "TCP port (0: any free one, printed)")
      ->capture_default_str()
      ->check(CLI::Range(0, 65535));
  app.add_option("--bind", bind, "IPv4 address to serve on (0.0.0.0: every interface)")
      ->capture_default_str();
  app.add_option("--max-pages", max_pages, "pages connected at once (more get HTTP 503)")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  app.add_option("--joint-rate", joint_rate_hz, "joint states sent to pages at most, Hz")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 1000.0));
  app.add_option("--web-root", web_root, "the page's folder (with node_modules/)")
      ->capture_default_str();
  app.add_option("--recording", recording,
                 "a JSON-lines recording (skinbus-host --json-status, skinbus-listen --status) to "
                 "serve at /recording.jsonl: open /?replay=/recording.jsonl to play it");
  app.add_option("--duration", duration_s, "exit after this many seconds (0: until Ctrl-C)")
      ->capture_default_str();
  app.add_option("-i,--interface", interfaces,
                 "also read this CAN bus (SocketCAN, repeatable) for the sensor panel: each "
                 "patch's 16 sensors' field change while it is pressed");
  app.add_option("--candump", candump_path,
                 "the same from candump -L lines in a file or '-' (standard input)")
      ->excludes("--interface");
  app.add_flag("--allow-commands", allow_commands,
               "let pages on this machine tare a patch or set its mode (needs -i or "
               "--commands-out)");
  app.add_option("--commands-out", commands_out,
                 "also write the commands sent as candump -L lines to this file ('-': standard "
                 "output)");
  app.add_option("--foxglove-port", foxglove_port,
                 "also serve the Foxglove WebSocket protocol (Foxglove, Lichtblick) on this TCP "
                 "port (0: any free one, printed; default: off): contacts and patches as "
                 "foxglove.SceneUpdate on /skin/contacts, the links on /tf, the status on "
                 "/skin/patch_status")
      ->check(CLI::Range(0, 65535));
  app.add_option("--foxglove-bind", foxglove_bind,
                 "IPv4 address the Foxglove port serves on (0.0.0.0: every interface)")
      ->capture_default_str();
  app.add_flag("-q,--quiet", quiet, "no address line, no counters at exit");
  CLI11_PARSE(app, argc, argv);
  constexpr const char* kTool = "skinbus-view";

  if (allow_commands && interfaces.empty() && commands_out.empty()) {
    return tools::fail(kTool, "--allow-commands: give the bus to send on (-i) or --commands-out",
                       2);
  }
  auto map = body_map::load_skin_map_file(map_path);
  if (!map) return tools::report_error(kTool, map.error());
  std::error_code no_throw;
  if (!std::filesystem::is_directory(web_root + "/node_modules/three", no_throw) ||
      !std::filesystem::is_directory(web_root + "/node_modules/urdf-loader", no_throw)) {
    return tools::fail(kTool,
                       "the page's libraries are not installed in " + web_root +
                           "/node_modules (scripts/setup.sh installs them: npm ci in view/web)",
                       1);
  }
  view::ServerOptions options;
  options.bind_address = bind;
  options.port = static_cast<uint16_t>(port);
  options.max_clients = max_pages;
  auto server = view::Server::create(options);
  if (!server) return tools::report_error(kTool, server.error());
  std::string robot_url, base_frame = "base_link";
  std::optional<body_map::RobotModel> robot_model;
  if (!map->robot.empty()) {
    const std::filesystem::path urdf = body_map::path_beside(map_path, map->robot);
    auto robot = body_map::RobotModel::from_urdf_file(urdf.string());
    if (!robot) return tools::report_error(kTool, robot.error());
    base_frame = robot->link(0).name;  // the frame skinbus-host publishes contacts in
    robot_model = std::move(robot).value();
    (*server)->add_folder("/robot/", urdf.parent_path().string());
    robot_url = "/robot/" + urdf.filename().string();
  }
  (*server)->add_folder("/", web_root);
  (*server)->add_folder("/node_modules/", web_root + "/node_modules");
  (*server)->add_document("/api/scene", "application/json",
                          view::scene_to_json(*map, robot_url, base_frame, !allow_commands));
  if (!recording.empty()) {
    std::ifstream in(recording, std::ios::binary);
    std::ostringstream text;
    text << in.rdbuf();
    if (!in.good() && !in.eof()) return tools::fail(kTool, "cannot read " + recording, 2);
    (*server)->add_document("/recording.jsonl", "application/x-ndjson", text.str());
  }

  // The Foxglove WebSocket server (--foxglove-port): a second server on its own port, the same
  // loop. Its channels' messages are made from what the page gets.
  std::unique_ptr<view::Server> fox;
  view::FoxgloveProtocol foxglove("skinbus-view");
  const uint32_t fox_contacts = foxglove.add_channel("/skin/contacts", view::kSceneUpdateSchemaName,
                                                     view::foxglove_scene_update_schema());
  const uint32_t fox_tf = foxglove.add_channel("/tf", view::kFrameTransformsSchemaName,
                                               view::foxglove_frame_transforms_schema());
  const uint32_t fox_status = foxglove.add_channel(
      "/skin/patch_status", view::kPatchStatusSchemaName, view::skinbus_patch_status_schema());
  if (foxglove_port >= 0) {
    view::ServerOptions fo;
    fo.bind_address = foxglove_bind;
    fo.port = static_cast<uint16_t>(foxglove_port);
    fo.max_clients = max_pages;
    auto created = view::Server::create(fo);
    if (!created) return tools::report_error(kTool, created.error());
    fox = std::move(created).value();
    fox->set_stream_path("/");
    fox->set_subprotocol(view::kFoxgloveSubprotocol);
    fox->set_greeting([&] {
      return std::vector<std::string>{foxglove.server_info_json(), foxglove.advertise_json()};
    });
    fox->set_message_handler([&](uint64_t client, std::string_view text, bool /*loopback*/) {
      foxglove.on_message(*fox, client, text);
    });
  }
  // The patches' states in map order, as the last status named them ("" before any).
  std::vector<std::string> patch_states(map->patches.size());
  auto publish_patches = [&](uint64_t stamp_us) {
    foxglove.publish(*fox, fox_contacts, stamp_us * 1000,
                     view::patches_scene_update_json(stamp_us, *map, patch_states));
  };
  std::vector<body_map::Pose> link_poses;
  std::vector<double> q;
  body_map::JointMap joint_map;
  // Every link from its parent at joint positions `names` = `positions` (radians, metres).
  auto publish_tf = [&](uint64_t stamp_us, std::span<const std::string> names,
                        std::span<const double> positions) {
    if (!robot_model) return;
    if (!joint_map.same_source(names, body_map::PrismaticUnit::kMetres)) {
      joint_map = body_map::JointMap(*robot_model, names, body_map::PrismaticUnit::kMetres);
    }
    joint_map.apply(positions, q);
    if (!robot_model->forward_kinematics(q, link_poses).ok()) return;
    foxglove.publish(*fox, fox_tf, stamp_us * 1000,
                     view::frame_transforms_json(stamp_us, *robot_model, link_poses));
  };
  view::ContactSceneEncoder contact_scene;
  std::vector<view::SceneContact> scene_contacts;
  if (fox) {
    if (robot_model) {
      q.assign(robot_model->joint_count(), 0.0);  // the zero pose until joint states arrive
      link_poses.resize(robot_model->link_count());
      publish_tf(bus::realtime_now_us(), {}, {});
    }
    publish_patches(bus::realtime_now_us());
  }

  dds::DdsOptions o;
  if (domain >= 0) o.domain_id = static_cast<uint32_t>(domain);
  if (Status st = dds::apply_namespace(&o, ns); !st.ok()) {
    return tools::fail(kTool, st.error().to_string(), 2);
  }
  auto sub = dds::SkinSubscriber::create(o);
  if (!sub) return tools::report_error(kTool, sub.error());
  auto joints = dds::JointStateSubscriber::create(o);
  if (!joints) return tools::report_error(kTool, joints.error());

  // The latest state a page opened now must see at once.
  std::string last_joint_state, last_status;
  (*server)->set_greeting([&] {
    std::vector<std::string> m{view::hello_to_json(!allow_commands)};
    if (!last_joint_state.empty()) m.push_back(last_joint_state);
    if (!last_status.empty()) m.push_back(last_status);
    return m;
  });
  if (!quiet) {
    // (on standard error when the commands go to standard output)
    std::fprintf(commands_out == "-" ? stderr : stdout,
                 "skinbus-view: serving http://%s:%u/ (%zu patches%s)\n",
                 bind == "0.0.0.0" ? "localhost" : bind.c_str(), (*server)->port(),
                 map->patches.size(), robot_url.empty() ? ", no robot" : "");
    if (fox) {
      std::fprintf(commands_out == "-" ? stderr : stdout,
                   "skinbus-view: serving the Foxglove WebSocket protocol at ws://%s:%u/\n",
                   foxglove_bind == "0.0.0.0" ? "localhost" : foxglove_bind.c_str(), fox->port());
    }
    std::fflush(stdout);
  }

  // Commands from pages: refused unless --allow-commands, and then only from this machine.
  std::unique_ptr<bus::SocketCanPort> command_port;
  if (allow_commands && !interfaces.empty()) {
    bus::SocketCanOptions opts;
    opts.fd = true;
    auto opened = bus::SocketCanPort::open(interfaces.front(), opts);
    if (!opened.ok()) return tools::report_error(kTool, opened.error());
    command_port = std::move(opened).value();
  }
  std::FILE* commands_file = nullptr;
  if (!commands_out.empty()) {
    commands_file = commands_out == "-" ? stdout : std::fopen(commands_out.c_str(), "w");
    if (commands_file == nullptr) return tools::fail(kTool, "cannot write " + commands_out, 2);
  }
  uint8_t command_seq = 0;
  uint64_t commands_sent = 0, commands_refused = 0;
  (*server)->set_message_handler([&](uint64_t page, std::string_view text, bool loopback) {
    auto cmd = view::parse_page_command(text);
    auto answer = [&](bool ok, const std::string& detail) {
      (*server)->send_to(page,
                         view::command_result_to_json(cmd.ok() ? &*cmd : nullptr, ok, detail));
      ok ? ++commands_sent : ++commands_refused;
    };
    if (!cmd.ok()) return answer(false, cmd.error().message);
    if (!allow_commands) {
      return answer(false, "read-only: skinbus-view runs without --allow-commands");
    }
    if (!loopback) return answer(false, "commands are taken from this machine only");
    bus::Message m;
    m.node = cmd->node;
    m.seq = command_seq++;
    m.kind = bus::FrameKind::kFd;
    m.body = cmd->command;
    std::array<bus::CanFrame, 1> frame;
    if (bus::encode(m, frame).frames != 1) return answer(false, "the command did not encode");
    std::string where;
    if (command_port) {
      if (Status st = command_port->send_blocking(frame[0], 100); !st.ok()) {
        return answer(false, "send: " + st.error().message);
      }
      where = "sent on " + interfaces.front();
    }
    if (commands_file != nullptr) {
      const std::string line = bus::format_candump_line(
          frame[0], bus::realtime_now_us(), interfaces.empty() ? "can0" : interfaces.front());
      std::fprintf(commands_file, "%s\n", line.c_str());
      std::fflush(commands_file);
      if (where.empty()) where = "written to " + commands_out;
    }
    if (!quiet) {
      std::fprintf(stderr, "skinbus-view: a page's command: %s to node %d (%s)\n",
                   cmd->name.c_str(), cmd->node, where.c_str());
    }
    answer(true, where);
  });

  tools::install_stop_handler();
  view::FieldTap tap;
  std::thread bus_reader;
  if (!candump_path.empty() || !interfaces.empty()) {
    bus_reader = std::thread(read_bus, candump_path, interfaces, &tap);
  }
  std::vector<std::string> field_updates;
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto joint_period = std::chrono::duration<double>(1.0 / joint_rate_hz);
  auto next_joint = start, next_heartbeat = start;
  std::optional<Clock::time_point> last_host;
  uint64_t contact_arrays = 0, status_arrays = 0;
  dds::JointStateSample js;
  bool joint_pending = false;
  while (!tools::stop_requested()) {
    if (duration_s > 0 && Clock::now() - start > std::chrono::duration<double>(duration_s)) break;
    if (Status st = (*server)->poll(10); !st.ok()) return tools::report_error(kTool, st.error());
    host::ContactArray ca;
    for (;;) {
      auto got = (*sub)->wait_contacts(&ca, 0);
      if (!got.ok() || !*got) break;
      (*server)->broadcast(host::contacts_to_json(ca));
      last_host = Clock::now();
      ++contact_arrays;
      if (fox) {
        scene_contacts.resize(ca.contacts.size());
        for (std::size_t i = 0; i < ca.contacts.size(); ++i) {
          const auto& c = ca.contacts[i];
          auto& s = scene_contacts[i];
          s.track_id = c.track_id;
          std::copy(c.position_mm, c.position_mm + 3, s.position_mm);
          s.depth_mm = c.depth_mm;
          s.force_n = c.force_n;
          s.node = c.node;
          s.link = c.link;
          s.has_shear = (c.flags & host::kContactShear) != 0;
          std::copy(c.shear_n, c.shear_n + 3, s.shear_n);
        }
        foxglove.publish(*fox, fox_contacts, ca.stamp_us * 1000,
                         contact_scene.encode(ca.stamp_us, ca.base_frame, scene_contacts));
      }
    }
    host::PatchStatusArray sa;
    for (;;) {
      auto got = (*sub)->wait_patch_status(&sa, 0);
      if (!got.ok() || !*got) break;
      last_status = host::patch_status_to_json(sa);
      (*server)->broadcast(last_status);
      last_host = Clock::now();
      ++status_arrays;
      if (fox) {
        foxglove.publish(*fox, fox_status, sa.stamp_us * 1000, last_status);
        bool changed = false;
        for (std::size_t i = 0; i < map->patches.size(); ++i) {
          for (const auto& p : sa.patches) {
            if (p.node != map->patches[i].node_id) continue;
            const std::string state(host::patch_link_state_name(p.state));
            changed = changed || state != patch_states[i];
            patch_states[i] = state;
          }
        }
        if (changed) publish_patches(sa.stamp_us);
      }
    }
    // Joint states: the latest, at most joint_rate_hz.
    if ((*joints)->take_latest(&js)) joint_pending = true;
    const auto now = Clock::now();
    if (joint_pending && now >= next_joint) {
      last_joint_state = view::joint_state_to_json(js.stamp_us, js.names, js.positions);
      (*server)->broadcast(last_joint_state);
      if (fox) publish_tf(js.stamp_us, js.names, js.positions);
      joint_pending = false;
      next_joint = now + std::chrono::duration_cast<Clock::duration>(joint_period);
    }
    field_updates.clear();
    tap.take_updates(bus::realtime_now_us(), &field_updates);
    for (const auto& m : field_updates) (*server)->broadcast(m);
    if (now >= next_heartbeat) {
      const int64_t age_ms =
          last_host
              ? std::chrono::duration_cast<std::chrono::milliseconds>(now - *last_host).count()
              : -1;
      (*server)->broadcast(view::heartbeat_to_json(bus::realtime_now_us(), age_ms));
      next_heartbeat = now + std::chrono::seconds(1);
    }
    // The Foxglove clients: what was queued above goes out, their requests are read.
    if (fox) {
      if (Status st = fox->poll(0); !st.ok()) return tools::report_error(kTool, st.error());
    }
  }
  tools::stop_requested() = true;  // ends the bus reader
  if (bus_reader.joinable()) bus_reader.join();
  if (commands_file != nullptr && commands_file != stdout) std::fclose(commands_file);
  if (!quiet) {
    const auto s = (*server)->stats();
    std::fprintf(stderr,
                 "skinbus-view: contact arrays %llu, status arrays %llu; pages connected %llu "
                 "(refused %llu, dropped for not reading %llu, closed for bad frames %llu), page "
                 "messages %llu (commands sent %llu, refused %llu), files %llu, bad requests "
                 "%llu; bus samples %llu, field updates %llu\n",
                 static_cast<unsigned long long>(contact_arrays),
                 static_cast<unsigned long long>(status_arrays),
                 static_cast<unsigned long long>(s.clients_connected),
                 static_cast<unsigned long long>(s.clients_refused),
                 static_cast<unsigned long long>(s.clients_dropped_slow),
                 static_cast<unsigned long long>(s.protocol_errors),
                 static_cast<unsigned long long>(s.client_messages),
                 static_cast<unsigned long long>(commands_sent),
                 static_cast<unsigned long long>(commands_refused),
                 static_cast<unsigned long long>(s.http_requests),
                 static_cast<unsigned long long>(s.http_errors),
                 static_cast<unsigned long long>(tap.stats().samples),
                 static_cast<unsigned long long>(tap.stats().updates));
    if (fox) {
      const auto f = fox->stats();
      std::fprintf(stderr,
                   "skinbus-view: Foxglove clients connected %llu (refused %llu, dropped for not "
                   "reading %llu, closed for bad frames %llu), subscription requests %llu, "
                   "refused %llu, bad requests %llu\n",
                   static_cast<unsigned long long>(f.clients_connected),
                   static_cast<unsigned long long>(f.clients_refused),
                   static_cast<unsigned long long>(f.clients_dropped_slow),
                   static_cast<unsigned long long>(f.protocol_errors),
                   static_cast<unsigned long long>(foxglove.subscribes()),
                   static_cast<unsigned long long>(foxglove.refusals()),
                   static_cast<unsigned long long>(f.http_errors));
    }
  }
  return 0;
}
