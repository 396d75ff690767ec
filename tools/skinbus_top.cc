// skinbus-top: a live terminal view of the skin: the robot seen from the front with its patches
// and the contacts on them, a table of every patch's state and activity, the current contacts and
// the latest events. Reads the DDS topics skinbus-host publishes (and rt/joint_states, to draw
// the arms where they are).
//
//   skinbus-top --map skin.yaml
//   skinbus-top --map skin.yaml --frames 1 --after 5 --plain     # one frame after 5 s, no ANSI
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "skinbus/body_map/joint_map.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/dds/dds.h"
#include "skinbus/host/contacts.h"
#include "skinbus/host/contacts_json.h"
#include "tool_util.h"

using namespace skinbus;

namespace {

// A character canvas; (0, 0) is the top left.
class Canvas {
 public:
  Canvas(int w, int h) : w_(w), h_(h), cells_(static_cast<std::size_t>(w * h), ' ') {}
  void put(int x, int y, char c) {
    if (x >= 0 && x < w_ && y >= 0 && y < h_) cells_[static_cast<std::size_t>(y * w_ + x)] = c;
  }
  void text(int x, int y, const std::string& s) {
    for (std::size_t i = 0; i < s.size(); ++i) put(x + static_cast<int>(i), y, s[i]);
  }
  char at(int x, int y) const { return cells_[static_cast<std::size_t>(y * w_ + x)]; }
  std::string row(int y) const {
    std::string r(cells_.begin() + y * w_, cells_.begin() + (y + 1) * w_);
    while (!r.empty() && r.back() == ' ') r.pop_back();
    return r;
  }
  int width() const { return w_; }
  int height() const { return h_; }

