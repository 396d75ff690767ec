// skinbus-bench pairs: the contact count and two contacts' places against their separation and
// depth, next to the two-contact Cramer-Rao bound, and how often a single press is split.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "bench_time.h"
#include "mismatched_units.h"
#include "skinbus/common/atomic_file.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators_bench/reports.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators_bench {
namespace {

using namespace skinbus::estimators;
using sim::Contact;

}  // namespace

Status bench_pairs(const PairsBenchArgs& a) {
  const sim::PatchDesign design;
  auto unit = sim::PatchModel::fabricated(design, a.uid, sim::FabricationVariation{});
  if (!unit.ok()) return unit.error();
  // The estimator on the unit's own model (identification's result, to its residual).
  auto physics = PhysicsEstimator::create(*unit);
  if (!physics.ok()) return physics.error();
  const ChannelNoise noise = ChannelNoise::of(design);
  sim::Rng rng(a.seed);
  std::string csv =
      "separation_mm,depth_mm,trials,count2_rate,count1_rate,xy_error_mm,crlb_xy_mm,"
      "depth_error_mm,us_per_sample,us_next_sample,next_count2_rate\n";
  std::printf(
      "Two presses of the same depth (5 mm tips), their midpoint uniform within +-30 mm, in a "
      "random direction, on a fabricated unit (UID 0x%llx; the estimator on its own model), the "
      "design's sensor noise; %d trials a row, seed %llu. XY error: mean per contact over the "
      "samples counted two; CRLB: the two-contact bound at the same places (mean). us / sample: "
      "the count from nothing (estimate_contacts); us / next sample: the host's path on a second "
      "sample of the same presses (refine_lm from the first contact, then count_contacts from "
      "this pair), and how often it counts two again.\n\n",
      static_cast<unsigned long long>(a.uid), a.trials, static_cast<unsigned long long>(a.seed));
  std::printf(
      "| separation (mm) | depth (mm) | counted 2 | counted 1 | XY error (mm) | CRLB (mm) | x "
      "CRLB | depth error (mm) | us / sample | pair iterations | us / next sample | next counted "
      "2 |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (double sep : a.separations) {
    for (double depth : a.depths) {
      int two = 0, one = 0;
      std::vector<double> err, bound, derr;
      double us = 0, iterations = 0, us_warm = 0;
      int warm = 0;
      for (int t = 0; t < a.trials; ++t) {
        const double mu = rng.uniform(-30, 30), mv = rng.uniform(-30, 30);
        const double th = rng.uniform(0, M_PI);
        const Contact p[2] = {{mu + sep / 2 * std::cos(th), mv + sep / 2 * std::sin(th), depth, 5},
                              {mu - sep / 2 * std::cos(th), mv - sep / 2 * std::sin(th), depth, 5}};
        const auto f = noisy_field(*unit, p, rng);
        const auto t0 = Clock::now();
        const ContactCountEstimate e = physics->estimate_contacts(f);
        us += us_since(t0);
        iterations += e.pair_iterations;
        one += e.count == 1;
        if (e.count != 2) continue;
        ++two;
        // The host's path on the next sample of the same presses: the single refinement from the
        // first contact, then the count from this pair.
        {
          const auto f2 = noisy_field(*unit, p, rng);
          const auto w0 = Clock::now();
          const PhysicsEstimate single = physics->refine_lm(f2, {}, e.contacts[0]);
          const ContactCountEstimate w = physics->count_contacts(
              f2, {}, single, {}, std::span<const ContactEstimate>(e.contacts, 2));
          us_warm += us_since(w0);
          warm += w.count == 2;
        }
        int match[2];
        match_contacts<Contact>(e.contacts, p, match);
        for (int k = 0; k < 2; ++k) {
          const ContactEstimate& c = e.contacts[match[k]];
          err.push_back(std::hypot(c.u_mm - p[k].u_mm, c.v_mm - p[k].v_mm));
          derr.push_back(std::fabs(c.depth_mm - p[k].depth_mm));
        }
        const sim::CrlbPair b = sim::crlb_pair_at(*unit, p[0], p[1], noise.xy_ut, noise.z_ut, true);
        bound.insert(bound.end(), {b.first.sd_xy_mm, b.second.sd_xy_mm});
      }
      const double e_xy = err.empty() ? 0 : mean(err), b_xy = bound.empty() ? 0 : mean(bound);
      const double e_d = derr.empty() ? 0 : mean(derr);
      std::printf(
          "| %.0f | %.1f | %.0f %% | %.0f %% | %.3f | %.3f | %.2f | %.3f | %.0f | %.1f | %.0f | "
          "%.0f "
          "%% |\n",
          sep, depth, 100.0 * two / a.trials, 100.0 * one / a.trials, e_xy, b_xy,
          b_xy > 0 ? e_xy / b_xy : 0.0, e_d, us / a.trials, iterations / a.trials,
          two > 0 ? us_warm / two : 0.0, two > 0 ? 100.0 * warm / two : 0.0);
      char row[160];
      std::snprintf(row, sizeof row, "%g,%g,%d,%.4f,%.4f,%.5f,%.5f,%.5f,%.1f,%.1f,%.4f\n", sep,
                    depth, a.trials, double(two) / a.trials, double(one) / a.trials, e_xy, b_xy,
                    e_d, us / a.trials, two > 0 ? us_warm / two : 0.0,
                    two > 0 ? double(warm) / two : 0.0);
      csv += row;
      std::fflush(stdout);
    }
  }

  // Single presses: on the unit itself, and on units whose physics the estimator's model lacks
  // (the nominal design's model against an anisotropic lattice and a stiffer lateral coupling).
  std::printf(
      "\nSingle presses (depth uniform 0.5-4.5 mm, anywhere within +-55 mm): how often they are "
      "split into two, and the run time of the single fit alone and of the count.\n\n"
      "| unit | estimator's model | presses | fitted above 1.5x noise | split into two | "
      "us / sample, single fit | us / sample, count |\n|---|---|---:|---:|---:|---:|---:|\n");
  const sim::PatchModel nominal = sim::PatchModel::nominal(design).value();
  auto nominal_physics = PhysicsEstimator::create(nominal);
  if (!nominal_physics.ok()) return nominal_physics.error();
  const std::vector<CountCase> cases = count_cases(design, *unit, &*physics, &*nominal_physics);
  for (const CountCase& c : cases) {
    int splits = 0, poor = 0;
    double us_single = 0, us_count = 0;
    for (int t = 0; t < a.single_trials; ++t) {
      const Contact press{rng.uniform(-55, 55), rng.uniform(-55, 55), rng.uniform(0.5, 4.5), 5};
      const auto f = noisy_field(c.truth, std::span<const Contact>(&press, 1), rng);
      auto t0 = Clock::now();
      const PhysicsEstimate s = c.estimator->estimate(f);
      us_single += us_since(t0);
      t0 = Clock::now();
      const ContactCountEstimate e = c.estimator->estimate_contacts(f);
      us_count += us_since(t0);
      poor += s.reduced_chi2 > 1.5;
      splits += e.count == 2;
    }
    std::printf("| %s | %s | %d | %d | %d | %.0f | %.0f |\n", c.unit, c.model, a.single_trials,
                poor, splits, us_single / a.single_trials, us_count / a.single_trials);
  }
  if (!a.csv.empty()) {
    if (Status st = write_file_atomic(a.csv, csv, "pairs table"); !st.ok()) return st;
  }
  return Status::Ok();
}

}  // namespace skinbus::estimators_bench
