// skinbus-bench: speed and accuracy of the project's estimators and stages, measured on the same
// data in one run. Prints Markdown tables; --csv / --plot write the numbers and a figure.
//
//   skinbus-bench calibration --plot docs/benchmarks/calibration.png
//   skinbus-bench fk --robot ../shared/robots/unitree_g1/g1_29dof.urdf
//   skinbus-bench models --test test.csv --train train.csv --model models/nominal_seed_cnn
#include <CLI/CLI.hpp>

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

#include "bench_ambient.h"
#include "bench_host.h"
#include "bench_models.h"
#include "skinbus/body_map/calibration.h"
#include "skinbus/body_map/calibration_sim.h"
#include "tool_util.h"

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

namespace {

using namespace skinbus::body_map;
using Clock = std::chrono::steady_clock;
using skinbus::tools::mean;
using skinbus::tools::quantile;
constexpr double kRadToDeg = 180.0 / std::numbers::pi;

std::string tools_dir() {
  const char* d = std::getenv("SKINBUS_TOOLS_DIR");
  return d ? d : SKINBUS_SOURCE_DIR "/tools";
}

int fail(const std::string& m) {
  std::fprintf(stderr, "skinbus-bench: %s\n", m.c_str());
  return 1;
}

struct CalibrationArgs {
  std::string robot = SKINBUS_SOURCE_DIR "/body_map/robots/skinbot.urdf";
  std::vector<int> touches = {10, 20, 30, 60};
  std::vector<double> noises = {0.2, 0.5, 1.0};
  int sessions = 30;
  double estimate_noise = 0.5, depth_noise = 0.1, outliers = 0.1;
  double position_error = 20, rotation_error = 30;
  bool base_frame = false;
  uint64_t seed = 1;
  std::string csv, plot;
};

int bench_calibration(const CalibrationArgs& a) {
  skinbus::Result<RobotModel> robot = RobotModel::from_urdf_file(a.robot);
  if (!robot.ok()) return fail(robot.error().to_string());
  skinbus::Result<SkinMap> truth = tile_humanoid(robot.value());
  if (!truth.ok()) return fail(truth.error().to_string());
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
  if (!a.csv.empty() && !csv) return fail("cannot write " + a.csv);
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
        if (!session.ok()) return fail(session.error().to_string());
        CalibrationOptions co;
        co.probe_sigma_mm = noise;
        co.estimate_sigma_mm = a.estimate_noise;
        co.estimate_depth_sigma_mm = a.depth_noise;
        for (const PatchPlacement& start : session.value().initial.patches) {
          skinbus::Result<std::vector<CalibrationTouch>> t =
              link_frame_touches(session.value().log, start, &robot.value());
          if (!t.ok()) return fail(t.error().to_string());
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
    if (a.csv.empty()) return fail("--plot needs --csv");
    const std::string cmd =
        "'" + tools_dir() + "/plot_calibration_bench.py' '" + a.csv + "' '" + a.plot + "'";
    if (std::system(cmd.c_str()) != 0) return fail("the plot failed: " + cmd);
  }
  return 0;
}

int bench_fk(const std::string& path, int calls) {
  skinbus::Result<RobotModel> robot = RobotModel::from_urdf_file(path);
  if (!robot.ok()) return fail(robot.error().to_string());
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
      if (!r.forward_kinematics(q, poses).ok()) return fail("forward kinematics failed");
    }
    us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count() / calls);
  }
  std::printf(
      "## Forward kinematics\n\n| robot | links | joints | all links, us (median of 7) | "
      "per link, ns |\n|---|---|---|---|---|\n| %s | %d | %d | %.3f | %.1f |\n",
      r.name().c_str(), r.link_count(), r.joint_count(), quantile(us, 0.5),
      1000 * quantile(us, 0.5) / r.link_count());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-bench: run time and error of the project's estimators and stages,\n"
      "measured together on the same data. One subcommand per stage; each prints a\n"
      "Markdown table (docs/benchmarks/ keeps the results and the commands).\n"};
  app.require_subcommand(1);
  CalibrationArgs ca;
  CLI::App* cal = app.add_subcommand(
      "calibration",
      "patch pose calibration on simulated sessions: pose error and solve time per patch against "
      "touches per patch and probe noise");
  cal->add_option("--robot", ca.robot, "robot (URDF) tiled by the default humanoid layout")
      ->capture_default_str();
  cal->add_option("--touches", ca.touches, "touches per patch")
      ->delimiter(',')
      ->capture_default_str();
  cal->add_option("--noise", ca.noises, "probe noise levels, mm")
      ->delimiter(',')
      ->capture_default_str();
  cal->add_option("--sessions", ca.sessions, "sessions per row (each calibrates every patch)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cal->add_option("--estimate-noise", ca.estimate_noise, "patch estimate error in u, v, mm")
      ->capture_default_str();
  cal->add_option("--depth-noise", ca.depth_noise, "patch estimate error in depth, mm")
      ->capture_default_str();
  cal->add_option("--outliers", ca.outliers, "fraction of outlier touches")->capture_default_str();
  cal->add_option("--position-error", ca.position_error, "starting poses this far off, mm")
      ->capture_default_str();
  cal->add_option("--rotation-error", ca.rotation_error, "... and turned this much, degrees")
      ->capture_default_str();
  cal->add_flag("--base-frame", ca.base_frame, "probe positions in the base frame (via FK)");
  cal->add_option("--seed", ca.seed, "random seed")->capture_default_str();
  cal->add_option("--csv", ca.csv, "write the table as CSV");
  cal->add_option("--plot", ca.plot, "draw error and time against touches (PNG; needs --csv)");
  std::string fk_robot = SKINBUS_SOURCE_DIR "/body_map/robots/skinbot.urdf";
  int fk_calls = 200000;
  CLI::App* fk = app.add_subcommand("fk", "forward kinematics of every link of a robot: time");
  fk->add_option("--robot", fk_robot, "robot description (URDF)")->capture_default_str();
  fk->add_option("--calls", fk_calls, "calls per repetition")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000000));
  skinbus::tools::ModelsBenchArgs ma;
  CLI::App* models = app.add_subcommand(
      "models",
      "per-patch estimators (networks on the host runtime, LibTorch reference, nearest-neighbour "
      "lookup, physics LM): latency, throughput and error per depth bin against the CRLB");
  skinbus::tools::add_models_options(models, ma);
  skinbus::tools::BudgetBenchArgs ba;
  skinbus::tools::CpuBenchArgs cpua;
  CLI::App* cpu = app.add_subcommand(
      "cpu",
      "one network (default: the shipped seed CNN) on every kernel set this CPU has (AVX-512, "
      "AVX2, NEON, portable), float32 and int8: batch 1 and batched on 1 and 2 threads against the "
      "FMA peak measured here, LibTorch at its best, and the errors on the same presses");
  skinbus::tools::add_cpu_options(cpu, cpua);
  CLI::App* budget = app.add_subcommand(
      "budget",
      "accuracy from one unit's 361 presses (the seed's robot-time budget): the seed recipe "
      "against the physics pipeline, per simulated unit, off-grid and at grid points");
  skinbus::tools::add_budget_options(budget, ba);
  skinbus::tools::AmbientBenchArgs aa;
  CLI::App* ambient = app.add_subcommand(
      "ambient",
      "a per-patch model's error when the ambient field turns between tare and press (a limb "
      "moving in the Earth's field), with and without common-mode rejection");
  skinbus::tools::add_ambient_options(ambient, aa);
  skinbus::tools::HostBenchArgs ha;
  CLI::App* host = app.add_subcommand(
      "host",
      "the host aggregator: latency from frame arrival to publication and CPU use for 16, 64 "
      "and 200 patches with 100, 10 and 0 % touched, and host time per idle patch");
  skinbus::tools::add_host_options(host, ha);
#ifdef SKINBUS_HAVE_TORCH
  skinbus::tools::FinetuneBenchArgs fa;
  CLI::App* finetune = app.add_subcommand(
      "finetune",
      "a new unit's error against the presses spent on it: fine-tuning a base network vs "
      "identifying the unit's physics from the same presses");
  skinbus::tools::add_finetune_options(finetune, fa);
#endif
  CLI11_PARSE(app, argc, argv);
  if (cal->parsed()) return bench_calibration(ca);
#ifdef SKINBUS_HAVE_TORCH
  if (finetune->parsed()) return skinbus::tools::bench_finetune(fa);
#endif
  if (budget->parsed()) return skinbus::tools::bench_budget(ba);
  if (ambient->parsed()) return skinbus::tools::bench_ambient(aa);
  if (host->parsed()) return skinbus::tools::bench_host(ha);
  if (models->parsed()) return skinbus::tools::bench_models(ma);
  if (cpu->parsed()) return skinbus::tools::bench_cpu(cpua);
  return bench_fk(fk_robot, fk_calls);
}
