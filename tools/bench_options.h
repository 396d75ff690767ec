// tools/bench_options.h: the command-line options of skinbus-bench's report subcommands (the
// reports themselves are library functions: estimators/bench, host/bench, body_map/bench).
#pragma once

#include <CLI/CLI.hpp>

#include "skinbus/estimators_bench/reports.h"
#include "skinbus/host_bench/reports.h"

namespace skinbus::tools {

void add_models_options(CLI::App* sub, estimators_bench::ModelsBenchArgs& a);
void add_cpu_options(CLI::App* sub, estimators_bench::CpuBenchArgs& a);
void add_budget_options(CLI::App* sub, estimators_bench::BudgetBenchArgs& a);
void add_pairs_options(CLI::App* sub, estimators_bench::PairsBenchArgs& a);
void add_triples_options(CLI::App* sub, estimators_bench::TriplesBenchArgs& a);
void add_shear_options(CLI::App* sub, estimators_bench::ShearBenchArgs& a);
void add_finetune_options(CLI::App* sub, estimators_bench::FinetuneBenchArgs& a);
void add_host_options(CLI::App* sub, host_bench::HostBenchArgs& a);
void add_ambient_options(CLI::App* sub, host_bench::AmbientBenchArgs& a);
void add_refine_options(CLI::App* sub, host_bench::RefineBenchArgs& a);

}  // namespace skinbus::tools
