// The per-patch estimators' reports (`skinbus-bench models | cpu | budget | finetune`): run time
// and error of every estimator on the same presses, against the Cramér-Rao bound and the CPU's FMA
// peak. Each prints Markdown tables on standard output and progress on standard error, writes the
// CSV and plot files its arguments name, and returns what went wrong as a Status.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/patch_model.h"

namespace skinbus::estimators_bench {

struct ModelsBenchArgs {
  std::string test_path;                 // off-grid test split (skinbus-dataset --plan random-test)
  std::string train_path;                // training presses (nearest-neighbour table); optional
  std::vector<std::string> model_paths;  // trained networks
  std::string reference_path;            // model run through LibTorch (default: first width-1 CNN)
  bool reduced = true;                   // add bfloat16 and int8 rows for each network
  bool physics = true;                   // add the physics LM row (nominal unit model)
  int latency_samples = 300;             // samples timed at batch 1
  int max_test = 2000;                   // test rows used
  std::string csv, errors_csv, plot;     // outputs
  std::string design_path;               // the test split's patch design file; empty: built-in
};

// The Cramer-Rao bound of each of the first `n` rows of `data` for `model` (its design's sensor
// noise; the tip the recording says, else the design's indenter); crlb_per_row() its RMS XY bound
// (mm); and a value's mean per depth bin.
std::vector<sim::CrlbPoint> crlb_points_per_row(const sim::PatchModel& model,
                                                const sim::Dataset& data, int n);
std::vector<double> crlb_per_row(const sim::PatchModel& model, const sim::Dataset& data, int n);
std::array<double, estimators::kDepthBins> mean_per_bin(std::span<const double> values,
                                                        std::span<const double> depth_mm);

Status bench_models(const ModelsBenchArgs& a);

// `skinbus-bench cpu` (report_cpu.cc): one network on every kernel set this CPU has, float32 and
// int8, batch 1 and batched on 1 and 2 threads, against the FMA peak measured here, LibTorch at
// its best and the portable kernels, with the errors on the same presses.
struct CpuBenchArgs {
  std::string model_path;  // default: the shipped seed CNN
  std::string test_path;   // default: simulated on the nominal patch
  int samples = 2000;
  int latency_samples = 500;
  int reps = 5;
  std::string csv, plot;
};
Status bench_cpu(const CpuBenchArgs& a);
// The float32 multiply-add peak of one core with `isa`'s vector width (GFLOP/s; 0 where this CPU
// or build has no such vectors, and for the portable kernels).
double fma_peak_gflops(estimators::RuntimeIsa isa);

// `skinbus-bench budget`: accuracy at a fixed robot-time budget (361 presses per unit).
struct BudgetBenchArgs {
  std::vector<std::string> units = {"nominal", "fabricated", "anisotropic"};
  uint64_t uid = 0x5B00000000000001ull;  // as skinbus-dataset's default
  // Units off the nominal model, each fabricated: "anisotropic" (this anisotropy, which
  // identification fits since 2026-11-28), and outside the class: "crushing"
  // (PatchDesign::tip_crush_mm), "discs" (PatchModel::with_disc_magnets), "dragging"
  // (PatchDesign::inplane_drag), "creeping" (PatchDesign::creep_fraction, with creep_time_s; its
  // test presses are ramps, as the presses it is calibrated on: a static press is the relaxed
  // state), "slow-creeping" (the same with a second, slower lag: creep_slow_fraction, which
  // identification fits as a second lag when held-out presses show it), "crushing-creeping" (a
  // crushing top on a creeping lattice: a creep fitted on the class alone takes part of the crush
  // for lag).
  double anisotropy = 0.05;
  double tip_crush_mm = 20;
  double inplane_drag = 0.15;
  double creep_fraction = 0.25, creep_time_s = 0.3;
  double creep_slow_fraction = 0.1, creep_slow_time_s = 3;
  std::vector<std::string> seed_models;  // "unit=path": seed CNN trained on that unit's grid
  int test_count = 2000;                 // off-grid test presses
  int grid_test_per_point = 3;           // test presses at every grid point
  std::string design_path;               // the units' patch design file; empty: built-in
  // The design the units are built to, when it differs from the file the pipelines start from
  // (what the drawing says vs what was printed); empty: design_path's.
  std::string unit_design_path;
  std::string csv;
};

Status bench_budget(const BudgetBenchArgs& a);

// `skinbus-bench finetune` (built with LibTorch only): error of a new unit against the presses
// spent on it, fine-tuning a base network vs identifying the unit's physics.
struct FinetuneBenchArgs {
  std::string base_path;
  std::vector<int> points = {10, 20, 40, 80, 160};
  uint64_t uid = 0x5B00000000000007ull;
  double anisotropy = 0;        // of the new unit's lattice (0.05: physics the nominal model lacks)
  std::string plan = "halton";  // press positions: halton | grid (round(sqrt(n))^2 points)
  int epochs = 30;
  double learning_rate = 3e-4;
  int test_count = 1000;
  int threads = 1;
  std::string csv;
};

Status bench_finetune(const FinetuneBenchArgs& a);

// `skinbus-bench pairs`: the contact count and two contacts' error against their separation and
// depth (next to the two-contact bound), and how often single presses are split.
struct PairsBenchArgs {
  std::vector<double> separations = {10, 15, 20, 30, 40, 60, 80};
  std::vector<double> depths = {1, 2, 3, 4};
  int trials = 40;          // pairs per (separation, depth)
  int single_trials = 200;  // single presses per unit
  uint64_t uid = 0x5B00000000000001ull;
  uint64_t seed = 1;
  std::string csv;
};

Status bench_pairs(const PairsBenchArgs& a);

// `skinbus-bench triples`: three presses on one patch: the count and each contact's error against
// their spacing and depth (next to the three-contact bound), and how often one or two presses are
// counted three on units whose physics the model lacks.
struct TriplesBenchArgs {
  std::vector<double> sides = {20, 30, 40, 50, 60};
  std::vector<double> depths = {1, 2, 3};
  int trials = 30;         // triangles per (side, depth)
  int other_trials = 100;  // one- and two-press samples per unit
  // A proposer network (contact_proposal.h; model path stem): the count also started from its
  // answer, and its own count measured. Empty: none.
  std::string proposer;
  uint64_t uid = 0x5B00000000000001ull;
  uint64_t seed = 1;
  std::string csv;
};

Status bench_triples(const TriplesBenchArgs& a);

// `skinbus-bench shear`: a contact's shear force against its Cramer-Rao bound per depth, the
// position with and without the shear fitted, the run time, and units outside the model.
struct ShearBenchArgs {
  std::vector<double> depths = {1, 2, 3, 4};
  int trials = 100;           // presses per depth and per unit outside the model
  double max_friction = 0.5;  // shear up to this fraction of the normal force
  uint64_t uid = 0x5B00000000000001ull;
  uint64_t seed = 1;
  std::string csv;
};

Status bench_shear(const ShearBenchArgs& a);

}  // namespace skinbus::estimators_bench
