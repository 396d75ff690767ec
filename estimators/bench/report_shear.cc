// skinbus-bench shear: the shear force's error against its Cramer-Rao bound per depth, what
// fitting it does for the position, its run time, and how it holds on units whose physics the
// estimator's model lacks.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "bench_time.h"
#include "skinbus/common/atomic_file.h"
#include "skinbus/common/stats.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/estimators_bench/reports.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators_bench {
namespace {

using namespace skinbus::estimators;
using sim::Contact;

// A press anywhere within +-55 mm at `depth_mm` (5 mm tip) with a shear of a friction
// coefficient uniform in [0, max_friction] of its normal force, in a random direction; every
// fourth press without shear.
Contact sheared_press(const sim::PatchModel& truth, double depth_mm, double max_friction, int i,
                      sim::Rng& rng) {
  Contact c{rng.uniform(-55, 55), rng.uniform(-55, 55), depth_mm, 5};
  const double mag = i % 4 == 0 ? 0.0 : rng.uniform(0, max_friction) * truth.force_n(depth_mm);
  const double dir = rng.uniform(0, 2 * M_PI);
  c.shear_u_n = mag * std::cos(dir);
  c.shear_v_n = mag * std::sin(dir);
  return c;
}

double rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0 : std::sqrt(s / static_cast<double>(v.size()));
}

}  // namespace

