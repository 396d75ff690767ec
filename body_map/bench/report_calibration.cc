// The body map's reports (`skinbus-bench calibration | fk`): patch pose calibration's error and
// solve time on simulated sessions, and forward kinematics' time.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "skinbus/body_map/calibration.h"
#include "skinbus/body_map/calibration_sim.h"
#include "skinbus/body_map_bench/reports.h"
#include "skinbus/common/error_format.h"
#include "skinbus/common/plot_script.h"
#include "skinbus/common/stats.h"

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

namespace skinbus::body_map_bench {
namespace {

using namespace skinbus::body_map;
using Clock = std::chrono::steady_clock;
constexpr double kRadToDeg = 180.0 / std::numbers::pi;

}  // namespace

Status bench_calibration(const CalibrationArgs& a) {
  skinbus::Result<RobotModel> robot = RobotModel::from_urdf_file(a.robot);
  if (!robot.ok()) return robot.error();
  skinbus::Result<SkinMap> truth = tile_humanoid(robot.value());
  if (!truth.ok()) return truth.error();
  std::printf(
      "## Patch pose calibration: error and solve time per patch\n\n"
      "%d simulated sessions per row on %s (%zu patches each: cylinder sections on the "
      "forearms, flat on the chest); %.0f%% outlier touches; patch estimates off by %.2g mm "
      "(u, v) and %.2g mm (depth), 1 sd; starting poses %.0f mm and %.0f degrees off; "
      "probe positions in the %s frame.\n\n",
      a.sessions, robot.value().name().c_str(), truth.value().patches.size(), 100 * a.outliers,
      a.estimate_noise, a.depth_noise, a.position_error, a.rotation_error,
      a.base_frame ? "base (random joint positions)" : "link");
  std::printf(
      "| touches | probe noise mm | patches | refused | position mean mm | position p95 mm "
      "| rotation mean deg | rotation p95 deg | sd/error | outliers caught | solve median "
      "ms | solve p95 ms |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  std::FILE* csv = a.csv.empty() ? nullptr : std::fopen(a.csv.c_str(), "w");
  if (!a.csv.empty() && !csv) return errorf(ErrorCode::kIo, "cannot write %s", a.csv.c_str());
  if (csv) {
    std::fprintf(csv,
                 "touches,probe_noise_mm,patches,refused,pos_mean_mm,pos_p95_mm,rot_mean_deg,"
                 "rot_p95_deg,solve_median_ms,solve_p95_ms\n");
  }
  const int rows = static_cast<int>(a.touches.size() * a.noises.size());
  int row = 0;
  for (int n : a.touches) {
    for (double noise : a.noises) {
      std::vector<double> pos, rot, ms, sd_ratio;
      int refused = 0, patches = 0, outliers = 0, caught = 0;
      for (int s = 0; s < a.sessions; ++s) {
        SessionOptions o;
        o.touches_per_patch = n;
        o.probe_noise_mm = noise;
        o.estimate_noise_mm = a.estimate_noise;
        o.estimate_depth_noise_mm = a.depth_noise;
        o.outlier_fraction = a.outliers;
        o.initial_position_error_mm = a.position_error;
        o.initial_rotation_error_deg = a.rotation_error;
        o.base_frame = a.base_frame;
        o.seed = a.seed * 1000003u + static_cast<uint64_t>(s) * 7919u + static_cast<uint64_t>(n);
        skinbus::Result<SimulatedSession> session =
            simulate_calibration_session(robot.value(), truth.value(), o);
        if (!session.ok()) return session.error();
        CalibrationOptions co;
        co.probe_sigma_mm = noise;
        co.estimate_sigma_mm = a.estimate_noise;
        co.estimate_depth_sigma_mm = a.depth_noise;
        for (const PatchPlacement& start : session.value().initial.patches) {
          skinbus::Result<std::vector<CalibrationTouch>> t =
              link_frame_touches(session.value().log, start, &robot.value());
          if (!t.ok()) return t.error();
          const auto t0 = Clock::now();
          skinbus::Result<PatchCalibration> c = calibrate_patch(start, t.value(), co);
          ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
          ++patches;
          if (!c.ok()) {
            ++refused;
            continue;
          }
          const PatchPlacement& p = *session.value().truth.find_node(start.node_id);
          const double e_pos =
              (c.value().pose_on_link.translation_mm - p.pose_on_link.translation_mm).norm();
          pos.push_back(e_pos);
          rot.push_back(
              rotation_angle_between(c.value().pose_on_link.rotation, p.pose_on_link.rotation) *
              kRadToDeg);
          sd_ratio.push_back(c.value().uncertainty.position_sd_mm.norm());
          // Outliers of this patch caught.
          int k = 0;
          for (std::size_t r = 0; r < session.value().log.touches.size(); ++r) {
            if (session.value().log.touches[r].node_id != start.node_id) continue;
            if (session.value().outlier[r]) {
              ++outliers;
              caught += c.value().residuals[k].outlier;
            }
            ++k;
          }
        }
      }
      // How honest the reported uncertainty is: rms error / rms reported sd (1 = honest).
      double e2 = 0, s2 = 0;
      for (std::size_t i = 0; i < pos.size(); ++i) {
        e2 += pos[i] * pos[i];
        s2 += sd_ratio[i] * sd_ratio[i];
      }
      const double honesty = pos.empty() ? NAN : std::sqrt(e2 / s2);
      std::printf(
          "| %d | %.1f | %d | %d | %.3f | %.3f | %.3f | %.3f | %.2f | %d/%d | %.2f | %.2f |\n", n,
          noise, patches, refused, mean(pos), quantile(pos, 0.95), mean(rot), quantile(rot, 0.95),
          honesty, caught, outliers, quantile(ms, 0.5), quantile(ms, 0.95));
      std::fflush(stdout);
      std::fprintf(stderr, "[%d/%d] %d touches, probe noise %.1f mm done\n", ++row, rows, n, noise);
      if (csv) {
        std::fprintf(csv, "%d,%.3f,%d,%d,%.5f,%.5f,%.5f,%.5f,%.4f,%.4f\n", n, noise, patches,
                     refused, mean(pos), quantile(pos, 0.95), mean(rot), quantile(rot, 0.95),
                     quantile(ms, 0.5), quantile(ms, 0.95));
      }
    }
  }
  std::printf(
      "\nsd/error: rms position error over rms reported position sd (1: the covariance "
      "is honest). Goals: 0.5 mm and 0.3 degrees from 30 touches at 0.5 mm probe noise; "
      "20 ms per patch.\n");
  if (csv) std::fclose(csv);
  if (!a.plot.empty()) {
    if (a.csv.empty()) return make_error(ErrorCode::kInvalidArgument, "--plot needs --csv");
    return run_plot_script(SKINBUS_SOURCE_DIR "/tools", "plot_calibration_bench.py",
                           {a.csv, a.plot});
  }
  return Status::Ok();
}

Status bench_fk(const std::string& path, int calls) {
  skinbus::Result<RobotModel> robot = RobotModel::from_urdf_file(path);
  if (!robot.ok()) return robot.error();
  const RobotModel& r = robot.value();
  std::vector<double> q(r.joint_count());
  std::vector<Pose> poses(r.link_count());
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<double> us;
  for (int rep = 0; rep < 7; ++rep) {
    for (double& x : q) x = u(rng);
    const auto t0 = Clock::now();
    for (int i = 0; i < calls; ++i) {
      q[i % q.size()] += 1e-9;
      if (Status s = r.forward_kinematics(q, poses); !s.ok()) return s;
    }
    us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count() / calls);
  }
  std::printf(
      "## Forward kinematics\n\n| robot | links | joints | all links, us (median of 7) | "
      "per link, ns |\n|---|---|---|---|---|\n| %s | %d | %d | %.3f | %.1f |\n",
      r.name().c_str(), r.link_count(), r.joint_count(), quantile(us, 0.5),
      1000 * quantile(us, 0.5) / r.link_count());
  return Status::Ok();
}

}  // namespace skinbus::body_map_bench
