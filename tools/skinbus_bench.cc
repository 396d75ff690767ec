// skinbus-bench: speed and accuracy of the project's estimators and stages, measured on the same
// data in one run. Prints Markdown tables; --csv / --plot write the numbers and a figure.
//
//   skinbus-bench calibration --plot docs/benchmarks/calibration.png
//   skinbus-bench fk --robot ../shared/robots/unitree_g1/g1_29dof.urdf
//   skinbus-bench models --test test.csv --train train.csv --model models/nominal_seed_cnn
#include <CLI/CLI.hpp>

#include <cstdio>
#include <string>

#include "bench_options.h"
#include "skinbus/body_map_bench/reports.h"
#include "skinbus/estimators_bench/reports.h"
#include "skinbus/host_bench/reports.h"
#include "tool_util.h"

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

namespace {

// The exit status of a report: 0, or the error reported (tool_util.h).
int report(const skinbus::Status& s) {
  return s.ok() ? 0 : skinbus::tools::report_error("skinbus-bench", s.error());
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-bench: run time and error of the project's estimators and stages,\n"
      "measured together on the same data. One subcommand per stage; each prints a\n"
      "Markdown table (docs/benchmarks/ keeps the results and the commands).\n"};
  app.require_subcommand(1);
  skinbus::body_map_bench::CalibrationArgs ca;
  ca.robot = SKINBUS_SOURCE_DIR "/body_map/robots/skinbot.urdf";
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
  skinbus::estimators_bench::ModelsBenchArgs ma;
  CLI::App* models = app.add_subcommand(
      "models",
      "per-patch estimators (networks on the host runtime, LibTorch reference, nearest-neighbour "
      "lookup, physics LM): latency, throughput and error per depth bin against the CRLB");
  skinbus::tools::add_models_options(models, ma);
  skinbus::estimators_bench::BudgetBenchArgs ba;
  skinbus::estimators_bench::CpuBenchArgs cpua;
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
  skinbus::estimators_bench::PairsBenchArgs pa;
  CLI::App* pairs = app.add_subcommand(
      "pairs",
      "two presses on one patch: how often the count is right and each contact's error against "
      "their separation and depth, next to the two-contact Cramer-Rao bound; how often a single "
      "press is split, on units whose physics the model lacks");
  skinbus::tools::add_pairs_options(pairs, pa);
  skinbus::estimators_bench::TriplesBenchArgs ta;
  CLI::App* triples = app.add_subcommand(
      "triples",
      "three presses on one patch: how often the count is right and each contact's error "
      "against their spacing and depth, next to the three-contact Cramer-Rao bound; how often "
      "one or two presses are counted three, on units whose physics the model lacks");
  skinbus::tools::add_triples_options(triples, ta);
  skinbus::estimators_bench::ShearBenchArgs sa;
  CLI::App* shear = app.add_subcommand(
      "shear",
      "a contact's shear force: its error against the Cramer-Rao bound per depth, the position "
      "with and without the shear fitted, the run time, and units whose physics the model lacks");
  skinbus::tools::add_shear_options(shear, sa);
  skinbus::host_bench::AmbientBenchArgs aa;
  CLI::App* ambient = app.add_subcommand(
      "ambient",
      "a per-patch model's error when the ambient field turns between tare and press (a limb "
      "moving in the Earth's field), with and without common-mode rejection");
  skinbus::tools::add_ambient_options(ambient, aa);
  skinbus::host_bench::HostBenchArgs ha;
  CLI::App* host = app.add_subcommand(
      "host",
      "the host aggregator: latency from frame arrival to publication and CPU use for 16, 64 "
      "and 200 patches with 100, 10 and 0 % touched, and host time per idle patch");
  skinbus::tools::add_host_options(host, ha);
  skinbus::host_bench::RefineBenchArgs ra;
  CLI::App* refine = app.add_subcommand(
      "refine",
      "the host's physics refinement on fabricated units: XY and depth error per depth bin of "
      "the network alone and refined, against the unit's Cramer-Rao bound, and the cost per "
      "touched sample from cold and warm starts");
  skinbus::tools::add_refine_options(refine, ra);
#ifdef SKINBUS_HAVE_TORCH
  skinbus::estimators_bench::FinetuneBenchArgs fa;
  CLI::App* finetune = app.add_subcommand(
      "finetune",
      "a new unit's error against the presses spent on it: fine-tuning a base network vs "
      "identifying the unit's physics from the same presses");
  skinbus::tools::add_finetune_options(finetune, fa);
#endif
  CLI11_PARSE(app, argc, argv);
  if (cal->parsed()) return report(skinbus::body_map_bench::bench_calibration(ca));
#ifdef SKINBUS_HAVE_TORCH
  if (finetune->parsed()) return report(skinbus::estimators_bench::bench_finetune(fa));
#endif
  if (budget->parsed()) return report(skinbus::estimators_bench::bench_budget(ba));
  if (pairs->parsed()) return report(skinbus::estimators_bench::bench_pairs(pa));
  if (triples->parsed()) return report(skinbus::estimators_bench::bench_triples(ta));
  if (shear->parsed()) return report(skinbus::estimators_bench::bench_shear(sa));
  if (ambient->parsed()) return report(skinbus::host_bench::bench_ambient(aa));
  if (host->parsed()) return report(skinbus::host_bench::bench_host(ha));
  if (refine->parsed()) return report(skinbus::host_bench::bench_refine(ra));
  if (models->parsed()) return report(skinbus::estimators_bench::bench_models(ma));
  if (cpu->parsed()) return report(skinbus::estimators_bench::bench_cpu(cpua));
  return report(skinbus::body_map_bench::bench_fk(fk_robot, fk_calls));
}
