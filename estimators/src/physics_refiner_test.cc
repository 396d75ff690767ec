// The physics refiner (physics_refiner.h): from a rough first estimate it reaches the unit's
// contact, and its covariance is an honest uncertainty: near the Cramer-Rao bound of the press
// (the bound is the covariance at the true contact) and equal to the spread of its own errors.
#include "skinbus/estimators/physics_refiner.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

#include <unistd.h>

#include "skinbus/sim/crlb.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::estimators {
namespace {

using sim::Contact;

// A fabricated unit of the built-in design.
sim::PatchModel fabricated_unit(uint64_t uid) {
  return sim::PatchModel::fabricated(sim::PatchDesign{}, uid, sim::FabricationVariation{}).value();
}

// The unit's field of one contact with the design's sensor noise.
std::vector<double> noisy_field(const sim::PatchModel& unit, const Contact& c,
                                const ChannelNoise& noise, sim::Rng& rng) {
  std::vector<double> f(static_cast<std::size_t>(unit.channel_count()));
  unit.contact_field_ut(std::span<const Contact>(&c, 1), f);
  for (std::size_t k = 0; k < f.size(); ++k) {
    f[k] += noise.sigma(static_cast<int>(k)) * rng.normal();
  }
  return f;
}

TEST(PhysicsRefinerTest, RefinesARoughStartWithAnHonestUncertainty) {
  const uint64_t seed = 20261124;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchDesign design;
  const sim::PatchModel unit = fabricated_unit(0x5B00000000000007ull);
  auto refiner = make_physics_refiner(unit);
  ASSERT_TRUE(refiner.ok()) << refiner.error().message;
  const ChannelNoise noise = ChannelNoise::of(design);
  sim::Rng rng(seed);
  double err2 = 0, sigma2 = 0, bound2 = 0;
  int n = 0;
  for (int i = 0; i < 80; ++i) {
    const Contact c{rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(1.0, 4.0), 5};
    const std::vector<double> f = noisy_field(unit, c, noise, rng);
    // A network's answer: off by a couple of millimetres and a few tenths in depth.
    ContactEstimate start;
    start.u_mm = c.u_mm + rng.uniform(-3, 3);
    start.v_mm = c.v_mm + rng.uniform(-3, 3);
    start.depth_mm = c.depth_mm + rng.uniform(-0.3, 0.3);
    const RefinedEstimate r = (*refiner)->refine(f, {}, start);
    ASSERT_TRUE(r.contact.valid());
    ASSERT_TRUE(std::isfinite(r.sigma_uv_mm));
    EXPECT_EQ(r.contact.flags & kEstimatePoorFit, 0u);
    const sim::CrlbPoint b = sim::crlb_at(unit, c, noise.xy_ut, noise.z_ut, true);
    err2 += std::pow(r.contact.u_mm - c.u_mm, 2) + std::pow(r.contact.v_mm - c.v_mm, 2);
    sigma2 += r.sigma_uv_mm * r.sigma_uv_mm;
    bound2 += b.sd_xy_mm * b.sd_xy_mm;
    // The covariance at the fitted contact is the bound at a nearby point: within 30 %.
    EXPECT_NEAR(r.sigma_uv_mm / b.sd_xy_mm, 1.0, 0.3)
        << c.u_mm << ", " << c.v_mm << ", " << c.depth_mm;
    ++n;
  }
  const double rms = std::sqrt(err2 / n), sigma = std::sqrt(sigma2 / n),
               bound = std::sqrt(bound2 / n);
  std::printf("refined from +-3 mm: RMS error %.4f mm, RMS sigma %.4f mm, RMS bound %.4f mm\n", rms,
              sigma, bound);
  // The stated uncertainty is the errors' spread (80 presses: ~10 % on the ratio).
  EXPECT_GT(rms / sigma, 0.75);
  EXPECT_LT(rms / sigma, 1.3);
}

TEST(PhysicsRefinerTest, LoadsAUnitFileAndNamesWhatItCannotRead) {
  const sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, 0x5B00000000000003ull, sim::FabricationVariation{})
          .value();
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("skinbus_refiner_" + std::to_string(::getpid()) + ".json"))
                               .string();
  ASSERT_TRUE(sim::write_unit_parameters(unit.parameters(), path).ok());
  auto r = make_physics_refiner(path, "");
  ASSERT_TRUE(r.ok()) << r.error().message;
  // The same parameters kept as a fit identification refused: read by the simulator, never
  // refined on; the error names the file and why it was refused.
  ASSERT_TRUE(sim::write_unit_parameters(unit.parameters(), path,
                                         {"identify rec.csv", "residual 5.80 noise units", {}})
                  .ok());
  auto refused = make_physics_refiner(path, "");
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code, ErrorCode::kInvalidArgument);
  EXPECT_NE(refused.error().message.find(path), std::string::npos);
  EXPECT_NE(refused.error().message.find("not for refinement (residual 5.80"), std::string::npos)
      << refused.error().message;
  EXPECT_TRUE(sim::read_unit_parameters(path).ok());
  std::filesystem::remove(path);
  auto missing = make_physics_refiner(path, "");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find(path), std::string::npos);
}

