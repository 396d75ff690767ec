// PhysicsEstimator::estimate_contacts: the contact count (0 to 3) and several contacts' places.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <tuple>
#include <utility>
#include <vector>

#include "skinbus/common/test_seed.h"
#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators {
namespace {

using sim::Contact;

double distance(const ContactEstimate& e, const Contact& c) {
  return std::hypot(e.u_mm - c.u_mm, e.v_mm - c.v_mm);
}

TEST(ContactCount, TwoPressesThirtyMillimetresApartAreResolvedOnAFabricatedUnit) {
  const sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, 0x5b0000000000002a, sim::FabricationVariation{}).value();
  // The estimator on the unit's own model (what identification gives, to its residual).
  const PhysicsEstimator physics = PhysicsEstimator::create(unit).value();
  sim::Rng rng(test_seed("TwoPressesThirtyMillimetresApartAreResolvedOnAFabricatedUnit"));
  int resolved = 0, placed = 0;
  const int n = 60;
  for (int i = 0; i < n; ++i) {
    const double mu = rng.uniform(-30, 30), mv = rng.uniform(-30, 30), a = rng.uniform(0, M_PI);
    const Contact presses[2] = {
        {mu + 15 * std::cos(a), mv + 15 * std::sin(a), rng.uniform(2, 3.5), 5},
        {mu - 15 * std::cos(a), mv - 15 * std::sin(a), rng.uniform(2, 3.5), 5}};
    const auto f = noisy_field(unit, presses, rng);
    const ContactCountEstimate e = physics.estimate_contacts(f);
    if (e.count != 2) continue;
    ++resolved;
    // Either order: each press has an estimate within 2 mm (the bound at 30 mm: ~0.3-0.4 mm).
    const bool straight =
        distance(e.contacts[0], presses[0]) + distance(e.contacts[1], presses[1]) <
        distance(e.contacts[0], presses[1]) + distance(e.contacts[1], presses[0]);
    const ContactEstimate& first = straight ? e.contacts[0] : e.contacts[1];
    const ContactEstimate& second = straight ? e.contacts[1] : e.contacts[0];
    if (distance(first, presses[0]) < 2 && distance(second, presses[1]) < 2) ++placed;
  }
  std::printf("two presses 30 mm apart: %d of %d counted two, %d placed within 2 mm\n", resolved, n,
              placed);
  // 96 % of such pairs are counted two (6000 pairs over 300 seeds). Of the 4 % missed, 70 % have
  // one press within 8 mm of the patch's centre, where the pair explains the sample to the noise
  // but improves the single fit's reduced chi-square by less than the 20x the count asks
  // (ContactCountOptions::min_improvement; 8-21x there), the rest mostly pairs near the edge
  // fitted as one. 85 % here, as at 17 of 20 before, over 60 pairs: at 20, three misses too many
  // failed about one run in 200.
  EXPECT_GE(resolved, n - 9);
  EXPECT_GE(placed, resolved - 3);
}

TEST(ContactCount, OnePressIsNeverSplitOnUnitsWhosePhysicsIsOutsideTheModelClass) {
  // The estimator's model: the nominal design. The units: anisotropic lattices (the spread 20 %
  // longer along u than v), a stiffer in-plane coupling, and fabrication variation, none of
  // which the nominal model holds.
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  // With and without each contact's shear fitted (more unknowns absorb more of a mismatch).
  PhysicsOptions with_shear;
  with_shear.fit_shear = true;
  const PhysicsEstimator estimators[2] = {PhysicsEstimator::create(nominal).value(),
                                          PhysicsEstimator::create(nominal, with_shear).value()};
  sim::PatchDesign anisotropic, lateral;
  anisotropic.anisotropy = 0.1;
  lateral.lateral_mm = 2.6;
  const sim::PatchModel units[] = {
      sim::PatchModel::nominal(anisotropic).value(), sim::PatchModel::nominal(lateral).value(),
      sim::PatchModel::fabricated(sim::PatchDesign{}, 7, sim::FabricationVariation{}).value()};
  sim::Rng rng(test_seed("OnePressIsNeverSplitOnUnitsWhosePhysicsIsOutsideTheModelClass"));
  int splits = 0, poor = 0, total = 0;
  for (const auto& unit : units) {
    for (int i = 0; i < 40; ++i) {
      const Contact press{rng.uniform(-55, 55), rng.uniform(-55, 55), rng.uniform(0.5, 4.5), 5};
      const auto f = noisy_field(unit, std::span<const Contact>(&press, 1), rng);
      const ContactCountEstimate e = estimators[i % 2].estimate_contacts(f);
      ++total;
      poor += e.single.reduced_chi2 > 1.5;
      if (e.count == 2) {
        ++splits;
        std::printf(
            "split: press (%.1f, %.1f, %.2f) -> (%.1f, %.1f, %.2f) + (%.1f, %.1f, %.2f), "
            "reduced chi2 %.2f -> %.2f\n",
            press.u_mm, press.v_mm, press.depth_mm, e.contacts[0].u_mm, e.contacts[0].v_mm,
            e.contacts[0].depth_mm, e.contacts[1].u_mm, e.contacts[1].v_mm, e.contacts[1].depth_mm,
            e.single.reduced_chi2, e.pair_reduced_chi2);
      }
    }
  }
  std::printf("single presses on mismatched units: %d of %d split, %d fitted above 1.5 x noise\n",
              splits, total, poor);
  EXPECT_GT(poor, total / 4);  // the mismatch is real: the single fit is often poor
  EXPECT_EQ(splits, 0);
}

