// skinbus-bench triples: three presses on one patch: how often the count is right and each
// contact's error against their spacing and depth, next to the three-contact Cramer-Rao bound;
// how often one or two presses are counted three, on units whose physics the model lacks.
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "bench_time.h"
#include "mismatched_units.h"
#include "skinbus/common/atomic_file.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators/contact_proposal.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators_bench/reports.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators_bench {
namespace {

using namespace skinbus::estimators;
using sim::Contact;

// The count started from a proposal: the single fit from its deepest contact (from the start
// table when it proposes none), then count_contacts() trying its contacts first.
ContactCountEstimate count_from(const PhysicsEstimator& physics, const std::vector<double>& f,
                                const ContactProposal& p, const ContactCountOptions& count) {
  const PhysicsEstimate single =
      p.count >= 1 ? physics.refine_lm(f, {}, p.contacts[0]) : physics.estimate(f);
  // Fewer than two contacts given are no start for several: count_contacts() then searches.
  return physics.count_contacts(
      f, {}, single, count,
      std::span<const ContactEstimate>(p.contacts, static_cast<std::size_t>(p.count)));
}

}  // namespace

Status bench_triples(const TriplesBenchArgs& a) {
  const sim::PatchDesign design;
  auto unit = sim::PatchModel::fabricated(design, a.uid, sim::FabricationVariation{});
  if (!unit.ok()) return unit.error();
  // The estimator on the unit's own model (identification's result, to its residual).
  auto physics = PhysicsEstimator::create(*unit);
  if (!physics.ok()) return physics.error();
  ContactCountOptions three;
  three.max_contacts = 3;
  std::optional<NetworkRuntime> proposer;
  if (!a.proposer.empty()) {
    auto rt = load_proposer(a.proposer, unit->channel_count());
    if (!rt.ok()) return rt.error();
    proposer.emplace(std::move(*rt));
  }
  const ChannelNoise noise = ChannelNoise::of(design);
  sim::Rng rng(a.seed);
  std::string csv =
      "side_mm,depth_mm,trials,count3_rate,count2_rate,count1_rate,xy_error_mm,crlb_xy_mm,"
      "depth_error_mm,us_per_sample,us_next_sample,next_count3_rate,proposer_count3_rate,"
      "proposed_count3_rate,us_per_sample_proposed\n";
  std::printf(
      "Three presses of the same depth (5 mm tips) at the corners of an equilateral triangle of "
      "the given side, its centre uniform within +-10 mm and turned at random, on a fabricated "
      "unit (UID 0x%llx; the estimator on its own model, max_contacts 3), the design's sensor "
      "noise; %d trials a row, seed %llu. XY error: mean per contact over the samples counted "
      "three (each estimate matched to its press); CRLB: the three-contact bound at the same "
      "places (mean). us / sample: the count from nothing (estimate_contacts); us / next sample: "
      "the host's path on a second sample of the same presses (refine_lm from the first contact, "
      "then count_contacts from these three), and how often it counts three again.%s\n\n",
      static_cast<unsigned long long>(a.uid), a.trials, static_cast<unsigned long long>(a.seed),
      proposer ? " Proposer: the network's own count (three); proposed: the count started from "
                 "its answer (the single fit from its deepest contact, then count_contacts from "
                 "its contacts), counted three and its time, the network's run included."
               : "");
  std::printf(
      "| side (mm) | depth (mm) | counted 3 | counted 2 | counted 1 | XY error (mm) | CRLB (mm) | "
      "x CRLB | depth error (mm) | us / sample | us / next sample | next counted 3 | proposer: "
      "3 | proposed: counted 3 | us / sample, proposed "
      "|\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (double side : a.sides) {
    for (double depth : a.depths) {
      int counts[kMaxContacts + 1] = {};
      std::vector<double> err, bound, derr;
      double us = 0, us_warm = 0, us_proposed = 0;
      int warm = 0, proposer_three = 0, proposed_three = 0;
      for (int t = 0; t < a.trials; ++t) {
        const double mu = rng.uniform(-10, 10), mv = rng.uniform(-10, 10);
        const double turn = rng.uniform(0, 2 * M_PI), r = side / std::sqrt(3.0);
        Contact p[3];
        for (int k = 0; k < 3; ++k) {
          const double th = turn + k * 2 * M_PI / 3;
          p[k] = {mu + r * std::cos(th), mv + r * std::sin(th), depth, 5};
        }
        const auto f = noisy_field(*unit, p, rng);
        const auto t0 = Clock::now();
        const ContactCountEstimate e = physics->estimate_contacts(f, {}, three);
        us += us_since(t0);
        ++counts[e.count];
        if (proposer) {
          const auto p0 = Clock::now();
          const ContactProposal prop = propose_contacts(*proposer, f);
          const ContactCountEstimate pe = count_from(*physics, f, prop, three);
          us_proposed += us_since(p0);
          proposer_three += prop.count == 3;
          proposed_three += pe.count == 3;
        }
        if (e.count != 3) continue;
        {
          const auto f2 = noisy_field(*unit, p, rng);
          const auto w0 = Clock::now();
          const PhysicsEstimate single = physics->refine_lm(f2, {}, e.contacts[0]);
          const ContactCountEstimate w = physics->count_contacts(f2, {}, single, three, e.contacts);
          us_warm += us_since(w0);
          warm += w.count == 3;
        }
        int match[3];
        match_contacts<Contact>(e.contacts, p, match);
        for (int k = 0; k < 3; ++k) {
          const ContactEstimate& c = e.contacts[match[k]];
          err.push_back(std::hypot(c.u_mm - p[k].u_mm, c.v_mm - p[k].v_mm));
          derr.push_back(std::fabs(c.depth_mm - p[k].depth_mm));
        }
        sim::CrlbPoint b[3];
        sim::crlb_contacts_at(*unit, p, noise.xy_ut, noise.z_ut, true, b);
        for (const sim::CrlbPoint& bk : b) bound.push_back(bk.sd_xy_mm);
      }
      const double e_xy = err.empty() ? 0 : mean(err), b_xy = bound.empty() ? 0 : mean(bound);
      const double e_d = derr.empty() ? 0 : mean(derr);
      const int n3 = counts[3];
      const double pr3 = proposer ? double(proposer_three) / a.trials : 0.0;
      const double pd3 = proposer ? double(proposed_three) / a.trials : 0.0;
      const double us_p = proposer ? us_proposed / a.trials : 0.0;
      std::printf(
          "| %.0f | %.1f | %.0f %% | %.0f %% | %.0f %% | %.3f | %.3f | %.2f | %.3f | %.0f | %.0f | "
          "%.0f %% | %.0f %% | %.0f %% | %.0f |\n",
          side, depth, 100.0 * n3 / a.trials, 100.0 * counts[2] / a.trials,
          100.0 * counts[1] / a.trials, e_xy, b_xy, b_xy > 0 ? e_xy / b_xy : 0.0, e_d,
          us / a.trials, n3 > 0 ? us_warm / n3 : 0.0, n3 > 0 ? 100.0 * warm / n3 : 0.0, 100 * pr3,
          100 * pd3, us_p);
      char row[256];
      std::snprintf(row, sizeof row,
                    "%g,%g,%d,%.4f,%.4f,%.4f,%.5f,%.5f,%.5f,%.1f,%.1f,%.4f,%.4f,%.4f,%.1f\n", side,
                    depth, a.trials, double(n3) / a.trials, double(counts[2]) / a.trials,
                    double(counts[1]) / a.trials, e_xy, b_xy, e_d, us / a.trials,
                    n3 > 0 ? us_warm / n3 : 0.0, n3 > 0 ? double(warm) / n3 : 0.0, pr3, pd3, us_p);
      csv += row;
      std::fflush(stdout);
    }
  }

  // One or two presses: on the unit itself, and on units whose physics the estimator's model
  // lacks (the nominal design's model against an anisotropic lattice, a stiffer lateral
  // coupling, a fabricated unit): how often they are counted three, and what max_contacts 3 costs
  // next to 2 on them.
  std::printf(
      "\nOne or two presses (depth uniform 1-4 mm; a pair's presses 20-60 mm apart, its midpoint "
      "within +-25 mm; a single press anywhere within +-55 mm): how often they are counted three "
      "with max_contacts 3, how often right, and the run time of the count with max_contacts 2 "
      "and 3.%s\n\n"
      "| unit | estimator's model | presses | samples | counted 3 | counted right | three "
      "tried | us / sample, max 2 | us / sample, max 3 | proposer right | proposed: counted 3 | "
      "proposed: counted right |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
      proposer ? " Proposer right: the network's own count; proposed: the count started from its "
                 "answer."
               : "");
  const sim::PatchModel nominal = sim::PatchModel::nominal(design).value();
  auto nominal_physics = PhysicsEstimator::create(nominal);
  if (!nominal_physics.ok()) return nominal_physics.error();
  const std::vector<CountCase> cases = count_cases(design, *unit, &*physics, &*nominal_physics);
  for (const CountCase& c : cases) {
    for (int presses = 1; presses <= 2; ++presses) {
      int threes = 0, right = 0, tried = 0, proposer_right = 0, proposed_threes = 0,
          proposed_right = 0;
      double us2 = 0, us3 = 0;
      for (int t = 0; t < a.other_trials; ++t) {
        Contact p[2];
        if (presses == 1) {
          p[0] = {rng.uniform(-55, 55), rng.uniform(-55, 55), rng.uniform(1, 4), 5};
        } else {
          const double mu = rng.uniform(-25, 25), mv = rng.uniform(-25, 25);
          const double th = rng.uniform(0, M_PI), half = rng.uniform(10, 30);
          p[0] = {mu + half * std::cos(th), mv + half * std::sin(th), rng.uniform(1, 4), 5};
          p[1] = {mu - half * std::cos(th), mv - half * std::sin(th), rng.uniform(1, 4), 5};
        }
        const auto f = noisy_field(c.truth, std::span<const Contact>(p, presses), rng);
        auto t0 = Clock::now();
        c.estimator->estimate_contacts(f);  // max_contacts 2: its cost
        us2 += us_since(t0);
        t0 = Clock::now();
        const ContactCountEstimate e = c.estimator->estimate_contacts(f, {}, three);
        us3 += us_since(t0);
        threes += e.count == 3;
        right += e.count == presses;
        tried += e.triple_tried;
        if (proposer) {
          const ContactProposal prop = propose_contacts(*proposer, f);
          const ContactCountEstimate pe = count_from(*c.estimator, f, prop, three);
          proposer_right += prop.count == presses;
          proposed_threes += pe.count == 3;
          proposed_right += pe.count == presses;
        }
      }
      std::printf("| %s | %s | %d | %d | %d | %d | %d | %.0f | %.0f | %d | %d | %d |\n", c.unit,
                  c.model, presses, a.other_trials, threes, right, tried, us2 / a.other_trials,
                  us3 / a.other_trials, proposer_right, proposed_threes, proposed_right);
      std::fflush(stdout);
    }
  }
  if (!a.csv.empty()) {
    if (Status st = write_file_atomic(a.csv, csv, "triples table"); !st.ok()) return st;
  }
  return Status::Ok();
}

}  // namespace skinbus::estimators_bench