// A unit file that says where its unit was pressed: refined contacts placed outside that area
// (by more than the margin) are flagged extrapolated, those inside are not; a file without the
// area flags nothing.
TEST(PhysicsRefinerTest, ContactsOutsideThePressedAreaAreFlaggedExtrapolated) {
  const uint64_t seed = 20261128;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchModel unit = fabricated_unit(0x5B00000000000005ull);
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("skinbus_area_" + std::to_string(::getpid()) + ".json"))
                               .string();
  const sim::PressedArea area{-20, 30, -25, 20};
  ASSERT_TRUE(sim::write_unit_parameters(unit.parameters(), path, {"test", {}, area}).ok());
  auto flagging = make_physics_refiner(path, "");
  ASSERT_TRUE(sim::write_unit_parameters(unit.parameters(), path).ok());
  auto plain = make_physics_refiner(path, "");
  std::filesystem::remove(path);
  ASSERT_TRUE(flagging.ok() && plain.ok());
  const ChannelNoise noise = ChannelNoise::of(sim::PatchDesign{});
  sim::Rng rng(seed);
  int inside = 0, outside = 0;
  for (int i = 0; i < 40; ++i) {
    const Contact c{rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(2.0, 4.0), 5};
    const std::vector<double> f = noisy_field(unit, c, noise, rng);
    ContactEstimate start;
    start.u_mm = c.u_mm + 1;
    start.v_mm = c.v_mm - 1;
    start.depth_mm = c.depth_mm;
    const RefinedEstimate a = (*flagging)->refine(f, {}, start);
    const RefinedEstimate b = (*plain)->refine(f, {}, start);
    ASSERT_TRUE(a.contact.valid());
    const bool in = area.contains(a.contact.u_mm, a.contact.v_mm, sim::kPressedAreaMarginMm);
    EXPECT_EQ((a.contact.flags & kEstimateExtrapolated) != 0, !in)
        << a.contact.u_mm << " " << a.contact.v_mm;
    EXPECT_EQ(b.contact.flags & kEstimateExtrapolated, 0u);
    EXPECT_EQ(a.contact.u_mm, b.contact.u_mm);  // the flag alone differs
    (in ? inside : outside) += 1;
  }
  EXPECT_GT(inside, 5);
  EXPECT_GT(outside, 5);
}