TEST(ContactCount, NothingCoincidentAndNonFiniteGiveCountsWithoutNaN) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const PhysicsEstimator physics = PhysicsEstimator::create(nominal).value();
  sim::Rng rng(test_seed("NothingCoincidentAndNonFiniteGiveCountsWithoutNaN"));
  const auto quiet = noisy_field(nominal, {}, rng);
  EXPECT_EQ(physics.estimate_contacts(quiet).count, 0);
  const Contact same[2] = {{10, -5, 2, 5}, {10, -5, 2, 5}};
  const ContactCountEstimate coincident =
      physics.estimate_contacts(noisy_field(nominal, same, rng));
  EXPECT_EQ(coincident.count, 1);  // two presses at one place are one deeper press
  for (const auto& c : coincident.contacts) {
    EXPECT_TRUE(std::isfinite(c.u_mm) && std::isfinite(c.v_mm) && std::isfinite(c.depth_mm));
  }
  ContactCountOptions three;
  three.max_contacts = 3;
  const Contact triple[3] = {{10, -5, 2, 5}, {10, -5, 2, 5}, {-30, 20, 2.5, 5}};
  const ContactCountEstimate two_at_one =
      physics.estimate_contacts(noisy_field(nominal, triple, rng), {}, three);
  EXPECT_LE(two_at_one.count, 2);  // two at one place and one apart: at most two
  for (const auto& c : two_at_one.contacts) {
    EXPECT_TRUE(std::isfinite(c.u_mm) && std::isfinite(c.v_mm) && std::isfinite(c.depth_mm));
  }
  std::vector<double> bad(quiet);
  bad[5] = std::nan("");
  const ContactCountEstimate e = physics.estimate_contacts(bad);
  for (const auto& c : e.contacts) EXPECT_TRUE(std::isfinite(c.u_mm) && std::isfinite(c.depth_mm));
}