Status bench_shear(const ShearBenchArgs& a) {
  const sim::PatchDesign design;
  auto unit = sim::PatchModel::fabricated(design, a.uid, sim::FabricationVariation{});
  if (!unit.ok()) return unit.error();
  PhysicsOptions with;
  with.fit_shear = true;
  with.covariance = true;
  auto shear = PhysicsEstimator::create(*unit, with);
  if (!shear.ok()) return shear.error();
  auto plain = PhysicsEstimator::create(*unit);
  if (!plain.ok()) return plain.error();
  const ChannelNoise noise = ChannelNoise::of(design);
  sim::Rng rng(a.seed);
  std::string csv =
      "depth_mm,trials,shear_rms_n,crlb_shear_rms_n,error_over_crlb_rms,signs_right,"
      "signs_told,xy_mean_mm,xy_mean_without_shear_mm,crlb_xy_mean_mm,depth_mean_mm,"
      "us_cold,us_warm,us_warm_without_shear\n";
  std::printf(
      "Presses anywhere within +-55 mm (5 mm tip) with a shear force of friction coefficient "
      "uniform 0-%.2f of the normal force in a random direction (every fourth none), on a "
      "fabricated unit (UID 0x%llx; the estimator on its own model), the design's sensor noise; "
      "%d presses a row, seed %llu. CRLB: u, v, depth, the shear and the ambient offset unknown. "
      "Error / CRLB: RMS over presses of each one's error in units of its own bound. Signs: "
      "components more than 4 bounds from 0 with the right sign. us: cold, estimate() from the "
      "start table; warm, refine_lm() started 0.3 mm and 0.1 N off (the host's warm start from "
      "the previous sample).\n\n",
      a.max_friction, static_cast<unsigned long long>(a.uid), a.trials,
      static_cast<unsigned long long>(a.seed));
  std::printf(
      "| depth (mm) | shear RMS error (N) | CRLB (N) | error / CRLB | signs right | XY mean (mm) "
      "| without shear fit (mm) | XY CRLB (mm) | depth mean (mm) | us cold | us warm | us warm, "
      "no shear |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (double depth : a.depths) {
    std::vector<double> err, bound, norm, xy, xy_plain, xy_bound, derr;
    int told = 0, right = 0;
    double us_cold = 0, us_warm = 0, us_plain = 0;
    for (int t = 0; t < a.trials; ++t) {
      const Contact c = sheared_press(*unit, depth, a.max_friction, t, rng);
      const auto f = noisy_field(*unit, std::span<const Contact>(&c, 1), rng);
      auto t0 = Clock::now();
      const PhysicsEstimate e = shear->estimate(f);
      us_cold += us_since(t0);
      ContactEstimate start;
      start.u_mm = c.u_mm + rng.uniform(-0.3, 0.3);
      start.v_mm = c.v_mm + rng.uniform(-0.3, 0.3);
      start.depth_mm = c.depth_mm + rng.uniform(-0.05, 0.05);
      start.shear_u_n = c.shear_u_n + rng.uniform(-0.1, 0.1);
      start.shear_v_n = c.shear_v_n + rng.uniform(-0.1, 0.1);
      t0 = Clock::now();
      const PhysicsEstimate w = shear->refine_lm(f, {}, start);
      us_warm += us_since(t0);
      t0 = Clock::now();
      const PhysicsEstimate p = plain->refine_lm(f, {}, start);
      us_plain += us_since(t0);
      (void)w;
      const sim::CrlbShear b = sim::crlb_shear_at(*unit, c, noise.xy_ut, noise.z_ut, true);
      if (!e.contact.valid() || !b.identifiable) continue;
      const double du = e.contact.shear_u_n - c.shear_u_n, dv = e.contact.shear_v_n - c.shear_v_n;
      err.push_back(std::hypot(du, dv));
      bound.push_back(b.sd_shear_n);
      norm.push_back(std::hypot(du, dv) / b.sd_shear_n);
      xy.push_back(std::hypot(e.contact.u_mm - c.u_mm, e.contact.v_mm - c.v_mm));
      xy_plain.push_back(std::hypot(p.contact.u_mm - c.u_mm, p.contact.v_mm - c.v_mm));
      xy_bound.push_back(b.contact.sd_xy_mm);
      derr.push_back(std::fabs(e.contact.depth_mm - c.depth_mm));
      for (int k = 0; k < 2; ++k) {
        const double truth = k == 0 ? c.shear_u_n : c.shear_v_n;
        const double got = k == 0 ? e.contact.shear_u_n : e.contact.shear_v_n;
        if (std::fabs(truth) > 4 * (k == 0 ? b.sd_shear_u_n : b.sd_shear_v_n)) {
          ++told;
          right += (got > 0) == (truth > 0);
        }
      }
    }
    const double n = a.trials;
    std::printf(
        "| %.1f | %.3f | %.3f | %.2f | %d of %d | %.3f | %.3f | %.3f | %.3f | %.0f | %.0f | %.0f "
        "|\n",
        depth, rms(err), rms(bound), rms(norm), right, told, xy.empty() ? 0 : mean(xy),
        xy_plain.empty() ? 0 : mean(xy_plain), xy_bound.empty() ? 0 : mean(xy_bound),
        derr.empty() ? 0 : mean(derr), us_cold / n, us_warm / n, us_plain / n);
    char row[320];
    std::snprintf(row, sizeof row,
                  "%g,%d,%.5f,%.5f,%.4f,%d,%d,%.5f,%.5f,%.5f,%.5f,%.1f,%.1f,%.1f\n", depth,
                  a.trials, rms(err), rms(bound), rms(norm), right, told, xy.empty() ? 0 : mean(xy),
                  xy_plain.empty() ? 0 : mean(xy_plain), xy_bound.empty() ? 0 : mean(xy_bound),
                  derr.empty() ? 0 : mean(derr), us_cold / n, us_warm / n, us_plain / n);
    csv += row;
    std::fflush(stdout);
  }

  // Units whose physics the estimator's model (the nominal design's) lacks or has wrong.
  std::printf(
      "\nUnits outside the estimator's model (the nominal design's), presses as above at depths "
      "uniform 1-4 mm. Magnitude: median of estimated / true |F| over presses with |F| > 1 N; "
      "direction: median angle between them; false shear: presses without shear whose estimate "
      "is more than 3 stated sigmas from 0.\n\n"
      "| unit | shear RMS error (N) | CRLB (N) | magnitude | direction (deg) | false shear | "
      "XY mean (mm) | reduced chi2 median |\n|---|---:|---:|---:|---:|---:|---:|---:|\n");
  const sim::PatchModel nominal = sim::PatchModel::nominal(design).value();
  auto nominal_shear = PhysicsEstimator::create(nominal, with);
  if (!nominal_shear.ok()) return nominal_shear.error();
  struct Case {
    const char* unit;
    sim::PatchDesign truth;
  };
  std::vector<Case> cases = {{"nominal (in the model)", design}};
  cases.push_back({"anisotropic lattice 0.1", design});
  cases.back().truth.anisotropy = 0.1;
  cases.push_back({"lateral coupling 2.6 mm (model 2)", design});
  cases.back().truth.lateral_mm = 2.6;
  cases.push_back({"shear stiffness 1.75 N/mm (model 1.4)", design});
  cases.back().truth.shear_stiffness_n_per_mm = 1.75;
  cases.push_back({"shear spread 10 mm (model 8)", design});
  cases.back().truth.shear_spread_mm = 10;
  for (const Case& k : cases) {
    const sim::PatchModel truth = sim::PatchModel::nominal(k.truth).value();
    std::vector<double> err, bound, ratio, angle, xy, chi2;
    int zero = 0, false_shear = 0;
    for (int t = 0; t < a.trials; ++t) {
      const Contact c = sheared_press(truth, rng.uniform(1, 4), a.max_friction, t, rng);
      const auto f = noisy_field(truth, std::span<const Contact>(&c, 1), rng);
      const PhysicsEstimate e = nominal_shear->estimate(f);
      if (!e.contact.valid()) continue;
      const sim::CrlbShear b = sim::crlb_shear_at(truth, c, noise.xy_ut, noise.z_ut, true);
      const double fu = e.contact.shear_u_n, fv = e.contact.shear_v_n;
      err.push_back(std::hypot(fu - c.shear_u_n, fv - c.shear_v_n));
      if (b.identifiable) bound.push_back(b.sd_shear_n);
      xy.push_back(std::hypot(e.contact.u_mm - c.u_mm, e.contact.v_mm - c.v_mm));
      chi2.push_back(e.reduced_chi2);
      const double true_mag = std::hypot(c.shear_u_n, c.shear_v_n);
      if (true_mag > 1) {
        ratio.push_back(std::hypot(fu, fv) / true_mag);
        const double cosang =
            (fu * c.shear_u_n + fv * c.shear_v_n) / (std::hypot(fu, fv) * true_mag + 1e-300);
        angle.push_back(std::acos(std::clamp(cosang, -1.0, 1.0)) * 180 / M_PI);
      }
      if (true_mag == 0) {
        ++zero;
        false_shear += std::isfinite(e.sigma_shear_n) && std::hypot(fu, fv) > 3 * e.sigma_shear_n;
      }
    }
    std::printf("| %s | %.3f | %.3f | %.2f | %.1f | %d of %d | %.3f | %.2f |\n", k.unit, rms(err),
                rms(bound), ratio.empty() ? 0 : quantile(ratio, 0.5),
                angle.empty() ? 0 : quantile(angle, 0.5), false_shear, zero,
                xy.empty() ? 0 : mean(xy), chi2.empty() ? 0 : quantile(chi2, 0.5));
    std::fflush(stdout);
  }

  // Two presses, each with its own shear: estimate_contacts() with fit_shear (the pair's fit over
  // both contacts' u, v, depth and shear), on the fabricated unit with its own model; and single
  // sheared presses on units outside the model, which must stay one.
  std::printf(
      "\nTwo presses at once, each 2-3.5 mm deep with its own shear as above (friction 0-%.2f, "
      "every fourth none), centred within +-25 mm, on the fabricated unit; estimate_contacts() "
      "with fit_shear. Counted two: of %d pairs a row. Shear error / CRLB: RMS over both presses "
      "of each one's error in units of its own two-contact bound (sim::crlb_pair_shear_at: both "
      "contacts' u, v, depth and shear and the ambient unknown). us: per sample, the count "
      "included.\n\n"
      "| separation (mm) | counted two | shear error / CRLB | shear CRLB RMS (N) | signs right | "
      "XY mean (mm) | XY CRLB mean (mm) | us |\n|---:|---:|---:|---:|---:|---:|---:|---:|\n",
      a.max_friction, a.trials / 2);
  for (double separation : {20.0, 30.0, 40.0, 60.0}) {
    std::vector<double> norm, bound, xy, xy_bound;
    int two = 0, told = 0, right = 0;
    double us = 0;
    const int pairs = a.trials / 2;
    for (int t = 0; t < pairs; ++t) {
      const double mu = rng.uniform(-25, 25), mv = rng.uniform(-25, 25);
      const double dir = rng.uniform(0, M_PI), h = separation / 2;
      Contact p[2];
      for (int k = 0; k < 2; ++k) {
        p[k] = sheared_press(*unit, rng.uniform(2, 3.5), a.max_friction, 2 * t + k, rng);
        p[k].u_mm = mu + (k == 0 ? h : -h) * std::cos(dir);
        p[k].v_mm = mv + (k == 0 ? h : -h) * std::sin(dir);
      }
      const auto f = noisy_field(*unit, std::span<const Contact>(p, 2), rng);
      const auto t0 = Clock::now();
      const ContactCountEstimate e = shear->estimate_contacts(f);
      us += us_since(t0);
      if (e.count != 2) continue;
      ++two;
      const sim::CrlbPairShear b =
          sim::crlb_pair_shear_at(*unit, p[0], p[1], noise.xy_ut, noise.z_ut, true);
      if (!b.first.identifiable) continue;
      const bool straight =
          std::hypot(e.contacts[0].u_mm - p[0].u_mm, e.contacts[0].v_mm - p[0].v_mm) <
          std::hypot(e.contacts[0].u_mm - p[1].u_mm, e.contacts[0].v_mm - p[1].v_mm);
      for (int k = 0; k < 2; ++k) {
        const ContactEstimate& c = e.contacts[straight ? k : 1 - k];
        const sim::CrlbShear& bk = k == 0 ? b.first : b.second;
        norm.push_back(std::hypot(c.shear_u_n - p[k].shear_u_n, c.shear_v_n - p[k].shear_v_n) /
                       bk.sd_shear_n);
        bound.push_back(bk.sd_shear_n);
        xy.push_back(std::hypot(c.u_mm - p[k].u_mm, c.v_mm - p[k].v_mm));
        xy_bound.push_back(bk.contact.sd_xy_mm);
        for (int j = 0; j < 2; ++j) {
          const double truth = j == 0 ? p[k].shear_u_n : p[k].shear_v_n;
          const double got = j == 0 ? c.shear_u_n : c.shear_v_n;
          if (std::fabs(truth) > 4 * (j == 0 ? bk.sd_shear_u_n : bk.sd_shear_v_n)) {
            ++told;
            right += (got > 0) == (truth > 0);
          }
        }
      }
    }
    std::printf("| %.0f | %d of %d | %.2f | %.3f | %d of %d | %.3f | %.3f | %.0f |\n", separation,
                two, pairs, rms(norm), rms(bound), right, told, xy.empty() ? 0 : mean(xy),
                xy_bound.empty() ? 0 : mean(xy_bound), us / std::max(pairs, 1));
    std::fflush(stdout);
  }
  {
    int splits = 0, total = 0;
    for (std::size_t i = 1; i < cases.size(); ++i) {  // cases[0] is the model's own design
      const sim::PatchModel truth = sim::PatchModel::nominal(cases[i].truth).value();
      for (int t = 0; t < a.trials; ++t) {
        const Contact c = sheared_press(truth, rng.uniform(1, 4), a.max_friction, t, rng);
        const auto f = noisy_field(truth, std::span<const Contact>(&c, 1), rng);
        ++total;
        splits += nominal_shear->estimate_contacts(f).count == 2;
      }
    }
    std::printf(
        "\nSingle sheared presses on the four units outside the model (the table above), counted "
        "with fit_shear by the nominal model: %d of %d split into two.\n",
        splits, total);
  }
  if (!a.csv.empty()) {
    if (Status st = write_file_atomic(a.csv, csv, "shear table"); !st.ok()) return st;
  }
  return Status::Ok();
}

}  // namespace skinbus::estimators_bench
