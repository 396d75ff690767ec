// The command-line options of skinbus-bench's report subcommands (bench_options.h).
#include "bench_options.h"

#include <string>

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

namespace skinbus::tools {

void add_models_options(CLI::App* sub, estimators_bench::ModelsBenchArgs& a) {
  sub->add_option("--design", a.design_path,
                  "patch design file (docs/design_file.md; default: the built-in design)")
      ->check(CLI::ExistingFile);
  sub->add_option("--test", a.test_path, "off-grid test split (skinbus-dataset --plan random-test)")
      ->required()
      ->check(CLI::ExistingFile);
  sub->add_option("--train", a.train_path,
                  "training presses: the nearest-neighbour lookup's table (optional)")
      ->check(CLI::ExistingFile);
  sub->add_option("--model", a.model_paths, "trained network (repeat); a stem or .json path");
  sub->add_option("--reference", a.reference_path,
                  "model run through LibTorch as the reference runtime (default: the first "
                  "width-1 CNN)");
  sub->add_flag("!--no-reduced", a.reduced, "leave out the bfloat16 and int8 rows");
  sub->add_flag("!--no-physics", a.physics, "leave out the physics LM row");
  sub->add_option("--latency-samples", a.latency_samples, "samples timed at batch 1")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--max-test", a.max_test, "test rows used")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000000));
  sub->add_option("--csv", a.csv, "write the table as CSV");
  sub->add_option("--errors-csv", a.errors_csv, "write every estimate's error (for the error map)");
  sub->add_option("--plot", a.plot,
                  "PNG stem: writes <stem>_pareto.png and <stem>_error_map.png (needs --errors-csv "
                  "and --csv)");
}

void add_cpu_options(CLI::App* sub, estimators_bench::CpuBenchArgs& a) {
  sub->add_option("--model", a.model_path,
                  "the network timed (model file stem; default: the shipped seed CNN, "
                  "estimators/models/nominal_seed_cnn)");
  sub->add_option("--test", a.test_path,
                  "off-grid test presses for the error columns (default: 2000 simulated on the "
                  "nominal patch, as skinbus-dataset --plan random-test)")
      ->check(CLI::ExistingFile);
  sub->add_option("--samples", a.samples, "test presses used (errors, batched timing)")
      ->check(CLI::Range(64, 100000));
  sub->add_option("--latency-samples", a.latency_samples, "samples timed one at a time")
      ->check(CLI::Range(10, 100000));
  sub->add_option("--reps", a.reps,
                  "rounds: each round times every row once, the rows in turn (the portable rows "
                  "in the first round only); the median over the rounds is reported. The FMA "
                  "peak and the read rate are measured again before each round, the best kept")
      ->check(CLI::Range(1, 50));
  sub->add_option("--csv", a.csv, "write the table as CSV");
  sub->add_option("--plot", a.plot,
                  "with --csv: also a PNG of the times (tools/plot_cpu.py, python3-matplotlib)");
}

void add_budget_options(CLI::App* sub, estimators_bench::BudgetBenchArgs& a) {
  sub->add_option("--design", a.design_path,
                  "patch design file (docs/design_file.md; default: the built-in design)")
      ->check(CLI::ExistingFile);
  sub->add_option("--unit-design", a.unit_design_path,
                  "the design the units are built to, when it differs from --design (the "
                  "design file the pipelines start from): a unit whose spread, depths or "
                  "moments are off its drawing")
      ->check(CLI::ExistingFile);
  sub->add_option("--units", a.units,
                  "simulated units: nominal, fabricated, and outside the model class "
                  "anisotropic, crushing (the top crushes under the tip), discs (finite "
                  "magnets), dragging (another in-plane motion law), creeping (the lattice "
                  "lags the press; tested on ramps), slow-creeping (creeping with a second, "
                  "slower lag, which identification finds when held-out presses show it), "
                  "crushing-creeping (both: a crushing top on a creeping lattice; tested on "
                  "ramps)")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--uid", a.uid, "hardware UID of the fabricated units (as skinbus-dataset)")
      ->capture_default_str();
  sub->add_option("--anisotropy", a.anisotropy, "lattice anisotropy of the 'anisotropic' unit")
      ->capture_default_str();
  sub->add_option("--tip-crush", a.tip_crush_mm,
                  "the 'crushing' and 'crushing-creeping' units: the plate bends d / (1 + d / "
                  "this) under a press d "
                  "deep, mm")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  sub->add_option("--inplane-drag", a.inplane_drag,
                  "the 'dragging' unit: magnets also move toward a press by this x their "
                  "deflection x distance / spread")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  sub->add_option("--creep", a.creep_fraction,
                  "the 'creeping' units: this part of the plate's bend lags the press ...")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.99));
  sub->add_option("--creep-time", a.creep_time_s, "... with this time constant, s")
      ->capture_default_str()
      ->check(CLI::Range(0.001, 3600.0));
  sub->add_option("--slow-creep", a.creep_slow_fraction,
                  "the 'slow-creeping' unit: a further part of the bend lags the press ...")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.99));
  sub->add_option("--slow-creep-time", a.creep_slow_time_s, "... with this slower time constant, s")
      ->capture_default_str()
      ->check(CLI::Range(0.001, 3600.0));
  sub->add_option("--seed-model", a.seed_models,
                  "unit=MODEL: the seed CNN trained on that unit's 19 x 19 grid (skinbus-train on "
                  "skinbus-dataset --plan grid); repeat per unit");
  sub->add_option("--test-count", a.test_count, "off-grid test presses per unit")
      ->capture_default_str()
      ->check(CLI::Range(10, 1000000));
  sub->add_option("--grid-test-per-point", a.grid_test_per_point, "test presses at each grid point")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  sub->add_option("--csv", a.csv, "write the table as CSV");
}