// Two presses, each dragging the skin its own way: with fit_shear the pair's fit recovers each
// one's shear, sign and magnitude, at the two-contact bound (sim::crlb_pair_shear_at).
TEST(ContactCount, EachOfTwoPressesHasItsOwnShearAtTheBound) {
  const sim::PatchModel unit = sim::PatchModel::fabricated(sim::PatchDesign{}, 0x5b0000000000002b,
                                                           sim::FabricationVariation{})
                                   .value();
  PhysicsOptions o;
  o.fit_shear = true;
  o.covariance = true;
  const PhysicsEstimator physics = PhysicsEstimator::create(unit, o).value();
  const ChannelNoise noise = ChannelNoise::of(unit.design());
  sim::Rng rng(test_seed("EachOfTwoPressesHasItsOwnShearAtTheBound"));
  int counted = 0, signs = 0, components = 0;
  double err2 = 0, bound2 = 0, stated2 = 0;
  // 48 pairs: the error's RMS over the bound then scatters by about 0.08 from seed to seed (0.14
  // over 16 pairs, where 0.6-1.4 failed about one seed in 100).
  const int n = 48;
  for (int i = 0; i < n; ++i) {
    const double mu = rng.uniform(-25, 25), mv = rng.uniform(-25, 25), a = rng.uniform(0, M_PI);
    Contact presses[2] = {{mu + 20 * std::cos(a), mv + 20 * std::sin(a), rng.uniform(2, 3.5), 5},
                          {mu - 20 * std::cos(a), mv - 20 * std::sin(a), rng.uniform(2, 3.5), 5}};
    for (Contact& p : presses) {  // a friction coefficient of 0.2-0.4, any direction
      const double mag = rng.uniform(0.2, 0.4) * unit.force_n(p.depth_mm);
      const double dir = rng.uniform(0, 2 * M_PI);
      p.shear_u_n = mag * std::cos(dir);
      p.shear_v_n = mag * std::sin(dir);
    }
    const auto f = noisy_field(unit, presses, rng);
    const ContactCountEstimate e = physics.estimate_contacts(f);
    if (e.count != 2) continue;
    ++counted;
    const sim::CrlbPairShear b =
        sim::crlb_pair_shear_at(unit, presses[0], presses[1], noise.xy_ut, noise.z_ut, true);
    const bool straight = distance(e.contacts[0], presses[0]) < distance(e.contacts[0], presses[1]);
    for (int k = 0; k < 2; ++k) {
      const ContactEstimate& c = e.contacts[straight ? k : 1 - k];
      const double su = presses[k].shear_u_n, sv = presses[k].shear_v_n;
      const sim::CrlbShear& bk = k == 0 ? b.first : b.second;
      for (const auto& [est, truth, sd] : {std::tuple{c.shear_u_n, su, bk.sd_shear_u_n},
                                           std::tuple{c.shear_v_n, sv, bk.sd_shear_v_n}}) {
        if (std::fabs(truth) > 4 * sd) {
          ++components;
          signs += (est > 0) == (truth > 0);
        }
      }
      err2 += std::pow(c.shear_u_n - su, 2) + std::pow(c.shear_v_n - sv, 2);
      bound2 += bk.sd_shear_n * bk.sd_shear_n;
      const double stated = e.sigma_shear_n[straight ? k : 1 - k];
      ASSERT_TRUE(std::isfinite(stated));
      stated2 += stated * stated;
    }
  }
  std::printf(
      "two sheared presses 40 mm apart: %d of %d counted two; shear RMS error / bound %.2f, "
      "stated / bound %.2f; %d of %d components beyond 4 bounds of the right sign\n",
      counted, n, std::sqrt(err2 / bound2), std::sqrt(stated2 / bound2), signs, components);
  // skinbus-bench shear counts 90-96 % of such pairs two (the rest one).
  EXPECT_GE(counted, n - n / 3);
  EXPECT_EQ(signs, components);
  EXPECT_GT(components, counted);  // the shear is told from none, mostly
  EXPECT_LT(std::sqrt(err2 / bound2), 1.4);
  EXPECT_GT(std::sqrt(err2 / bound2), 0.6);
  EXPECT_NEAR(std::sqrt(stated2 / bound2), 1.0, 0.3);
}

// A single fit started between two presses can run off the patch and find nothing; with the
// previous pair given, the count still tries it and finds both. Without the pair it is nothing.
// Over 20 noise draws: a pair fitted right is still refused when the noise alone leaves a reduced
// chi-square above max_reduced_chi2 (1.6 on 39 degrees of freedom: about 1 % of draws).
TEST(ContactCount, AGivenPairIsTriedWhenTheSingleFitFoundNothing) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const PhysicsEstimator physics = PhysicsEstimator::create(nominal).value();
  sim::Rng rng(test_seed("AGivenPairIsTriedWhenTheSingleFitFoundNothing"));
  const Contact presses[2] = {{-33, 8, 2.5, 5}, {23, 8, 2.5, 5}};
  const int draws = 20;
  int found = 0;
  for (int d = 0; d < draws; ++d) {
    const auto f = noisy_field(nominal, presses, rng);
    // The single fit from the middle, taken as it may come out: off the patch, nothing pressed.
    ContactEstimate mid;
    mid.u_mm = -5;
    mid.v_mm = 8;
    mid.depth_mm = 2;
    PhysicsEstimate single = physics.refine_lm(f, {}, mid);
    single.contact.u_mm = 85;
    single.contact.v_mm = 85;
    single.contact.depth_mm = 0;
    single.contact.flags |= kEstimateNoContact | kEstimateOutsidePatch;
    ContactEstimate previous[2];
    for (int k = 0; k < 2; ++k) {
      previous[k].u_mm = presses[k].u_mm + 0.75;
      previous[k].v_mm = presses[k].v_mm;
      previous[k].depth_mm = presses[k].depth_mm;
    }
    const ContactCountEstimate with = physics.count_contacts(f, {}, single, {}, previous);
    EXPECT_TRUE(with.pair_tried) << d;
    if (with.count == 2) {
      ++found;
      for (int k = 0; k < 2; ++k) EXPECT_LT(distance(with.contacts[k], presses[k]), 1.0) << k;
    } else {
      std::printf("draw %d: the pair refused at reduced chi-square %.2f\n", d,
                  with.pair_reduced_chi2);
    }
    const ContactCountEstimate without = physics.count_contacts(f, {}, single, {}, {});
    EXPECT_EQ(without.count, 0) << d;
  }
  EXPECT_GE(found, draws - 2);
}

