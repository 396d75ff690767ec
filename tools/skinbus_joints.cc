// skinbus-joints: publishes joint states on DDS (rt/joint_states, ROS 2 sensor_msgs/JointState)
// from a joint trajectory file, as a simulated robot would.
//
//   skinbus-joints --trajectory arms.csv                      # 100 Hz, holds the last row
//   skinbus-joints --trajectory arms.csv --duration 2.5       # then the stream stops
//   skinbus-joints --trajectory arms.csv --robot skinbot.urdf --domain 5 --wait-match 20

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "skinbus/body_map/joint_map.h"
#include "skinbus/body_map/joint_trajectory.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/bus/socketcan.h"
#include "skinbus/dds/dds.h"
#include "tool_util.h"

using namespace skinbus;

namespace {

constexpr int kExitFailed = 1;  // a file, DDS, or no subscriber within --wait-match
constexpr int kExitUsage = 2;   // bad arguments
constexpr auto kSlice = std::chrono::milliseconds(50);  // how often sleeps look at Ctrl-C

// Sleeps until `t` in slices, so that SIGINT / SIGTERM end the tool promptly. False if a stop
// was requested.
bool sleep_until(std::chrono::steady_clock::time_point t) {
  while (!tools::stop_requested()) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= t) return true;
    std::this_thread::sleep_for(std::min<std::chrono::steady_clock::duration>(t - now, kSlice));
  }
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-joints: publishes joint states on DDS as a simulated robot would, from a joint\n"
      "trajectory file (CSV: time_s,<joint>,...; docs/aggregator.md), on rt/joint_states in the\n"
      "layout of ROS 2's sensor_msgs/JointState (names and positions; velocity, effort and\n"
      "frame_id empty), reliable, volatile, keep last 10, which skinbus-host --joints dds and a\n"
      "default ROS 2 subscription read.\n\n"
      "Time zero is the start of publishing: the tool's start, or with --wait-match the moment a\n"
      "subscriber matched. At --rate the positions at the time since then (interpolated between\n"
      "rows, as skinbus-host --joints FILE and skinbus-locate --joints do) are published, stamped\n"
      "with CLOCK_REALTIME. After the last row the tool keeps publishing it until Ctrl-C or\n"
      "SIGTERM; --duration stops it earlier or later (the stream then simply ends).\n\n"
      "Units: the file's numbers are radians for revolute joints and millimetres for prismatic\n"
      "ones (as body_map uses them); on the wire ROS 2 wants metres. Without --robot the tool\n"
      "knows no joint types and publishes every number as it is: right for revolute and\n"
      "continuous joints, but a prismatic joint's column would go out in millimetres. With\n"
      "--robot URDF the prismatic columns are divided by 1000, and every column must name a\n"
      "movable joint of that robot.\n\n"
      "On stderr: the time zero and, at the end, the stamp of the last sample, both "
      "CLOCK_REALTIME\n"
      "microseconds. The network is Cyclone DDS's: CYCLONEDDS_URI (docs/dds.md). ROS_DOMAIN_ID is\n"
      "not read: use --domain.\n\n"
      "Exit status: 0 when --duration was reached or on Ctrl-C / SIGTERM, 1 when a file could not\n"
      "be read, DDS failed or no subscriber matched within --wait-match, 2 on bad arguments.\n\n"
      "Examples:\n"
      "  skinbus-joints --trajectory arms.csv\n"
      "  skinbus-joints --trajectory arms.csv --robot skinbot.urdf --domain 5 --wait-match 20 \\\n"
      "      --duration 2.5 &\n"
      "  skinbus-host --map skin.yaml -i can0 --joints dds --domain 5"};
  std::string trajectory_path, robot_path;
  double rate_hz = 100, duration_s = 0, wait_match_s = -1;
  int domain = -1;
  bool quiet = false;
  dds::DdsOptions options;
  app.add_option("--trajectory", trajectory_path, "joint trajectory (CSV: time_s,<joint>,...)")
      ->required();
  app.add_option("--robot", robot_path,
                 "robot (URDF): publish its prismatic joints' columns in metres (the file has mm) "
                 "and refuse columns that are not its movable joints");
  app.add_option("--rate", rate_hz, "samples a second")
      ->check(CLI::Range(0.1, 10000.0))
      ->capture_default_str();
  app.add_option("--duration", duration_s,
                 "stop after this many seconds from time zero (0: run until Ctrl-C / SIGTERM, "
                 "holding the last row after the trajectory's end)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--domain", domain, "DDS domain id 0..232 (default: CYCLONEDDS_URI's, else 0)")
      ->check(CLI::Range(0, 232));
  app.add_option("--wait-match", wait_match_s,
                 "first wait up to SECONDS until a joint-state subscriber is matched (exit 1 if "
                 "none); time zero is then the match")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--topic", options.joint_states_topic, "DDS topic")->capture_default_str();
  app.add_flag("-q,--quiet", quiet, "print only errors");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : kExitUsage;  // --help: 0
  }
  if (domain >= 0) options.domain_id = static_cast<uint32_t>(domain);

  auto traj = body_map::load_joint_trajectory(trajectory_path);
  if (!traj.ok()) {
    return skinbus::tools::fail("skinbus-joints", traj.error().to_string(), kExitFailed);
  }
  // Per column: the factor from the file's unit to the wire's (1e-3 for prismatic joints).
  std::vector<double> scale(traj->names.size(), 1.0);
  if (!robot_path.empty()) {
    auto robot = body_map::RobotModel::from_urdf_file(robot_path);
    if (!robot.ok()) {
      return skinbus::tools::fail("skinbus-joints", robot.error().to_string(), kExitFailed);
    }
    const body_map::JointMap wire(*robot, traj->names, body_map::PrismaticUnit::kMetres);
    if (Status st = wire.check_all_joints(); !st.ok()) {
      return skinbus::tools::fail("skinbus-joints", trajectory_path + ": " + st.error().message,
                                  kExitUsage);
    }
    for (std::size_t i = 0; i < traj->names.size(); ++i) scale[i] = 1.0 / wire.to_model(i);
  }

  tools::install_stop_handler();
  auto pub = dds::JointStatePublisher::create(options);
  if (!pub.ok()) {
    return skinbus::tools::fail("skinbus-joints", pub.error().to_string(), kExitFailed);
  }
  using Clock = std::chrono::steady_clock;
  if (wait_match_s >= 0) {
    const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(wait_match_s));
    for (;;) {
      auto n = (*pub)->matched_subscribers();
      if (!n.ok()) {
        return skinbus::tools::fail("skinbus-joints", n.error().to_string(), kExitFailed);
      }
      if (*n > 0) break;
      if (Clock::now() >= deadline) {
        return skinbus::tools::fail("skinbus-joints",
                                    "no subscriber of " + options.joint_states_topic +
                                        " matched within " +
                                        skinbus::tools::format_g(wait_match_s) + " s",
                                    kExitFailed);
      }
      if (!sleep_until(std::min(deadline, Clock::now() + std::chrono::milliseconds(20)))) {
        return 0;  // Ctrl-C before anything was published
      }
    }
    if (!quiet) {
      std::fprintf(stderr, "skinbus-joints: matched a subscriber of %s\n",
                   options.joint_states_topic.c_str());
    }
  }

  const double end_s = traj->t_s.back();
  const auto period =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate_hz));
  const Clock::time_point t0 = Clock::now();
  const uint64_t t0_us = bus::realtime_now_us();
  if (!quiet) {
    std::string names;
    for (const std::string& n : traj->names) names += (names.empty() ? "" : ", ") + n;
    char until[64] = "holding the last row until stopped";
    if (duration_s > 0) std::snprintf(until, sizeof until, "stopping at %g s", duration_s);
    std::fprintf(stderr,
                 "skinbus-joints: publishing %zu joint(s) (%s) on %s at %g Hz; the trajectory "
                 "lasts %g s; %s\n",
                 traj->names.size(), names.c_str(), options.joint_states_topic.c_str(), rate_hz,
                 end_s, until);
    std::fprintf(stderr, "skinbus-joints: time zero %" PRIu64 " us (CLOCK_REALTIME)\n", t0_us);
  }

  std::vector<double> q(traj->names.size());
  uint64_t published = 0, dropped = 0, last_stamp_us = 0;
  for (int64_t k = 0;; ++k) {
    const double tk_s = static_cast<double>(k) / rate_hz;
    if (duration_s > 0 && tk_s > duration_s + 1e-9) break;
    if (!sleep_until(t0 + k * period)) break;
    const Clock::time_point now = Clock::now();
    // Fell behind by more than a period (a stall): skip the missed ticks instead of bursting.
    if (now - (t0 + k * period) > period) {
      k = static_cast<int64_t>((now - t0) / period);
      if (duration_s > 0 && static_cast<double>(k) / rate_hz > duration_s + 1e-9) break;
    }
    const double t_s = std::chrono::duration<double>(now - t0).count();
    traj->sample(t_s, q);
    for (std::size_t i = 0; i < q.size(); ++i) q[i] *= scale[i];
    const uint64_t stamp_us = bus::realtime_now_us();
    const Status st = (*pub)->publish(traj->names, q, stamp_us);
    if (st.ok()) {
      ++published;
      last_stamp_us = stamp_us;
    } else if (st.error().code == ErrorCode::kUnavailable) {
      ++dropped;  // a reliable subscriber lagged: this sample is lost, the next goes out
      if (dropped == 1 || dropped % 100 == 0) {
        std::fprintf(stderr, "skinbus-joints: %s (%" PRIu64 " dropped so far)\n",
                     st.error().to_string().c_str(), dropped);
      }
    } else {
      return skinbus::tools::fail("skinbus-joints", st.error().to_string(), kExitFailed);
    }
  }
  if (!quiet) {
    std::fprintf(stderr,
                 "skinbus-joints: published %" PRIu64 " samples (%" PRIu64
                 " dropped), the last stamped %" PRIu64 " us (CLOCK_REALTIME)\n",
                 published, dropped, last_stamp_us);
  }
  return 0;
}