void add_pairs_options(CLI::App* sub, estimators_bench::PairsBenchArgs& a) {
  sub->add_option("--separations", a.separations, "separations of the two presses, mm")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--depths", a.depths, "depths of both presses, mm")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--trials", a.trials, "pairs per separation and depth")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--single-trials", a.single_trials, "single presses per unit")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--uid", a.uid, "hardware UID of the fabricated unit")->capture_default_str();
  sub->add_option("--seed", a.seed, "random seed of the presses and the noise")
      ->capture_default_str();
  sub->add_option("--csv", a.csv, "write the pairs table as CSV");
}

void add_triples_options(CLI::App* sub, estimators_bench::TriplesBenchArgs& a) {
  sub->add_option("--sides", a.sides, "sides of the presses' equilateral triangle, mm")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--depths", a.depths, "depths of the three presses, mm")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--trials", a.trials, "triangles per side and depth")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--other-trials", a.other_trials,
                  "one-press and two-press samples per unit (counted three or not)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--uid", a.uid, "hardware UID of the fabricated unit")->capture_default_str();
  sub->add_option("--seed", a.seed, "random seed of the presses and the noise")
      ->capture_default_str();
  a.proposer = SKINBUS_SOURCE_DIR "/estimators/models/nominal_proposer";
  sub->add_option("--proposer", a.proposer,
                  "proposer network (model path stem) the count also starts from; \"\": none")
      ->capture_default_str();
  sub->add_option("--csv", a.csv, "write the triples table as CSV");
}