// Three fingers: presses at the corners of a triangle of 40 mm sides, on a fabricated unit with
// the estimator on its own model and max_contacts 3.
TEST(ContactCount, ThreePressesFortyMillimetresApartAreResolvedOnAFabricatedUnit) {
  const sim::PatchModel unit = sim::PatchModel::fabricated(sim::PatchDesign{}, 0x5b0000000000002c,
                                                           sim::FabricationVariation{})
                                   .value();
  const PhysicsEstimator physics = PhysicsEstimator::create(unit).value();
  ContactCountOptions three;
  three.max_contacts = 3;
  sim::Rng rng(test_seed("ThreePressesFortyMillimetresApartAreResolvedOnAFabricatedUnit"));
  int counted = 0, placed = 0, two = 0;
  const int n = 12;
  for (int i = 0; i < n; ++i) {
    const double mu = rng.uniform(-15, 15), mv = rng.uniform(-15, 15), a = rng.uniform(0, M_PI);
    const double r = 40 / std::sqrt(3.0);  // the circumradius of the triangle
    Contact presses[3];
    for (int k = 0; k < 3; ++k) {
      const double t = a + k * 2 * M_PI / 3;
      presses[k] = {mu + r * std::cos(t), mv + r * std::sin(t), rng.uniform(2, 3.5), 5};
    }
    const auto f = noisy_field(unit, presses, rng);
    const ContactCountEstimate e = physics.estimate_contacts(f, {}, three);
    two += e.count == 2;
    if (e.count != 3) continue;
    ++counted;
    int match[3];
    ASSERT_TRUE(match_contacts<Contact>(e.contacts, presses, match));
    double worst = 0;
    for (int k = 0; k < 3; ++k) worst = std::max(worst, distance(e.contacts[match[k]], presses[k]));
    if (worst < 2) ++placed;
    for (int k = 0; k < 3; ++k)
      EXPECT_TRUE(std::isfinite(e.sigma_uv_mm[k]) || !physics.options().covariance);
  }
  std::printf("three presses 40 mm apart: %d of %d counted three (%d two), %d placed within 2 mm\n",
              counted, n, two, placed);
  EXPECT_GE(counted, n - 3);
  EXPECT_GE(placed, counted - 1);
  // The same presses with max_contacts 2 (the default): never three.
  const Contact p3[3] = {{-20, -10, 3, 5}, {20, -10, 3, 5}, {0, 25, 3, 5}};
  EXPECT_LE(physics.estimate_contacts(noisy_field(unit, p3, rng)).count, 2);
}