 private:
  int w_, h_;
  std::vector<char> cells_;
};

struct View {
  const body_map::SkinMap& map;
  const body_map::RobotModel* robot;
  std::vector<double> q;
  host::ContactArray contacts;
  host::PatchStatusArray status;
  std::vector<host::PatchEvent> events;  // newest last
  uint64_t contact_arrays = 0, status_arrays = 0;
};

// The robot seen from the front (looking along -x): screen right is the robot's +y, up is +z.
void draw_body(const View& v, Canvas& c) {
  std::vector<body_map::Pose> poses;
  if (v.robot != nullptr) {
    poses.resize(static_cast<std::size_t>(v.robot->link_count()));
    if (!v.robot->forward_kinematics(v.q, poses).ok()) poses.clear();
  }
  auto link_pose = [&](const std::string& name) -> body_map::Pose {
    if (v.robot == nullptr || poses.empty()) return {};
    const int l = v.robot->find_link(name);
    return l >= 0 ? poses[static_cast<std::size_t>(l)] : body_map::Pose{};
  };
  // Points to fit: link origins and patch centres.
  std::vector<Eigen::Vector3d> pts;
  for (const body_map::Pose& p : poses) pts.push_back(p.translation_mm);
  std::vector<Eigen::Vector3d> centres;
  for (const body_map::PatchPlacement& p : v.map.patches) {
    centres.push_back(link_pose(p.link).apply(body_map::link_surface_point(p, 0, 0, 0).point_mm));
    pts.push_back(centres.back());
  }
  if (pts.empty()) return;
  double y0 = 1e300, y1 = -1e300, z0 = 1e300, z1 = -1e300;
  for (const auto& p : pts) {
    y0 = std::min(y0, p.y());
    y1 = std::max(y1, p.y());
    z0 = std::min(z0, p.z());
    z1 = std::max(z1, p.z());
  }
  // Terminal cells are about twice as tall as wide.
  const double span = std::max({y1 - y0, 2 * (z1 - z0), 1.0});
  const double scale = (c.width() - 4) / span;
  const double yc = 0.5 * (y0 + y1), zc = 0.5 * (z0 + z1);
  auto to_screen = [&](const Eigen::Vector3d& p, int* x, int* y) {
    *x = static_cast<int>(std::lround(c.width() / 2.0 + (p.y() - yc) * scale));
    *y = static_cast<int>(std::lround(c.height() / 2.0 - (p.z() - zc) * scale / 2));
  };
  // Links: a dotted line from each link's origin to its parent's.
  if (v.robot != nullptr && !poses.empty()) {
    for (int l = 1; l < v.robot->link_count(); ++l) {
      const int parent = v.robot->link(l).parent;
      const Eigen::Vector3d a = poses[static_cast<std::size_t>(parent)].translation_mm;
      const Eigen::Vector3d b = poses[static_cast<std::size_t>(l)].translation_mm;
      for (int k = 0; k <= 20; ++k) {
        int x, y;
        to_screen(a + (b - a) * (k / 20.0), &x, &y);
        c.put(x, y, '.');
      }
    }
  }
  // Patches: their node ID at their centre; a touched patch in brackets.
  std::map<int, bool> touched;
  for (const host::BodyContact& ct : v.contacts.contacts) touched[ct.node] = true;
  for (std::size_t i = 0; i < v.map.patches.size(); ++i) {
    int x, y;
    to_screen(centres[i], &x, &y);
    const int node = v.map.patches[i].node_id;
    const std::string label =
        touched.count(node) ? "[" + std::to_string(node) + "]" : std::to_string(node);
    c.text(x - static_cast<int>(label.size()) / 2, y, label);
  }
  // Contacts: '@' where they are.
  for (const host::BodyContact& ct : v.contacts.contacts) {
    int x, y;
    to_screen(Eigen::Vector3d(ct.position_mm[0], ct.position_mm[1], ct.position_mm[2]), &x, &y);
    c.put(x, y, '@');
  }
}

std::string render(const View& v, int width, int height) {
  std::string out;
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "skinbus-top  %zu patches in the map, %zu heard, %zu contacts  (contact arrays "
                "%" PRIu64 ", status %" PRIu64 ")\n",
                v.map.patches.size(), v.status.patches.size(), v.contacts.contacts.size(),
                v.contact_arrays, v.status_arrays);
  out += buf;
  Canvas c(width, height);
  draw_body(v, c);
  for (int y = 0; y < c.height(); ++y) out += "  " + c.row(y) + "\n";
  out += "  front view: patches by node ID, [n] touched, @ contact, . links\n\n";
  out += " node  link                   state        samples   contacts  lost  reboots  detail\n";
  for (const host::PatchStatus& p : v.status.patches) {
    std::snprintf(buf, sizeof buf,
                  " %4u  %-22.22s %-11s %8" PRIu64 " %10" PRIu64 " %5" PRIu64 " %8u  %.40s\n",
                  p.node, p.link.c_str(), std::string(host::patch_link_state_name(p.state)).c_str(),
                  p.samples, p.contacts, p.samples_lost, p.reboots, p.detail.c_str());
    out += buf;
  }
  out += "\n track  node  link                   x_mm     y_mm     z_mm   depth  force  flags\n";
  for (const host::BodyContact& ct : v.contacts.contacts) {
    std::string flags;
    for (const std::string& f : host::contact_flag_names(ct.flags)) flags += f + " ";
    std::snprintf(buf, sizeof buf, " %5u  %4u  %-22.22s %7.1f  %7.1f  %7.1f  %5.2f  %5.2f  %s\n",
                  ct.track_id, ct.node, ct.link.c_str(), ct.position_mm[0], ct.position_mm[1],
                  ct.position_mm[2], ct.depth_mm, ct.force_n, flags.c_str());
    out += buf;
  }
  out += "\n recent events\n";
  const std::size_t first = v.events.size() > 6 ? v.events.size() - 6 : 0;
  for (std::size_t i = first; i < v.events.size(); ++i) {
    out += "  " + std::string(host::patch_event_name(v.events[i].kind)) + ": " +
           v.events[i].detail.substr(0, 100) + "\n";
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-top: a live terminal view of the robot skin. Subscribes to the topics skinbus-host\n"
      "publishes (rt/skin/contacts, rt/skin/patch_status) and to rt/joint_states, and redraws:\n"
      "  - the robot seen from the front (its links from forward kinematics at the newest joint\n"
      "    state), each patch as its node ID at its centre, [n] when touched, @ at each contact;\n"
      "  - every patch heard: state, samples, contacts, lost samples, reboots, why degraded;\n"
      "  - the current contacts (track, link, base-frame position, depth, force, flags);\n"
      "  - the latest events (patches appearing, going stale, rebooting, duplicate IDs, ...).\n"
      "The skin map gives the patches and the robot (docs/body_map.md).\n\n"
      "Examples:\n"
      "  skinbus-top --map skin.yaml\n"
      "  skinbus-top --map skin.yaml --frames 1 --after 5 --plain > frame.txt\n\n"
      "Exit status: 0, 1 when DDS or the map failed, 2 on bad arguments."};
  std::string map_path;
  int domain = -1, frames = 0, width = 72, height = 24;
  double period_s = 0.25, after_s = 0;
  bool plain = false;
  std::string ns;
  app.add_option("--map", map_path, "skin map (YAML)")->required();
  app.add_option("--namespace", ns, "the host's --namespace (topics rt/NS/skin/...)");
  app.add_option("--domain", domain, "DDS domain ID (default: Cyclone DDS's)");
  app.add_option("--period", period_s, "seconds between redraws")
      ->capture_default_str()
      ->check(CLI::Range(0.02, 60.0));
  app.add_option("--frames", frames, "exit after this many frames (0: run until Ctrl-C)")
      ->capture_default_str();
  app.add_option("--after", after_s, "draw the first frame only after this many seconds")
      ->capture_default_str();
  app.add_flag("--plain", plain, "no screen clearing: frames one after another (logs, tests)");
  app.add_option("--width", width, "body view width, characters")
      ->capture_default_str()
      ->check(CLI::Range(20, 400));
  app.add_option("--height", height, "body view height, lines")
      ->capture_default_str()
      ->check(CLI::Range(8, 200));
  CLI11_PARSE(app, argc, argv);