void add_shear_options(CLI::App* sub, estimators_bench::ShearBenchArgs& a) {
  sub->add_option("--depths", a.depths, "press depths, mm")->delimiter(',')->capture_default_str();
  sub->add_option("--trials", a.trials, "presses per depth and per unit outside the model")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  sub->add_option("--max-friction", a.max_friction,
                  "shear up to this fraction of the normal force (friction coefficient)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 2.0));
  sub->add_option("--uid", a.uid, "hardware UID of the fabricated unit")->capture_default_str();
  sub->add_option("--seed", a.seed, "random seed of the presses and the noise")
      ->capture_default_str();
  sub->add_option("--csv", a.csv, "write the per-depth table as CSV");
}

void add_finetune_options(CLI::App* sub, estimators_bench::FinetuneBenchArgs& a) {
  sub->add_option("--base", a.base_path, "the base network (trained on the nominal patch)")
      ->required();
  sub->add_option("--points", a.points, "presses spent on the new unit (Halton positions)")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--uid", a.uid, "hardware UID of the new (fabricated) unit")
      ->capture_default_str();
  sub->add_option("--anisotropy", a.anisotropy,
                  "lattice anisotropy of the new unit (physics the nominal model does not have)")
      ->capture_default_str();
  sub->add_option("--plan", a.plan,
                  "press positions: halton (n points) | grid (the nearest square grid over the "
                  "patch, round(sqrt(n))^2 points)")
      ->capture_default_str()
      ->check(CLI::IsMember({"halton", "grid"}));
  sub->add_option("--epochs", a.epochs, "fine-tuning epochs")->capture_default_str();
  sub->add_option("--lr", a.learning_rate, "fine-tuning learning rate")->capture_default_str();
  sub->add_option("--test-count", a.test_count, "off-grid test presses")->capture_default_str();
  sub->add_option("--threads", a.threads, "LibTorch threads")->capture_default_str();
  sub->add_option("--csv", a.csv, "write the table as CSV");
}

void add_refine_options(CLI::App* sub, host_bench::RefineBenchArgs& a) {
  sub->add_option("--uids", a.uids, "fabricated units (hardware UIDs)")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--presses", a.presses, "presses per unit")->capture_default_str();
  sub->add_option("--samples", a.samples_per_press, "samples per press (41.7 Hz)")
      ->capture_default_str()
      ->check(CLI::Range(3, 1000));
  sub->add_option("--seed", a.seed, "random seed")->capture_default_str();
  sub->add_option("--csv", a.csv, "write the error table as CSV");
  sub->add_option("--design", a.design_path,
                  "patch design file of the units (docs/design_file.md; 16 sensors, as a patch "
                  "on the bus sends; default: the built-in design); presses with its indenter")
      ->check(CLI::ExistingFile);
  sub->add_option("--model", a.model_path,
                  "the network the host refines from (model file stem or .json; default: the "
                  "shipped seed CNN, estimators/models/nominal_seed_cnn)");
  sub->add_option("--half-extent", a.half_extent_mm,
                  "presses uniform within +-this of the patch centre, mm")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 500.0));
  sub->add_option("--unit", a.unit_path,
                  "a unit file (skinbus-identify's, with its field correction if any) on --design "
                  "instead of fabricated units: its model is pressed and refined on (the cost of "
                  "refining such a unit; --uids' first seeds the noise); keep --half-extent "
                  "within the area it was pressed on")
      ->check(CLI::ExistingFile);
  sub->add_option("--basin-check", a.basin_check_mm,
                  "search a single refined press again from the start table once it is this "
                  "deep and at each doubling of its depth (the host's refine_basin_check_mm), "
                  "mm; 0: never")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
}

void add_ambient_options(CLI::App* sub, host_bench::AmbientBenchArgs& a) {
  sub->add_option("--model", a.model_path, "per-patch model (stem, .json or .safetensors)")
      ->capture_default_str();
  sub->add_option("--units", a.units, "units: nominal, fabricated (UID-seeded variation)")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--count", a.count, "presses per unit")->capture_default_str();
  sub->add_option("--field", a.field_ut, "magnitude of the turning ambient field, uT")
      ->capture_default_str();
  sub->add_option("--max-turn", a.max_turn_deg,
                  "largest turn of the field between tare and press, degrees (180: any)")
      ->capture_default_str();
  sub->add_option("--csv", a.csv, "write the table as CSV here");
}

void add_host_options(CLI::App* sub, host_bench::HostBenchArgs& a) {
  sub->add_option("--patches", a.patches, "patch counts")->delimiter(',')->capture_default_str();
  sub->add_option("--touched", a.touched_percent, "touched shares, percent")
      ->delimiter(',')
      ->capture_default_str();
  sub->add_option("--seconds", a.seconds, "simulated seconds per configuration")
      ->capture_default_str();
  sub->add_option("--mode", a.mode, "stream (idle patches send samples) or event")
      ->capture_default_str();
  sub->add_option("--threads", a.threads, "threads of each model runtime")->capture_default_str();
  sub->add_option("--precision", a.precision, "network precision")
      ->capture_default_str()
      ->check(CLI::IsMember({"float32", "bfloat16", "int8"}));
  sub->add_option("--isa", a.isa,
                  "the widest instruction set the kernels may use (avx2: what an AVX2-only CPU "
                  "runs)")
      ->capture_default_str()
      ->check(CLI::IsMember({"avx512", "avx2", "neon", "portable"}));
  sub->add_option("--max-lag-ms", a.max_lag_ms,
                  "the aggregator's lag bound (0: none): samples it cannot publish within this "
                  "of their time are superseded (counted as late)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 60'000.0));
  sub->add_option("--record", a.record,
                  "also time each configuration while recorded into this MCAP file (as "
                  "skinbus-host --record; overwritten): the added time and MB per minute");
  sub->add_option("--model-delay-us", a.model_delay_us,
                  "every estimate busy-waits this many us more, as on a slower CPU (paced runs "
                  "only)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1'000'000));
  sub->add_option("--csv", a.csv, "write the table as CSV here");
}

}  // namespace skinbus::tools
