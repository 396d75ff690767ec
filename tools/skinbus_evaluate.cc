// skinbus-evaluate: a calibrated unit's estimators on presses with known truth: its network alone
// and refined on its identified unit as skinbus-host does, per depth bin, next to the Cramer-Rao
// bound of the identified unit at the same presses.
//
//   skinbus-evaluate held.csv --model cal/network --unit cal/unit.json [--design design.yaml]
#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/physics_refiner.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/unit_parameters.h"
#include "tool_util.h"

namespace {

constexpr char kTool[] = "skinbus-evaluate";

}  // namespace

int main(int argc, char** argv) {
  using namespace skinbus;
  CLI::App app{
      "skinbus-evaluate: how well a calibrated unit's estimators place presses whose truth is\n"
      "known (held-out lab presses, or simulated ones): its network alone, and refined on its\n"
      "identified unit as skinbus-host refines it (Levenberg-Marquardt from the network's answer;\n"
      "the host's rule for keeping a refined contact, docs/aggregator.md), per depth bin, next to\n"
      "the Cramer-Rao bound of the identified unit at the same presses (ambient field estimated).\n"
      "Prints a Markdown table. The samples go to the network as they are in the file (tared; no\n"
      "common-mode removal) and are refined cold (no warm start from a previous sample).\n\n"
      "Example:\n"
      "  skinbus-evaluate held.csv --model cal/network --unit cal/unit.json\n"};
  std::string test_path, model_path, unit_path, design_path;
  double tip_radius_mm = 5.0;
  app.add_option("presses", test_path, "presses with known truth (dataset CSV)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--model", model_path, "the unit's network (model file, without extension)")
      ->required();
  app.add_option("--unit", unit_path, "the unit file (skinbus-identify)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--design", design_path, "the unit's design file (default: the built-in design)")
      ->check(CLI::ExistingFile);
  app.add_option("--tip-radius", tip_radius_mm, "the indenter's round tip radius, mm")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 50.0));
  CLI11_PARSE(app, argc, argv);

  Result<sim::Dataset> data = sim::read_dataset_csv(test_path);
  if (!data.ok()) return tools::report_error(kTool, data.error());
  auto model = estimators::read_model(model_path);
  if (!model.ok()) return tools::report_error(kTool, model.error());
  auto runtime = estimators::NetworkRuntime::create(*model);
  if (!runtime.ok()) return tools::report_error(kTool, runtime.error());
  // The unit once: the refiner fits it, the bound is its.
  auto design = sim::read_design_or_builtin(design_path);
  if (!design.ok()) return tools::report_error(kTool, design.error());
  auto params = sim::read_unit_parameters(unit_path);
  if (!params.ok()) return tools::report_error(kTool, params.error());
  auto unit = sim::PatchModel::from_parameters(*design, *params);
  if (!unit.ok()) return tools::fail(kTool, unit_path + ": " + unit.error().message, 1);
  estimators::RefinerOptions ro;
  ro.physics.tip_radius_mm = tip_radius_mm;
  auto refiner = estimators::make_physics_refiner(*unit, ro);
  if (!refiner.ok()) return tools::report_error(kTool, refiner.error());
  const int nc = unit->channel_count();
  if (data->channels() != nc || runtime->channels() != nc) {
    return tools::fail(kTool,
                       test_path + ": " + std::to_string(data->channels()) +
                           " channels; the unit has " + std::to_string(nc) + ", the network " +
                           std::to_string(runtime->channels()),
                       2);
  }
  const estimators::ChannelNoise noise = estimators::ChannelNoise::of(unit->design());
  const host::AggregatorOptions host_rule;

  const std::size_t n = data->rows();
  std::vector<estimators::ContactEstimate> net(n), ref(n);
  std::vector<double> bound(n, std::nan(""));
  std::size_t attempted = 0, kept_network = 0;
  double refine_us = 0;
  for (std::size_t r = 0; r < n; ++r) {
    const std::span<const double> f(data->field(r), static_cast<std::size_t>(nc));
    net[r] = runtime->estimate(f);
    ref[r] = net[r];
    if (net[r].valid() && (net[r].flags & estimators::kEstimateNoContact) == 0) {
      ++attempted;
      const auto t0 = std::chrono::steady_clock::now();
      const estimators::RefinedEstimate e = (*refiner)->refine(f, {}, net[r]);
      refine_us +=
          std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
      if (host::refinement_accepted(e, &net[r], host_rule)) {
        ref[r] = e.contact;
      } else {
        ++kept_network;
      }
    }
    const sim::CrlbPoint b = sim::crlb_at(
        *unit, sim::Contact{data->u_mm[r], data->v_mm[r], data->depth_mm[r], tip_radius_mm},
        noise.xy_ut, noise.z_ut, true);
    if (b.identifiable) bound[r] = b.sd_xy_mm;
  }
  const estimators::Truth truth{data->u_mm, data->v_mm, data->depth_mm, data->force_n};
  const estimators::ErrorSummary sn = estimators::summarize_errors(net, truth);
  const estimators::ErrorSummary sr = estimators::summarize_errors(ref, truth);
  std::printf(
      "%zu presses of %s; network %s (%s); unit %s; %zu refined, %zu kept the network's "
      "answer (the host's rule), %zu without a network contact; %.0f us a refinement on "
      "average\n\n",
      n, test_path.c_str(), model_path.c_str(), runtime->kernel_name(), unit_path.c_str(),
      attempted - kept_network, kept_network, n - attempted,
      attempted > 0 ? refine_us / static_cast<double>(attempted) : 0.0);
  std::printf(
      "| depth (mm) | presses | network XY mean (mm) | refined XY mean (mm) | CRLB (mm) | "
      "refined x CRLB | network depth mean (mm) | refined depth mean (mm) |\n"
      "|---|---:|---:|---:|---:|---:|---:|---:|\n");
  for (int bin = 2; bin < estimators::kDepthBins; ++bin) {
    double sum = 0;
    int count = 0;
    for (std::size_t r = 0; r < n; ++r) {
      if (estimators::depth_bin(data->depth_mm[r]) != bin || !std::isfinite(bound[r])) continue;
      sum += bound[r];
      ++count;
    }
    const double mean_bound = count > 0 ? sum / count : std::nan("");
    const estimators::ErrorStats& a = sn.bins[static_cast<std::size_t>(bin)];
    const estimators::ErrorStats& b = sr.bins[static_cast<std::size_t>(bin)];
    std::printf("| %s | %d | %.3f | %.3f | %.3f | %.2f | %.3f | %.3f |\n",
                estimators::depth_bin_name(bin).c_str(), b.count, a.xy_mean_mm, b.xy_mean_mm,
                mean_bound, b.xy_mean_mm / mean_bound, a.depth_mean_mm, b.depth_mean_mm);
  }
  std::printf(
      "\nCRLB: the mean over the bin's presses of the identified unit's bound (RMS radial; the "
      "mean of a 2-D Gaussian error is about 0.89 of its RMS: about 0.89 x CRLB is at the bound). "
      "The bound is the identified model's; a unit whose physics the model lacks is not bounded "
      "by it.\n");
  return 0;
}