  auto map = body_map::load_skin_map_file(map_path);
  if (!map) {
    return skinbus::tools::fail("skinbus-top", map.error().to_string(), 1);
  }
  std::unique_ptr<body_map::RobotModel> robot;
  if (!map->robot.empty()) {
    auto r = body_map::RobotModel::from_urdf_file(body_map::path_beside(map_path, map->robot));
    if (!r) {
      return skinbus::tools::fail("skinbus-top", r.error().to_string(), 1);
    }
    robot = std::make_unique<body_map::RobotModel>(std::move(*r));
  }
  dds::DdsOptions o;
  if (domain >= 0) o.domain_id = static_cast<uint32_t>(domain);
  if (Status st = dds::apply_namespace(&o, ns); !st.ok()) {
    return skinbus::tools::fail("skinbus-top", st.error().to_string(), 2);
  }
  auto sub = dds::SkinSubscriber::create(o);
  auto joints = dds::JointStateSubscriber::create(o);
  if (!sub || !joints) {
    return skinbus::tools::fail("skinbus-top", (!sub ? sub.error() : joints.error()).to_string(),
                                1);
  }
  View v{*map, robot.get(), {}, {}, {}, {}, 0, 0};
  body_map::JointMap joint_map;  // the joint states' names onto q
  if (robot) v.q.assign(static_cast<std::size_t>(robot->joint_count()), 0.0);
  tools::install_stop_handler();
  const auto start = std::chrono::steady_clock::now();
  auto next = start + std::chrono::duration<double>(after_s);
  int drawn = 0;
  while (!tools::stop_requested()) {
    // Take everything that arrived; keep the newest contacts and status, all events.
    host::ContactArray ca;
    for (;;) {
      auto got = (*sub)->wait_contacts(&ca, 0);
      if (!got.ok() || !*got) break;
      v.contacts = std::move(ca);
      ++v.contact_arrays;
    }
    host::PatchStatusArray sa;
    for (;;) {
      auto got = (*sub)->wait_patch_status(&sa, 0);
      if (!got.ok() || !*got) break;
      v.events.insert(v.events.end(), sa.events.begin(), sa.events.end());
      if (v.events.size() > 100) v.events.erase(v.events.begin(), v.events.end() - 100);
      v.status = std::move(sa);
      ++v.status_arrays;
    }
    dds::JointStateSample js;
    if (robot && (*joints)->take_latest(&js)) {
      // ROS 2 joint states: prismatic joints in metres.
      if (!joint_map.same_source(js.names, body_map::PrismaticUnit::kMetres)) {
        joint_map = body_map::JointMap(*robot, js.names, body_map::PrismaticUnit::kMetres);
      }
      joint_map.apply(js.positions, v.q);
    }
    if (std::chrono::steady_clock::now() >= next) {
      const std::string frame = render(v, width, height);
      if (!plain) std::fputs("\x1b[H\x1b[2J", stdout);
      std::fputs(frame.c_str(), stdout);
      if (plain) std::fputs("\n", stdout);
      std::fflush(stdout);
      next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(
          std::chrono::duration<double>(period_s));
      if (frames > 0 && ++drawn >= frames) break;
    }
    (void)(*sub)->wait_any(20);
  }
  return 0;
}