// A first estimate far from the press (a network trained briefly, or meeting a place it was not
// trained on) leaves the fit in another basin of the field, where it ends poor; the refiner then
// searches its start table and reaches the press. Without the search the fit stays poor.
TEST(PhysicsRefinerTest, AFitThatEndsPoorIsSearchedAgainFromTheStartTable) {
  const uint64_t seed = 20261127;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  const sim::PatchDesign design;
  const sim::PatchModel unit = fabricated_unit(0x5B00000000000009ull);
  RefinerOptions with, without;
  without.search_when_poor = false;
  auto searching = make_physics_refiner(unit, with);
  auto plain = make_physics_refiner(unit, without);
  ASSERT_TRUE(searching.ok() && plain.ok());
  const ChannelNoise noise = ChannelNoise::of(design);
  sim::Rng rng(seed);
  int poor_plain = 0, poor_searched = 0, far_plain = 0, far_searched = 0;
  constexpr int kPresses = 60;
  for (int i = 0; i < kPresses; ++i) {
    const Contact c{rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(2.0, 4.0), 5};
    const std::vector<double> f = noisy_field(unit, c, noise, rng);
    // Half a magnet spacing to two off, in a random direction.
    const double off = rng.uniform(10, 40), angle = rng.uniform(0, 2 * M_PI);
    ContactEstimate start;
    start.u_mm = c.u_mm + off * std::cos(angle);
    start.v_mm = c.v_mm + off * std::sin(angle);
    start.depth_mm = 2;
    const RefinedEstimate a = (*plain)->refine(f, {}, start);
    const RefinedEstimate b = (*searching)->refine(f, {}, start);
    const auto poor = [](const RefinedEstimate& r) {
      return !r.contact.valid() || (r.contact.flags & (kEstimatePoorFit | kEstimateNoContact)) != 0;
    };
    const auto far = [&](const RefinedEstimate& r) {
      return !r.contact.valid() || std::hypot(r.contact.u_mm - c.u_mm, r.contact.v_mm - c.v_mm) > 2;
    };
    poor_plain += poor(a);
    poor_searched += poor(b);
    far_plain += far(a);
    far_searched += far(b);
  }
  std::printf(
      "of %d presses started 10-40 mm off: poor fits %d without the search, %d with; more "
      "than 2 mm off %d and %d\n",
      kPresses, poor_plain, poor_searched, far_plain, far_searched);
  EXPECT_GE(poor_plain, kPresses / 10);  // the case exists (9 of 60 with this seed)
  EXPECT_LE(poor_searched, 2);
  EXPECT_LE(far_searched, 2);
}

// The host refines with the indenter of the design a skin-map entry names: presses made with a
// 10 mm tip are refined to their depth with a design that says so, and read too shallow or deep
// with the built-in design's 5 mm.
TEST(PhysicsRefinerTest, RefinesWithTheDesignsIndenter) {
  const uint64_t seed = 20261126;
  std::printf("seed %llu\n", static_cast<unsigned long long>(seed));
  sim::PatchDesign design;
  const sim::PatchModel unit =
      sim::PatchModel::fabricated(design, 0x5B00000000000005ull, sim::FabricationVariation{})
          .value();
  const std::string stem = (std::filesystem::temp_directory_path() /
                            ("skinbus_refiner_tip_" + std::to_string(::getpid())))
                               .string();
  ASSERT_TRUE(sim::write_unit_parameters(unit.parameters(), stem + ".json").ok());
  design.indenter_tip_radius_mm = 10;
  ASSERT_TRUE(sim::write_design_file(design, stem + ".yaml").ok());
  auto with_tip = make_physics_refiner(stem + ".json", stem + ".yaml");
  auto builtin = make_physics_refiner(stem + ".json", "");
  std::filesystem::remove(stem + ".json");
  std::filesystem::remove(stem + ".yaml");
  ASSERT_TRUE(with_tip.ok()) << with_tip.error().message;
  ASSERT_TRUE(builtin.ok()) << builtin.error().message;
  const ChannelNoise noise = ChannelNoise::of(design);
  sim::Rng rng(seed);
  double err_tip = 0, err_builtin = 0;
  constexpr int kPresses = 40;
  for (int i = 0; i < kPresses; ++i) {
    const Contact c{rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(1.5, 4.0), 10};
    const std::vector<double> f = noisy_field(unit, c, noise, rng);
    ContactEstimate start;
    start.u_mm = c.u_mm;
    start.v_mm = c.v_mm;
    start.depth_mm = c.depth_mm;
    const RefinedEstimate a = (*with_tip)->refine(f, {}, start);
    const RefinedEstimate b = (*builtin)->refine(f, {}, start);
    ASSERT_TRUE(a.contact.valid());
    ASSERT_TRUE(b.contact.valid());
    err_tip += std::fabs(a.contact.depth_mm - c.depth_mm) / kPresses;
    err_builtin += std::fabs(b.contact.depth_mm - c.depth_mm) / kPresses;
  }
  std::printf(
      "depth mean error, 10 mm tip: %.4f mm with the design's indenter, %.4f mm with 5 mm\n",
      err_tip, err_builtin);
  EXPECT_LT(err_tip, 0.5 * err_builtin);
}

}  // namespace
}  // namespace skinbus::estimators
