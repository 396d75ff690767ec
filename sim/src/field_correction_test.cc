#include "skinbus/sim/field_correction.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include "skinbus/common/test_seed.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/rng.h"

namespace skinbus::sim {
namespace {

// A correction over +-60 mm with knots 12 mm apart, depth to 4 mm, random coefficients (uT).
FieldCorrection random_correction(int channels, uint64_t seed) {
  FieldCorrection::Grid g;
  g.u0_mm = -60;
  g.v0_mm = -60;
  g.step_mm = 12;
  g.nu = 13;
  g.nv = 13;
  g.max_depth_mm = 4;
  Rng rng(seed);
  std::vector<double> coef(g.terms() * static_cast<std::size_t>(channels));
  for (double& c : coef) c = 5 * rng.normal();
  auto made = FieldCorrection::make(g, channels, std::move(coef));
  EXPECT_TRUE(made.ok()) << made.error().to_string();
  return std::move(made).value();
}

TEST(FieldCorrectionTest, HandDerivativesEqualTheJetsAndFiniteDifferences) {
  const uint64_t seed = test_seed("FieldCorrectionTest.HandDerivatives");
  const FieldCorrection f = random_correction(6, seed);
  Rng rng(seed + 1);
  using D = Dual<3>;
  for (int trial = 0; trial < 200; ++trial) {
    // Inside and outside the grid, shallow and beyond max_depth_mm.
    const double u = rng.uniform(-80, 80), v = rng.uniform(-80, 80), d = rng.uniform(0.01, 5);
    double field[6] = {}, jac[6 * 3] = {};
    f.add_with_jacobian(u, v, d, field, jac, 3, 0);
    D jets[6] = {};
    f.add_ut(D::variable(u, 0), D::variable(v, 1), D::variable(d, 2), jets);
    for (int c = 0; c < 6; ++c) {
      EXPECT_NEAR(field[c], jets[c].v, 1e-12 * (1 + std::fabs(jets[c].v))) << trial;
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(jac[3 * c + k], jets[c].d[static_cast<std::size_t>(k)],
                    1e-12 * (1 + std::fabs(jac[3 * c + k])))
            << trial << " channel " << c << " unknown " << k;
      }
    }
    // Finite differences away from the grid's edges and the depth's end, where the value is C2.
    if (std::fabs(u) > 58 || std::fabs(v) > 58 || d > 3.9) continue;
    const double h = 1e-5, x[3] = {u, v, d};
    for (int k = 0; k < 3; ++k) {
      double up[3] = {x[0], x[1], x[2]}, dn[3] = {x[0], x[1], x[2]};
      up[k] += h;
      dn[k] -= h;
      double fu[6] = {}, fd[6] = {};
      f.add_ut(up[0], up[1], up[2], fu);
      f.add_ut(dn[0], dn[1], dn[2], fd);
      for (int c = 0; c < 6; ++c) {
        EXPECT_NEAR(jac[3 * c + k], (fu[c] - fd[c]) / (2 * h),
                    1e-5 * (1 + std::fabs(jac[3 * c + k])))
            << trial << " channel " << c << " unknown " << k;
      }
    }
  }
}

TEST(FieldCorrectionTest, NothingWithoutDepthAndTheEdgesValueOutside) {
  const FieldCorrection f = random_correction(3, 11);
  for (double d : {0.0, -1.0, std::numeric_limits<double>::quiet_NaN()}) {
    double field[3] = {1, 2, 3}, jac[9] = {};
    f.add_with_jacobian(5, 5, d, field, jac, 3, 0);
    f.add_ut(5.0, 5.0, d, field);
    EXPECT_EQ(field[0], 1);
    EXPECT_EQ(field[2], 3);
    for (double j : jac) EXPECT_EQ(j, 0);
  }
  // Beyond the grid (it spans -60 .. 60): the edge's value, no slope along that axis; beyond
  // max_depth_mm the value there, no slope by depth.
  double edge[3] = {}, out[3] = {}, jac[9] = {};
  f.add_ut(60.0, 12.5, 2.0, edge);
  f.add_with_jacobian(75, 12.5, 2.0, out, jac, 3, 0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(out[c], edge[c], 1e-12 * (1 + std::fabs(edge[c])));
    EXPECT_EQ(jac[3 * c], 0);
    EXPECT_NE(jac[3 * c + 1], 0);
  }
  double deep[3] = {}, deeper[3] = {}, jd[9] = {};
  f.add_ut(10.0, 10.0, 4.0, deep);
  f.add_with_jacobian(10, 10, 7.0, deeper, jd, 3, 0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(deeper[c], deep[c], 1e-12 * (1 + std::fabs(deep[c])));
    EXPECT_EQ(jd[3 * c + 2], 0);
  }
  // NaN places: the edge's value, finite.
  double nan_place[3] = {};
  f.add_ut(std::numeric_limits<double>::quiet_NaN(), 0.0, 2.0, nan_place);
  for (double x : nan_place) EXPECT_TRUE(std::isfinite(x));
}

TEST(FieldCorrectionTest, BadGridsAndCoefficientsAreNamed) {
  FieldCorrection::Grid g;
  g.step_mm = 10;
  g.nu = g.nv = 5;
  g.max_depth_mm = 4;
  const std::size_t n = g.terms() * 3;
  EXPECT_TRUE(FieldCorrection::make(g, 3, std::vector<double>(n, 0.0)).ok());
  auto message = [&](FieldCorrection::Grid gg, int channels, std::vector<double> c) {
    auto r = FieldCorrection::make(gg, channels, std::move(c));
    EXPECT_FALSE(r.ok());
    return r.ok() ? std::string() : r.error().message;
  };
  EXPECT_NE(message(g, 3, std::vector<double>(n - 1, 0.0)).find("coefficients"), std::string::npos);
  EXPECT_NE(message(g, 0, {}).find("channels"), std::string::npos);
  FieldCorrection::Grid bad = g;
  bad.nu = 3;
  EXPECT_NE(message(bad, 3, std::vector<double>(n, 0.0)).find("nu and nv"), std::string::npos);
  bad = g;
  bad.step_mm = 0;
  EXPECT_NE(message(bad, 3, std::vector<double>(n, 0.0)).find("step_mm"), std::string::npos);
  bad = g;
  bad.max_depth_mm = std::numeric_limits<double>::infinity();
  EXPECT_NE(message(bad, 3, std::vector<double>(n, 0.0)).find("max_depth_mm"), std::string::npos);
  std::vector<double> nan(n, 0.0);
  nan[7] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(message(g, 3, nan).find("coefficient 7"), std::string::npos);
  std::vector<double> huge(n, 0.0);
  huge[3] = 2e6;
  EXPECT_NE(message(g, 3, huge).find("coefficient 3 is not finite or beyond"), std::string::npos);
}

// A model with a correction adds it, per pressing contact, on the fast path, the template and the
// Jacobian; a correction of another channel count is refused.
TEST(FieldCorrectionTest, APatchModelAddsItOnEveryPath) {
  PatchDesign design;
  auto plain = PatchModel::fabricated(design, 0x5B01, FabricationVariation{});
  ASSERT_TRUE(plain.ok());
  UnitParameters p = plain->parameters();
  p.field_correction = std::make_shared<const FieldCorrection>(random_correction(48, 5));
  auto corrected = PatchModel::from_parameters(design, p);
  ASSERT_TRUE(corrected.ok()) << corrected.error().to_string();
  ASSERT_NE(corrected->field_correction(), nullptr);
  EXPECT_EQ(corrected->parameters().field_correction, p.field_correction);
  const Contact two[2] = {{10, -20, 2.5, 5.0}, {-30, 35, 1.0, 5.0}};
  std::vector<double> a(48), b(48), t(48), want(48);
  plain->contact_field_ut(two, a);
  corrected->contact_field_ut(two, b);
  corrected->contact_field_ut<double>(std::span<const Contact>(two, 2), t.data());
  want = a;
  for (const Contact& c : two) p.field_correction->add_ut(c.u_mm, c.v_mm, c.depth_mm, want.data());
  for (std::size_t c = 0; c < 48; ++c) {
    EXPECT_NEAR(b[c], want[c], 1e-9 * (1 + std::fabs(want[c]))) << c;
    EXPECT_NEAR(t[c], want[c], 1e-9 * (1 + std::fabs(want[c]))) << c;
  }
  // The Jacobian against the template's jets.
  using D = Dual<6>;
  ContactT<D> cd[2];
  for (int j = 0; j < 2; ++j) {
    cd[j] = {D::variable(two[j].u_mm, 3 * j), D::variable(two[j].v_mm, 3 * j + 1),
             D::variable(two[j].depth_mm, 3 * j + 2), two[j].tip_radius_mm};
  }
  std::vector<D> jets(48);
  corrected->contact_field_ut<D>(std::span<const ContactT<D>>(cd, 2), jets.data());
  std::vector<double> field(48), jac(48 * 6);
  ASSERT_TRUE(corrected->contact_field_jacobian_ut(two, false, field, jac));
  for (std::size_t c = 0; c < 48; ++c) {
    EXPECT_NEAR(field[c], jets[c].v, 1e-9 * (1 + std::fabs(jets[c].v))) << c;
    for (std::size_t k = 0; k < 6; ++k) {
      EXPECT_NEAR(jac[c * 6 + k], jets[c].d[k], 1e-9 * (1 + std::fabs(jets[c].d[k])))
          << c << " " << k;
    }
  }
  // One press without shear: the Jacobian's hand-derived path.
  using D3 = Dual<3>;
  const ContactT<D3> one{D3::variable(4.2, 0), D3::variable(-13.0, 1), D3::variable(1.7, 2), 5.0};
  std::vector<D3> jets3(48);
  corrected->contact_field_ut<D3>(std::span<const ContactT<D3>>(&one, 1), jets3.data());
  const Contact one_d{4.2, -13.0, 1.7, 5.0};
  std::vector<double> jac3(48 * 3);
  ASSERT_TRUE(corrected->contact_field_jacobian_ut(std::span<const Contact>(&one_d, 1), false,
                                                   field, jac3));
  for (std::size_t c = 0; c < 48; ++c) {
    EXPECT_NEAR(field[c], jets3[c].v, 1e-9 * (1 + std::fabs(jets3[c].v))) << c;
    for (std::size_t k = 0; k < 3; ++k) {
      EXPECT_NEAR(jac3[c * 3 + k], jets3[c].d[k], 1e-9 * (1 + std::fabs(jets3[c].d[k])))
          << c << " " << k;
    }
  }
  p.field_correction = std::make_shared<const FieldCorrection>(random_correction(45, 5));
  auto wrong = PatchModel::from_parameters(design, p);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().message.find("field correction has 45 channels"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::sim
