#include "skinbus/sim/scene.h"

#include <gtest/gtest.h>

#include <cmath>

namespace skinbus::sim {
namespace {

double energy(const std::vector<double>& a, const std::vector<double>& b) {
  double e = 0;
  for (std::size_t i = 0; i < a.size(); ++i) e += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(e);
}

TEST(SceneTest, OnlyTouchedPatchesDeformAndTheTouchShowsWhereItIs) {
  Scene scene;
  PatchDesign flat;
  PatchDesign arm;
  arm.surface = SurfaceKind::kCylinder;
  arm.radius_mm = 45;
  for (int i = 0; i < 12; ++i) ASSERT_TRUE(scene.add_patch(0x5B00 + i, i < 6 ? arm : flat).ok());
  ASSERT_TRUE(scene.add_contact({3, 1.0, 2.0, 10, -5, 3.0}).ok());
  std::vector<std::vector<double>> base(12, std::vector<double>(48)),
      now(12, std::vector<double>(48));
  for (int i = 0; i < 12; ++i) scene.measure(i, 0.0, base[i]);
  std::vector<Contact> truth;
  for (int i = 0; i < 12; ++i) {
    scene.measure(i, 1.5, now[i], &truth);
    if (i == 3) {
      ASSERT_EQ(truth.size(), 1u);
      EXPECT_NEAR(truth[0].depth_mm, 3.0, 3.0 * 0.05 + 1e-9);  // held depth plus some creep
      EXPECT_GT(energy(now[i], base[i]), 40.0);  // tens of uT against ~5 uT of noise energy
    } else {
      EXPECT_TRUE(truth.empty());
      EXPECT_LT(energy(now[i], base[i]), 15.0);  // noise only
    }
  }
  EXPECT_EQ(scene.deformation_evaluations(), 1u);
  EXPECT_EQ(scene.idle_evaluations(), 23u);
}

TEST(SceneTest, TurningLimbChangesTheAmbientFieldUniformly) {
  Scene scene;
  LimbMotion swing{{1, 0, 0}, M_PI / 2, 4.0, 0};
  ASSERT_TRUE(scene.add_patch(1, PatchDesign{}, swing).ok());
  const Environment e0 = scene.environment(0, 0.0),
                    e1 = scene.environment(0, 1.0);  // 0 and 90 degrees
  const double m0 = std::sqrt(dot(e0.ambient_ut, e0.ambient_ut)),
               m1 = std::sqrt(dot(e1.ambient_ut, e1.ambient_ut));
  EXPECT_NEAR(m0, m1, 1e-9);  // a rotation keeps the magnitude
  EXPECT_GT(std::sqrt(dot(e0.ambient_ut - e1.ambient_ut, e0.ambient_ut - e1.ambient_ut)), 40.0);
}

TEST(SceneTest, CreepAndRelease) {
  SceneConfig cfg;
  cfg.creep_fraction = 0.1;
  cfg.creep_tau_s = 1.0;
  Scene scene(cfg);
  ASSERT_TRUE(scene.add_patch(9, PatchDesign{}).ok());
  ASSERT_TRUE(scene.add_contact({0, 0.0, 10.0, 0, 0, 2.0, 0.1}).ok());
  std::vector<Contact> c;
  double last = 0;
  for (double t = 0.2; t < 9.5; t += 0.1) {
    c.clear();
    scene.active_contacts(0, t, &c);
    ASSERT_EQ(c.size(), 1u);
    EXPECT_GE(c[0].depth_mm, last - 1e-12);  // sinks further while held
    last = c[0].depth_mm;
  }
  EXPECT_NEAR(last, 2.2, 0.01);
  c.clear();
  scene.active_contacts(0, 10.5, &c);
  EXPECT_TRUE(c.empty());
}

TEST(SceneTest, ASlidingPressMovesAndDragsTheSkinAlong) {
  Scene scene;
  ASSERT_TRUE(scene.add_patch(9, PatchDesign{}).ok());
  SceneContact slide{0, 1.0, 3.0, -20, 10, 2.0, 0.1};
  slide.u_end_mm = 20;
  slide.v_end_mm = -20;
  slide.friction = 0.5;
  ASSERT_TRUE(scene.add_contact(slide).ok());
  std::vector<Contact> c;
  scene.active_contacts(0, 2.0, &c);  // half way
  ASSERT_EQ(c.size(), 1u);
  EXPECT_NEAR(c[0].u_mm, 0, 1e-9);
  EXPECT_NEAR(c[0].v_mm, -5, 1e-9);
  // Along the slide (40, -30)/50, half the normal force.
  const double fn = scene.patch(0).model().force_n(c[0].depth_mm);
  EXPECT_NEAR(c[0].shear_u_n, 0.5 * fn * 0.8, 1e-9);
  EXPECT_NEAR(c[0].shear_v_n, -0.5 * fn * 0.6, 1e-9);
  // It changes the field beyond the move alone.
  std::vector<double> with(48), without(48);
  scene.patch(0).model().contact_field_ut(c, with);
  Contact plain = c[0];
  plain.shear_u_n = plain.shear_v_n = 0;
  scene.patch(0).model().contact_field_ut(std::span<const Contact>(&plain, 1), without);
  double diff = 0;
  for (int i = 0; i < 48; ++i) diff = std::max(diff, std::fabs(with[i] - without[i]));
  EXPECT_GT(diff, 5.0);  // uT
  SceneContact bad = slide;
  bad.v_end_mm = std::nan("");  // one end only
  EXPECT_FALSE(scene.add_contact(bad).ok());
  bad = slide;
  bad.friction = -1;
  EXPECT_FALSE(scene.add_contact(bad).ok());
}

TEST(SceneTest, BadInputsAreRefused) {
  Scene scene;
  ASSERT_TRUE(scene.add_patch(1, PatchDesign{}).ok());
  EXPECT_FALSE(scene.add_patch(1, PatchDesign{}).ok());  // duplicate UID
  EXPECT_FALSE(scene.add_contact({5, 0, 1, 0, 0, 1}).ok());
  EXPECT_FALSE(scene.add_contact({0, 1, 0, 0, 0, 1}).ok());
  EXPECT_FALSE(scene.add_contact({0, 0, 1, std::nan(""), 0, 1}).ok());
}

}  // namespace
}  // namespace skinbus::sim
