// contact_proposal.h: reading a proposer's outputs, and the shipped proposer
// (estimators/models/nominal_proposer) as the start of the physics count.
#include "skinbus/estimators/contact_proposal.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>

#include "skinbus/common/test_seed.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/estimators/physics_estimator.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators {
namespace {

using sim::Contact;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

TEST(ContactProposal, OutputsAreReadDeepestFirstWithTheCountRoundedAndBounded) {
  //                  slot 1           slot 2           slot 3           count
  const double y[] = {10, 20, 1.0, -30, 5, 3.0, 40, -40, 2.0, 2.4};
  ContactProposal p = proposal_from_outputs(y);
  ASSERT_EQ(p.count, 2);
  EXPECT_EQ(p.contacts[0].u_mm, -30);  // the deepest two, deepest first
  EXPECT_EQ(p.contacts[1].u_mm, 40);
  double many[] = {10, 20, 1.0, -30, 5, 3.0, 40, -40, -0.5, 7.2};
  p = proposal_from_outputs(many);
  ASSERT_EQ(p.count, 3);                   // at most kMaxContacts
  EXPECT_EQ(p.contacts[2].depth_mm, 0.0);  // never negative
  many[9] = kNaN;
  EXPECT_EQ(proposal_from_outputs(many).count, 0);
  many[9] = 3;
  many[4] = kNaN;  // a slot with a non-finite value is never proposed
  p = proposal_from_outputs(many);
  ASSERT_EQ(p.count, 2);
  for (int k = 0; k < 2; ++k) EXPECT_TRUE(std::isfinite(p.contacts[k].v_mm));
  EXPECT_EQ(proposal_from_outputs(std::span<const double>(y, 5)).count, 0);  // too short
  ModelMeta meta;
  meta.outputs.assign(kProposerOutputs.begin(), kProposerOutputs.end());
  EXPECT_TRUE(is_proposer(meta));
  meta.outputs.back() = "force_n";
  EXPECT_FALSE(is_proposer(meta));
}

// The shipped proposer on a unit it was not trained on: its own count, and the physics count
// started from it against the same count from nothing (the solver's iterations: the work).
TEST(ContactProposal, TheShippedProposerCountsAndStartsThePhysicsCount) {
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  const std::string path =
      std::string(dir != nullptr ? dir : ".") + "/estimators/models/nominal_proposer";
  const sim::PatchModel unit = sim::PatchModel::fabricated(sim::PatchDesign{}, 0x5b0000000000002e,
                                                           sim::FabricationVariation{})
                                   .value();
  auto proposer = load_proposer(path, unit.channel_count());  // read, checked a proposer, loaded
  ASSERT_TRUE(proposer.ok()) << proposer.error().to_string();
  const PhysicsEstimator physics = PhysicsEstimator::create(unit).value();
  ContactCountOptions three;
  three.max_contacts = 3;
  sim::Rng rng(test_seed("TheShippedProposerCountsAndStartsThePhysicsCount"));
  // The proposer's count over `tries` samples of each count (it misses about 7 % of pairs on
  // this unit: at least 80 % right asked of 60 samples fails about one run in 10^4; of 20, one in
  // 50); the physics count on the first `physics_tries` samples of three. Started from the
  // proposal, the physics count misses a triple the count from nothing finds in about 0.7 % of
  // samples (20 of 3000 over 150 seeds); asking it to miss at most one more of 20 failed about
  // one run in 150 (a CI run, seed 18247047663620060379: 18 against 20). Of 60 (100 seeds: 0, 1 or
  // 2 more, mean 0.3), at most 4 more: rarer than one run in 10^4 (Poisson).
  int right[4] = {}, tries = 60, physics_tries = 60, counted = 0, proposed_counted = 0;
  long iterations_nothing = 0, iterations_proposed = 0;
  for (int presses = 0; presses <= 3; ++presses) {
    for (int t = 0; t < tries; ++t) {
      // Presses 1-4 mm deep, their centres on a circle of 25 mm around a point near the centre
      // (at least 43 mm apart for three).
      Contact p[3];
      const double mu = rng.uniform(-10, 10), mv = rng.uniform(-10, 10), a = rng.uniform(0, 7);
      for (int k = 0; k < presses; ++k) {
        const double th = a + k * 2 * M_PI / 3;
        p[k] = {mu + 25 * std::cos(th), mv + 25 * std::sin(th), rng.uniform(1, 4), 5};
      }
      const auto f = noisy_field(unit, std::span<const Contact>(p, presses), rng);
      const ContactProposal prop = propose_contacts(*proposer, f);
      right[presses] += prop.count == presses;
      if (presses != 3 || t >= physics_tries) continue;
      const ContactCountEstimate nothing = physics.estimate_contacts(f, {}, three);
      const PhysicsEstimate single = physics.refine_lm(f, {}, prop.contacts[0]);
      const ContactCountEstimate from = physics.count_contacts(
          f, {}, single, three, std::span<const ContactEstimate>(prop.contacts, prop.count));
      counted += nothing.count == 3;
      proposed_counted += from.count == 3;
      iterations_nothing += nothing.pair_iterations + nothing.triple_iterations;
      iterations_proposed += from.pair_iterations + from.triple_iterations;
    }
  }
  std::printf(
      "shipped proposer on a new unit: counts right %d / %d / %d / %d of %d (0-3 presses); three "
      "presses counted three %d of %d from nothing (%ld solver iterations), %d from the "
      "proposal (%ld)\n",
      right[0], right[1], right[2], right[3], tries, counted, physics_tries, iterations_nothing,
      proposed_counted, iterations_proposed);
  EXPECT_GE(right[0], tries - 3);
  for (int k = 1; k <= 3; ++k) EXPECT_GE(right[k], tries * 4 / 5) << k << " presses";
  EXPECT_GE(proposed_counted, counted - 4);
  EXPECT_LT(iterations_proposed, iterations_nothing / 2);  // the search it spares
}

}  // namespace
}  // namespace skinbus::estimators
