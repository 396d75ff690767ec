// skinbus-evaluate: a calibrated unit's estimators on presses with known truth: its network alone
// and refined on its identified unit as skinbus-host does, per depth bin, next to the Cramer-Rao
// bound of the identified unit at the same presses.
//
//   skinbus-evaluate held.csv --model cal/network --unit cal/unit.json [--design design.yaml]
//       [--correction cal/correction.json | --fit-correction cal/correction.json]
#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "skinbus/estimators/bias_correction.h"
#include "skinbus/estimators/creep.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/physics_refiner.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/unit_model.h"
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
      "common-mode removal) and are refined cold (no warm start from a previous sample). A unit\n"
      "whose creep identification found (the unit file's creep) has its lag undone along each\n"
      "press of several rows, in the file's order and times, as the host undoes it.\n"
      "When the unit file says where the unit was pressed (pressed_area_mm: skinbus-identify\n"
      "writes it) and some presses lie more than 1 mm outside it, the table is given again for\n"
      "the presses inside and for those outside: out there the fit is extrapolated.\n\n"
      "The learned correction (docs/physics_estimator.md, 'The learned correction'): with\n"
      "--fit-correction, the refined estimates of these presses teach a correction of what the\n"
      "unit's model misses; it is judged on presses it was not fitted on (five folds of press\n"
      "places) at degree 4, 8 and 12, and written only if it lowers the held-out position\n"
      "or depth error (then only for what it lowers). With --correction, the refined estimates\n"
      "are corrected by such a file, as skinbus-host does with a skin-map entry's\n"
      "'correction:'.\n\n"
      "Examples:\n"
      "  skinbus-evaluate lab.csv --model cal/network --unit cal/unit.json \\\n"
      "      --fit-correction cal/correction.json\n"
      "  skinbus-evaluate held.csv --model cal/network --unit cal/unit.json \\\n"
      "      --correction cal/correction.json\n"};
  std::string test_path, model_path, unit_path, design_path, correction_path, fit_path;
  double tip_radius_mm = 5.0;
  app.add_option("presses", test_path, "presses with known truth (dataset CSV)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--model", model_path, "the unit's network (model file, without extension)")
      ->required();
  app.add_option("--unit", unit_path, "the unit file (skinbus-identify)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option(
         "--design", design_path,
         "the unit's design file (default: the built-in design); the unit's model is its class "
         "(the design's anisotropy, crushing top, in-plane drag and creep are not added to an "
         "identified unit; the unit file's own anisotropy and creep are)")
      ->check(CLI::ExistingFile);
  CLI::Option* tip_given =
      app.add_option("--tip-radius", tip_radius_mm,
                     "the indenter's round tip radius, mm (default: the recording's, its "
                     "protocol header's tip_radius_mm=, else the design's indenter)")
          ->check(CLI::Range(0.0, sim::kMaxIndenterTipRadiusMm));
  bool no_search = false;
  app.add_flag("--no-search", no_search,
               "refine without searching the start table again when a fit from the network's "
               "answer ends poor (the host searches: RefinerOptions::search_when_poor)");
  auto* apply_opt =
      app.add_option("--correction", correction_path,
                     "correct the refined estimates by this correction file (as the host does)")
          ->check(CLI::ExistingFile);
  app.add_option("--fit-correction", fit_path,
                 "learn the unit's correction from these presses and write it here, if it "
                 "lowers the error on held-out presses (nothing written otherwise)")
      ->excludes(apply_opt);
  CLI11_PARSE(app, argc, argv);

  Result<sim::Dataset> data = sim::read_dataset_csv(test_path);
  if (!data.ok()) return tools::report_error(kTool, data.error());
  if (const std::string note = sim::leave_out_stuck_channels(&*data); !note.empty()) {
    std::fprintf(stderr, "%s: %s: %s\n", kTool, test_path.c_str(), note.c_str());
  }
  auto model = estimators::read_model(model_path);
  if (!model.ok()) return tools::report_error(kTool, model.error());
  auto runtime = estimators::NetworkRuntime::create(*model);
  if (!runtime.ok()) return tools::report_error(kTool, runtime.error());
  // The unit once: the refiner fits it, the bound is its.
  auto design = sim::read_design_or_builtin(design_path);
  if (!design.ok()) return tools::report_error(kTool, design.error());
  auto read = sim::read_unit_model(unit_path, *design);
  if (!read.ok()) return tools::fail(kTool, read.error().message, 1);
  const sim::UnitFileNote& note = read->note;
  if (!note.refused.empty()) {  // measured as asked; the host refuses to refine on it
    std::fprintf(stderr,
                 "%s: %s is a fit identification refused (%s): skinbus-host will not "
                 "refine on it\n",
                 kTool, unit_path.c_str(), note.refused.c_str());
  }
  const sim::PatchModel* const unit = &read->model;
  // Presses deeper than the unit's lattice compresses in its model: the refinement holds them at
  // that depth, so they are not measured (skinbus-identify left them out of the fit too).
  if (const std::string deeper =
          sim::leave_out_presses_past_the_lattice(&*data, unit->design(), unit->depth_zero_mm());
      !deeper.empty()) {
    std::fprintf(stderr, "%s: %s: %s\n", kTool, test_path.c_str(), deeper.c_str());
  }
  // The header lists the design's sensor places (the unit's are in the presses' frame, which
  // identification may have found shifted and turned from the design's).
  if (Result<sim::PatchModel> drawn = sim::PatchModel::nominal(*design); drawn.ok()) {
    if (Status s = sim::check_sensor_layout(*data, *drawn); !s.ok()) {
      return tools::fail(kTool, test_path + ": " + s.error().message, 2);
    }
  }
  std::string tip_from = "--tip-radius";
  if (tip_given->count() == 0) {
    Result<double> tip = sim::presses_tip_radius_mm(*data, *design, &tip_from);
    if (!tip.ok()) return tools::fail(kTool, test_path + ": " + tip.error().message, 1);
    tip_radius_mm = *tip;
  }
  std::fprintf(stderr, "%s: indenter tip radius %g mm (%s)\n", kTool, tip_radius_mm,
               tip_from.c_str());
  estimators::RefinerOptions ro;
  ro.physics.tip_radius_mm = tip_radius_mm;
  ro.correction = correction_path;
  ro.search_when_poor = !no_search;
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
  std::size_t attempted = 0, kept_network = 0, without_network = 0, fitted_without_network = 0;
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
    } else if (!net[r].valid() && host::channels_left_out(net[r].reason)) {
      // A dead or saturated sensor (a value that is not finite): the network cannot read the
      // sample; the host fits it on the channels left, from the refiner's own starts.
      ++without_network;
      const auto t0 = std::chrono::steady_clock::now();
      const std::optional<estimators::RefinedEstimate> e =
          host::refine_without_network(**refiner, f, {}, nullptr, host_rule);
      refine_us +=
          std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
      if (e) {
        ref[r] = e->contact;
        ++fitted_without_network;
      }
    }
    const sim::CrlbPoint b = sim::crlb_at(
        *unit, sim::Contact{data->u_mm[r], data->v_mm[r], data->depth_mm[r], tip_radius_mm},
        noise.xy_ut, noise.z_ut, true);
    if (b.identifiable) bound[r] = b.sd_xy_mm;
  }
  // A unit whose creep identification found: its lag undone along the recording's ramps, as the
  // host undoes it along a press (a press of one row is a static one).
  estimators::undo_creep(estimators::CreepLaw::of(unit->design()), *data, ref);
  if (!fit_path.empty()) {
    // Scaled to the presses' extent: the correction interpolates over what the recording covers.
    estimators::BiasCorrectionOptions base;
    base.half_u_mm = base.half_v_mm = 0;
    for (std::size_t r = 0; r < n; ++r) {
      base.half_u_mm = std::fmax(base.half_u_mm, std::fabs(data->u_mm[r]));
      base.half_v_mm = std::fmax(base.half_v_mm, std::fabs(data->v_mm[r]));
    }
    base.half_u_mm = std::fmax(1.0, base.half_u_mm);
    base.half_v_mm = std::fmax(1.0, base.half_v_mm);
    const int degrees[] = {4, 8, 12};
    std::fprintf(stderr,
                 "%s: judging a correction at degree 4, 8 and 12 on held-out presses and places\n",
                 kTool);
    auto choice = estimators::BiasCorrection::choose(ref, data->u_mm, data->v_mm, data->depth_mm,
                                                     base, degrees);
    if (!choice.ok()) return tools::report_error(kTool, choice.error());
    const estimators::CorrectionCheck& c = choice->check;
    for (const auto& [degree, t] : choice->tried) {
      std::fprintf(stderr, "%s: %s\n", kTool, t.held_out_text(degree).c_str());
    }
    for (const auto& [degree, why] : choice->skipped) {
      std::fprintf(stderr, "%s: degree %d not judged: %s\n", kTool, degree, why.c_str());
    }
    std::printf(
        "Learned correction, judged on held-out presses (%d estimates >= %.1f mm deep), "
        "%s: %s.\n",
        c.samples, choice->options.min_depth_mm, choice->degree_text().c_str(),
        choice->summary_text().c_str());
    if (choice->any()) {
      auto fitted = estimators::BiasCorrection::fit(ref, data->u_mm, data->v_mm, data->depth_mm,
                                                    choice->options);
      if (!fitted.ok()) return tools::report_error(kTool, fitted.error());
      if (Status w = fitted->write(
              fit_path, &c,
              "skinbus-evaluate --fit-correction " + test_path + " --unit " + unit_path);
          !w.ok()) {
        return tools::report_error(kTool, w.error());
      }
      std::printf("Written: %s (skin-map entry: 'correction: %s').\n\n", fit_path.c_str(),
                  fit_path.c_str());
    } else {
      std::printf("It helps neither on held-out presses: no correction written.\n\n");
    }
  }
  std::printf(
      "%zu presses of %s; network %s (%s); unit %s%s%s; %zu refined, %zu kept the network's "
      "answer (the host's rule), %zu without a network contact (of those, %zu the network could "
      "not read for a dead or saturated channel, %zu of them fitted on the channels left); %.0f "
      "us a refinement on average\n\n",
      n, test_path.c_str(), model_path.c_str(), runtime->kernel_name(), unit_path.c_str(),
      correction_path.empty() ? "" : ", refined estimates corrected by ", correction_path.c_str(),
      attempted - kept_network, kept_network, n - attempted, without_network,
      fitted_without_network,
      attempted + without_network > 0 ? refine_us / static_cast<double>(attempted + without_network)
                                      : 0.0);
  // The table over the rows `keep` marks (all: every row).
  auto table = [&](const std::vector<char>* keep) {
    std::vector<estimators::ContactEstimate> a, b;
    std::vector<double> u, v, depth, force, bounds;
    for (std::size_t r = 0; r < n; ++r) {
      if (keep != nullptr && (*keep)[r] == 0) continue;
      a.push_back(net[r]);
      b.push_back(ref[r]);
      u.push_back(data->u_mm[r]);
      v.push_back(data->v_mm[r]);
      depth.push_back(data->depth_mm[r]);
      force.push_back(data->force_n[r]);
      bounds.push_back(bound[r]);
    }
    const estimators::Truth truth{u, v, depth, force};
    const estimators::ErrorSummary sn = estimators::summarize_errors(a, truth);
    const estimators::ErrorSummary sr = estimators::summarize_errors(b, truth);
    std::printf(
        "| depth (mm) | presses | network XY mean (mm) | refined XY mean (mm) | CRLB (mm) | "
        "refined x CRLB | network depth mean (mm) | refined depth mean (mm) |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for (int bin = 2; bin < estimators::kDepthBins; ++bin) {
      double sum = 0;
      int count = 0;
      for (std::size_t r = 0; r < depth.size(); ++r) {
        if (estimators::depth_bin(depth[r]) != bin || !std::isfinite(bounds[r])) continue;
        sum += bounds[r];
        ++count;
      }
      const double mean_bound = count > 0 ? sum / count : std::nan("");
      const estimators::ErrorStats& x = sn.bins[static_cast<std::size_t>(bin)];
      const estimators::ErrorStats& y = sr.bins[static_cast<std::size_t>(bin)];
      if (y.count == 0) continue;  // no press that deep (a lattice that compresses less)
      std::printf("| %s | %d | %.3f | %.3f | %.3f | %.2f | %.3f | %.3f |\n",
                  estimators::depth_bin_name(bin).c_str(), y.count, x.xy_mean_mm, y.xy_mean_mm,
                  mean_bound, y.xy_mean_mm / mean_bound, x.depth_mean_mm, y.depth_mean_mm);
    }
  };
  table(nullptr);
  // Presses beyond the area the unit was pressed on (more than the margin): there the fit is
  // extrapolated, so they are shown apart as well.
  if (const std::optional<sim::PressedArea>& area = note.pressed_area; area) {
    std::vector<char> inside(n);
    std::size_t outside = 0;
    for (std::size_t r = 0; r < n; ++r) {
      inside[r] = area->contains(data->u_mm[r], data->v_mm[r], sim::kPressedAreaMarginMm) ? 1 : 0;
      outside += inside[r] == 0 ? 1 : 0;
    }
    if (outside > 0) {
      std::printf(
          "\n%zu of the %zu presses lie outside the area the unit was pressed on (u %.1f .. %.1f, "
          "v %.1f .. %.1f mm, the unit file's pressed_area_mm, widened by %.0f mm), where its fit "
          "is extrapolated (a field correction only as its edge's value). The presses inside "
          "it:\n\n",
          outside, n, area->u_min_mm, area->u_max_mm, area->v_min_mm, area->v_max_mm,
          sim::kPressedAreaMarginMm);
      table(&inside);
      for (char& k : inside) k = k != 0 ? 0 : 1;
      std::printf("\nThe presses outside it:\n\n");
      table(&inside);
    }
  }
  std::printf(
      "\nCRLB: the mean over the bin's presses of the identified unit's bound (RMS radial; the "
      "mean of a 2-D Gaussian error is about 0.89 of its RMS: about 0.89 x CRLB is at the bound). "
      "The bound is the identified model's; a unit whose physics the model lacks is not bounded "
      "by it.\n");
  return 0;
}