// Three presses each dragging the skin its own way, with fit_shear (each contact's shear fitted:
// 18 unknowns): counted three, each press's shear of the right sign where it is beyond 4 of the
// fit's stated sigmas.
TEST(ContactCount, ThreeShearedPressesAreCountedWithTheirShears) {
  const sim::PatchModel unit = sim::PatchModel::fabricated(sim::PatchDesign{}, 0x5b0000000000002d,
                                                           sim::FabricationVariation{})
                                   .value();
  PhysicsOptions o;
  o.fit_shear = true;
  o.covariance = true;
  const PhysicsEstimator physics = PhysicsEstimator::create(unit, o).value();
  ContactCountOptions three;
  three.max_contacts = 3;
  sim::Rng rng(test_seed("ThreeShearedPressesAreCountedWithTheirShears"));
  int counted = 0, signs = 0, components = 0;
  double err2 = 0, truth2 = 0;
  const int n = 12;
  for (int i = 0; i < n; ++i) {
    const double a = rng.uniform(0, M_PI), r = 50 / std::sqrt(3.0);
    Contact presses[3];
    for (int k = 0; k < 3; ++k) {
      const double t = a + k * 2 * M_PI / 3;
      presses[k] = {r * std::cos(t), r * std::sin(t), rng.uniform(2, 3.5), 5};
      const double mag = rng.uniform(0.25, 0.4) * unit.force_n(presses[k].depth_mm);
      const double dir = rng.uniform(0, 2 * M_PI);
      presses[k].shear_u_n = mag * std::cos(dir);
      presses[k].shear_v_n = mag * std::sin(dir);
    }
    const ContactCountEstimate e =
        physics.estimate_contacts(noisy_field(unit, presses, rng), {}, three);
    if (e.count != 3) continue;
    ++counted;
    int match[3];
    ASSERT_TRUE(match_contacts<Contact>(e.contacts, presses, match));
    for (int k = 0; k < 3; ++k) {
      const ContactEstimate& c = e.contacts[match[k]];
      const double sigma = e.sigma_shear_n[match[k]];  // the fit's own, N
      ASSERT_TRUE(std::isfinite(sigma));
      for (const auto& [est, truth] : {std::pair{c.shear_u_n, presses[k].shear_u_n},
                                       std::pair{c.shear_v_n, presses[k].shear_v_n}}) {
        if (std::fabs(truth) > 4 * sigma) {  // told from none by the fit's own uncertainty
          ++components;
          signs += (est > 0) == (truth > 0);
        }
        err2 += (est - truth) * (est - truth);
        truth2 += truth * truth;
      }
    }
  }
  std::printf(
      "three sheared presses 50 mm apart: %d of %d counted three; %d of %d components of the "
      "right sign; shear RMS error %.0f %% of the shear's RMS\n",
      counted, n, signs, components, truth2 > 0 ? 100 * std::sqrt(err2 / truth2) : 0.0);
  // ~97 % are counted three (40 runs of 8): 8 of 12 fails about one run in 4000.
  EXPECT_GE(counted, n - 4);
  EXPECT_EQ(signs, components);
  EXPECT_GT(components, counted);
  EXPECT_LT(std::sqrt(err2 / truth2), 0.35);
}

// Model-order choice beyond two: two presses on units whose physics the estimator's model lacks
// are never counted three, and neither is one press.
TEST(ContactCount, OneOrTwoPressesAreNeverCountedThreeOnUnitsOutsideTheModelClass) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const PhysicsEstimator physics = PhysicsEstimator::create(nominal).value();
  ContactCountOptions three;
  three.max_contacts = 3;
  sim::PatchDesign anisotropic, lateral;
  anisotropic.anisotropy = 0.1;
  lateral.lateral_mm = 2.6;
  const sim::PatchModel units[] = {
      sim::PatchModel::nominal(anisotropic).value(), sim::PatchModel::nominal(lateral).value(),
      sim::PatchModel::fabricated(sim::PatchDesign{}, 7, sim::FabricationVariation{}).value()};
  sim::Rng rng(test_seed("OneOrTwoPressesAreNeverCountedThreeOnUnitsOutsideTheModelClass"));
  int threes = 0, pairs = 0, tried = 0, total = 0;
  for (const auto& unit : units) {
    for (int i = 0; i < 20; ++i) {
      const double mu = rng.uniform(-25, 25), mv = rng.uniform(-25, 25), a = rng.uniform(0, M_PI);
      const double half = rng.uniform(12, 30);
      const Contact presses[2] = {
          {mu + half * std::cos(a), mv + half * std::sin(a), rng.uniform(1, 4), 5},
          {mu - half * std::cos(a), mv - half * std::sin(a), rng.uniform(1, 4), 5}};
      const std::size_t n = i % 4 == 0 ? 1 : 2;  // every fourth a single press
      const auto f = noisy_field(unit, std::span<const Contact>(presses, n), rng);
      const ContactCountEstimate e = physics.estimate_contacts(f, {}, three);
      ++total;
      pairs += e.count == 2;
      tried += e.triple_tried;
      if (e.count == 3) {
        ++threes;
        std::printf("three from %zu: reduced chi2 %.2f -> %.2f -> %.2f\n", n, e.single.reduced_chi2,
                    e.pair_reduced_chi2, e.triple_reduced_chi2);
      }
    }
  }
  std::printf(
      "one or two presses on mismatched units: %d of %d counted three (%d two; three "
      "tried on %d)\n",
      threes, total, pairs, tried);
  EXPECT_GT(tried, total / 4);  // the mismatch leaves more than noise after the pair: tested
  EXPECT_EQ(threes, 0);
}

}  // namespace
}  // namespace skinbus::estimators
