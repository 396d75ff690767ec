// PhysicsEstimator::estimate_contacts: the contact count (0, 1, 2) and two contacts' places.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <tuple>
#include <vector>

#include "skinbus/common/test_seed.h"
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
  const int n = 20;
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
  // 97 % of such pairs pass the improvement the count asks (150 pairs measured): 17 of 20 here.
  EXPECT_GE(resolved, n - 3);
  EXPECT_GE(placed, resolved - 1);
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
  const int n = 16;
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
  // skinbus-bench shear counts 90-96 % of such pairs two (the rest one): 11 of 16 fails one run
  // in ~500 (random seed).
  EXPECT_GE(counted, n - 5);
  EXPECT_EQ(signs, components);
  EXPECT_GT(components, counted);  // the shear is told from none, mostly
  EXPECT_LT(std::sqrt(err2 / bound2), 1.4);
  EXPECT_GT(std::sqrt(err2 / bound2), 0.6);
  EXPECT_NEAR(std::sqrt(stated2 / bound2), 1.0, 0.3);
}

// A single fit started between two presses can run off the patch and find nothing; with the
// previous pair given, the count still tries it and finds both. Without the pair it is nothing.
TEST(ContactCount, AGivenPairIsTriedWhenTheSingleFitFoundNothing) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const PhysicsEstimator physics = PhysicsEstimator::create(nominal).value();
  sim::Rng rng(test_seed("AGivenPairIsTriedWhenTheSingleFitFoundNothing"));
  const Contact presses[2] = {{-33, 8, 2.5, 5}, {23, 8, 2.5, 5}};
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
  ASSERT_EQ(with.count, 2);
  for (int k = 0; k < 2; ++k) EXPECT_LT(distance(with.contacts[k], presses[k]), 1.0) << k;
  const ContactCountEstimate without = physics.count_contacts(f, {}, single, {}, nullptr);
  EXPECT_EQ(without.count, 0);
}

}  // namespace
}  // namespace skinbus::estimators
