// Physics of a patch: dipole field, plate kernel, sensor model and the forward model.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "skinbus/sim/dipole.h"
#include "skinbus/sim/dual.h"
#include "skinbus/sim/mlx90393.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/plate_kernel.h"

namespace skinbus::sim {
namespace {

TEST(DipoleTest, AnalyticValuesOnAxisAndEquator) {
  const double m = 0.011;                                   // A m^2
  const double r = 17.0;                                    // mm
  const double k = 1e-7 * m / std::pow(r * 1e-3, 3) * 1e6;  // mu0/4pi m / r^3 in uT
  const auto on_axis = dipole_field_ut(Vec3<double>{0, 0, m}, Vec3<double>{0, 0, r});
  EXPECT_NEAR(on_axis.z, 2 * k, 1e-9 * k);
  EXPECT_NEAR(on_axis.x, 0, 1e-12);
  const auto equator = dipole_field_ut(Vec3<double>{0, 0, m}, Vec3<double>{r, 0, 0});
  EXPECT_NEAR(equator.z, -k, 1e-9 * k);
  // Off-axis at 45 degrees in the x-z plane: B = k (3 cos t sin t, 0, 3 cos^2 t - 1).
  const double c = std::sqrt(0.5);
  const auto diag = dipole_field_ut(Vec3<double>{0, 0, m}, Vec3<double>{r * c, 0, r * c});
  EXPECT_NEAR(diag.x, k * 3 * c * c, 1e-9 * k);
  EXPECT_NEAR(diag.z, k * (3 * c * c - 1), 1e-9 * k);
}

TEST(DipoleTest, ClosedFormGradientEqualsTheJets) {
  // Random moments and offsets (a printed seed): the closed form against dual numbers through
  // dipole_field_ut(), variables r (0-2) and m (3-5).
  const unsigned seed = 20261128;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> pos(-30.0, 30.0), mom(-0.02, 0.02);
  for (int trial = 0; trial < 200; ++trial) {
    const Vec3<double> r{pos(rng), pos(rng), pos(rng) - 40.0}, m{mom(rng), mom(rng), mom(rng)};
    using D = Dual<6>;
    const Vec3<D> rd{D::variable(r.x, 0), D::variable(r.y, 1), D::variable(r.z, 2)};
    const Vec3<D> md{D::variable(m.x, 3), D::variable(m.y, 4), D::variable(m.z, 5)};
    const Vec3<D> bd = dipole_field_ut(md, rd);
    double d_dr[3][3], d_dm[3][3];
    const Vec3<double> b = dipole_field_gradient_ut(m, r, d_dr, d_dm);
    const D* comp[3] = {&bd.x, &bd.y, &bd.z};
    const double bv[3] = {b.x, b.y, b.z};
    for (int i = 0; i < 3; ++i) {
      const double scale = std::fabs(comp[i]->v) + 1e-3;
      EXPECT_NEAR(bv[i], comp[i]->v, 1e-12 * scale) << "seed " << seed << " trial " << trial;
      const Vec3<double> plain = dipole_field_ut(m, r);  // the same operations: the same bits
      EXPECT_EQ(bv[i], i == 0 ? plain.x : i == 1 ? plain.y : plain.z);
      for (int j = 0; j < 3; ++j) {
        const double tol_r = 1e-12 * (std::fabs(comp[i]->d[j]) + 1e-3);
        const double tol_m = 1e-12 * (std::fabs(comp[i]->d[3 + j]) + 1.0);
        EXPECT_NEAR(d_dr[i][j], comp[i]->d[j], tol_r) << "seed " << seed << " trial " << trial;
        EXPECT_NEAR(d_dm[i][j], comp[i]->d[3 + j], tol_m) << "seed " << seed << " trial " << trial;
      }
    }
  }
}

// The same for a magnet with an octupole (a disc's, and a tall cylinder's): the closed form
// against dual numbers through magnet_field_ut().
TEST(DipoleTest, TheOctupolesClosedFormGradientEqualsTheJets) {
  const unsigned seed = 20261129;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> pos(-30.0, 30.0), mom(-0.02, 0.02);
  for (double oct : {cylinder_octupole_mm2(3.0, 1.5), cylinder_octupole_mm2(2.0, 4.0)}) {
    for (int trial = 0; trial < 200; ++trial) {
      const Vec3<double> r{pos(rng), pos(rng), pos(rng) - 40.0}, m{mom(rng), mom(rng), mom(rng)};
      using D = Dual<6>;
      const Vec3<D> rd{D::variable(r.x, 0), D::variable(r.y, 1), D::variable(r.z, 2)};
      const Vec3<D> md{D::variable(m.x, 3), D::variable(m.y, 4), D::variable(m.z, 5)};
      const Vec3<D> bd = magnet_field_ut(md, rd, oct);
      double d_dr[3][3], d_dm[3][3];
      const Vec3<double> b = magnet_field_gradient_ut(m, r, oct, d_dr, d_dm);
      const D* comp[3] = {&bd.x, &bd.y, &bd.z};
      const double bv[3] = {b.x, b.y, b.z};
      for (int i = 0; i < 3; ++i) {
        const double scale = std::fabs(comp[i]->v) + 1e-3;
        EXPECT_NEAR(bv[i], comp[i]->v, 1e-12 * scale) << "seed " << seed << " trial " << trial;
        for (int j = 0; j < 3; ++j) {
          const double tol_r = 1e-11 * (std::fabs(comp[i]->d[j]) + 1e-3);
          const double tol_m = 1e-11 * (std::fabs(comp[i]->d[3 + j]) + 1.0);
          EXPECT_NEAR(d_dr[i][j], comp[i]->d[j], tol_r) << "seed " << seed << " trial " << trial;
          EXPECT_NEAR(d_dm[i][j], comp[i]->d[3 + j], tol_m)
              << "seed " << seed << " trial " << trial;
        }
      }
    }
  }
  // Octupole 0: the dipole's very bits, value and derivatives.
  const Vec3<double> r{3, -4, -17}, m{0.001, -0.002, 0.011};
  double a_dr[3][3], a_dm[3][3], b_dr[3][3], b_dm[3][3];
  const Vec3<double> a = magnet_field_gradient_ut(m, r, 0.0, a_dr, a_dm);
  const Vec3<double> b = dipole_field_gradient_ut(m, r, b_dr, b_dm);
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.z, magnet_field_ut(m, r, 0.0).z);
  EXPECT_EQ(a_dr[1][2], b_dr[1][2]);
  EXPECT_EQ(a_dm[2][0], b_dm[2][0]);
}

// A 3 x 1.5 mm disc along its axis, 5 to 40 mm away: the dipole with the cylinder's octupole
// against the exact field, where the point dipole is 9 % high at 5 mm and 0.7 % at 17.75 mm.
// What is left, the cylinder's l = 5 term and beyond, falls as (radius / z)^4.
TEST(DipoleTest, TheOctupoleTakesTheDiscsShapeIntoAccount) {
  const double m = cylinder_moment_am2(1.32, 3.0, 1.5);
  const double oct = cylinder_octupole_mm2(3.0, 1.5);
  EXPECT_DOUBLE_EQ(oct, -1.125);
  EXPECT_NEAR(cylinder_octupole_mm2(2.0, std::sqrt(3.0)), 0.0, 1e-12);  // sqrt(3) a tall: none
  for (double z : {5.0, 8.0, 12.0, 17.75, 40.0}) {
    const double exact = cylinder_axial_field_ut(1.32, 3.0, 1.5, z);
    const double dip = dipole_field_ut(Vec3<double>{0, 0, m}, Vec3<double>{0, 0, z}).z;
    const double both = magnet_field_ut(Vec3<double>{0, 0, m}, Vec3<double>{0, 0, z}, oct).z;
    std::printf("z %5.2f mm: dipole %+.4f %%, with the octupole %+.5f %% of the exact field\n", z,
                100 * (dip / exact - 1), 100 * (both / exact - 1));
    EXPECT_LT(std::fabs(both - exact), 0.15 * std::fabs(dip - exact)) << "z " << z;
    EXPECT_NEAR(both / exact, 1.0, 3e-3 * std::pow(5.0 / z, 4)) << "z " << z;
  }
}

TEST(DipoleTest, PointDipoleMatchesAFiniteCylinderAtSensorDistance) {
  // A 3 x 1.5 mm N42 disc seen along its axis: the point dipole overestimates the exact field
  // by (radius/z)^2-order terms: 0.7 % at the sensors' 17.75 mm, 1.6 % at 12 mm.
  const double m = cylinder_moment_am2(1.32, 3.0, 1.5);
  const double limits[][2] = {
      {12.0, 0.02}, {16.0, 0.01}, {17.75, 0.008}, {20.0, 0.006}, {40.0, 0.0015}};
  for (const auto& [z, tol] : limits) {
    const double exact = cylinder_axial_field_ut(1.32, 3.0, 1.5, z);
    const double dip = dipole_field_ut(Vec3<double>{0, 0, m}, Vec3<double>{0, 0, z}).z;
    EXPECT_GT(dip, exact);
    EXPECT_NEAR(dip / exact, 1.0, tol) << "z=" << z;
  }
}

TEST(PlateKernelTest, KelvinFunctionAndShape) {
  double kei, dkei;
  kelvin_kei(0, &kei, &dkei);
  EXPECT_DOUBLE_EQ(kei, -M_PI / 4);
  kelvin_kei(1, &kei, &dkei);
  // Reference values from the independent integral kei(x) = Im int_0^inf exp(-x e^{i pi/4}
  // cosh t) dt, evaluated by quadrature.
  EXPECT_NEAR(kei, -0.494994637, 2e-9);
  kelvin_kei(2, &kei, &dkei);
  EXPECT_NEAR(kei, -0.202400068, 2e-9);
  kelvin_kei(3, &kei, &dkei);
  EXPECT_NEAR(kei, -0.051121884, 2e-9);
  for (double x : {0.3, 1.0, 2.5, 4.0, 6.0}) {
    double a, da, b, db;
    kelvin_kei(x - 1e-6, &a, &da);
    kelvin_kei(x + 1e-6, &b, &db);
    kelvin_kei(x, &kei, &dkei);
    EXPECT_NEAR(dkei, (b - a) / 2e-6, 1e-6) << x;
  }
  double g, dg, d2g;
  plate_kernel(0, &g, &dg, &d2g);
  EXPECT_NEAR(g, 1.0, 1e-12);
  EXPECT_NEAR(dg, 0.0, 1e-9);
  plate_kernel(kPlateKernelCutoff, &g, &dg);
  EXPECT_EQ(g, 0);
  EXPECT_EQ(dg, 0);
  plate_kernel(std::nan(""), &g, &dg);
  EXPECT_EQ(g, 0);
  // Monotone bowl out to the uplift ring, continuous derivative everywhere.
  double prev = 2;
  for (double s = 0; s < 3.5; s += 0.01) {
    plate_kernel(s, &g, &dg);
    EXPECT_LT(g, prev);
    prev = g;
  }
  for (double s = 0.005; s < kPlateKernelCutoff; s += 0.0137) {
    double ga, gb;
    plate_kernel(s - 1e-5, &ga, &dg);
    plate_kernel(s + 1e-5, &gb, &dg);
    plate_kernel(s, &g, &dg);
    EXPECT_NEAR(dg, (gb - ga) / 2e-5, 1e-5) << s;
  }
}

TEST(Mlx90393NoiseTest, FallsAsMoreSamplesAreAveraged) {
  const mlx90393::Config fastest{7, 0, 0, 0, 0, false};  // 3 ADC samples per axis
  const mlx90393::Config c{0, 1, 0, 1, 2, false};        // 12
  EXPECT_LT(mlx90393_noise_xy_ut(c), mlx90393_noise_xy_ut(fastest));
  // The anchors at the fastest settings, 1/sqrt(samples) from there.
  EXPECT_DOUBLE_EQ(mlx90393_noise_xy_ut(fastest), 1.4);
  EXPECT_DOUBLE_EQ(mlx90393_noise_z_ut(fastest), 2.3);
  EXPECT_DOUBLE_EQ(mlx90393_noise_z_ut(c), 2.3 * std::sqrt(3.0 / 12.0));
}

class PatchModelTest : public ::testing::Test {
 protected:
  PatchDesign design;
  PatchModel nominal() {
    auto m = PatchModel::nominal(design);
    EXPECT_TRUE(m.ok()) << m.error().to_string();
    return std::move(m).value();
  }
};

TEST_F(PatchModelTest, NoContactNoSignal) {
  const PatchModel p = nominal();
  std::vector<double> out(48, 1.0);
  p.contact_field_ut({}, out);
  for (double x : out) EXPECT_EQ(x, 0.0);
  const Contact zero{10, 10, 0};
  p.contact_field_ut(std::span<const Contact>(&zero, 1), out);
  for (double x : out) EXPECT_EQ(x, 0.0);
}

TEST_F(PatchModelTest, PressProducesALocalisedSignal) {
  const PatchModel p = nominal();
  std::vector<double> out(48);
  const Contact c{-45, -45, 3};  // over sensor 0
  p.contact_field_ut(std::span<const Contact>(&c, 1), out);
  double near = 0, far = 0;
  for (int k = 0; k < 3; ++k) {
    near += out[k] * out[k];
    far += out[45 + k] * out[45 + k];  // sensor 15, the far corner
  }
  EXPECT_GT(std::sqrt(near), 50.0);  // tens to hundreds of uT under a 3 mm press
  EXPECT_LT(std::sqrt(far), 1.0);
}

TEST_F(PatchModelTest, MirrorSymmetryOfTheNominalPatch) {
  const PatchModel p = nominal();
  std::vector<double> a(48), b(48);
  const Contact c{12.5, -7.0, 2.0}, m{-12.5, -7.0, 2.0};
  p.contact_field_ut(std::span<const Contact>(&c, 1), a);
  p.contact_field_ut(std::span<const Contact>(&m, 1), b);
  for (int s = 0; s < 16; ++s) {
    const int ms = (s / 4) * 4 + (3 - s % 4);  // sensor mirrored in u
    EXPECT_NEAR(a[3 * s + 0], -b[3 * ms + 0], 1e-9);
    EXPECT_NEAR(a[3 * s + 1], b[3 * ms + 1], 1e-9);
    EXPECT_NEAR(a[3 * s + 2], b[3 * ms + 2], 1e-9);
  }
}

TEST_F(PatchModelTest, DistantContactsSuperpose) {
  design.size_u_mm = 300;
  design.magnets_u = 15;
  const PatchModel p = nominal();
  std::vector<double> ab(48), a(48), b(48);
  const Contact ca{-140, 0, 3}, cb{140, 0, 2};  // reaches do not overlap (6.5 l = 65 mm)
  const Contact both[2] = {ca, cb};
  p.contact_field_ut(both, ab);
  p.contact_field_ut(std::span<const Contact>(&ca, 1), a);
  p.contact_field_ut(std::span<const Contact>(&cb, 1), b);
  for (int i = 0; i < 48; ++i) EXPECT_NEAR(ab[i], a[i] + b[i], 1e-9);
}

TEST_F(PatchModelTest, JacobianMatchesFiniteDifferences) {
  for (SurfaceKind kind : {SurfaceKind::kFlat, SurfaceKind::kCylinder}) {
    design.surface = kind;
    design.radius_mm = 45;
    design.size_u_mm = 140;
    auto made = PatchModel::fabricated(design, 0xABCDEF, FabricationVariation{});
    ASSERT_TRUE(made.ok()) << made.error().to_string();
    const PatchModel& p = *made;
    for (const Contact c : {Contact{3.3, -7.1, 1.5}, Contact{-40, 22, 3.5}, Contact{61, 60, 0.7},
                            Contact{-12, 8, 2.5, 6.0}, Contact{20, 20, 8.0, 4.0}}) {
      std::vector<double> jac(48 * 3), f0(48), fp(48), fm(48);
      p.contact_jacobian(c, jac, f0);
      for (int k = 0; k < 3; ++k) {
        const double h = 1e-5;
        Contact cp = c, cm = c;
        (k == 0 ? cp.u_mm : k == 1 ? cp.v_mm : cp.depth_mm) += h;
        (k == 0 ? cm.u_mm : k == 1 ? cm.v_mm : cm.depth_mm) -= h;
        p.contact_field_ut(std::span<const Contact>(&cp, 1), fp);
        p.contact_field_ut(std::span<const Contact>(&cm, 1), fm);
        for (int i = 0; i < 48; ++i) {
          const double fd = (fp[i] - fm[i]) / (2 * h);
          EXPECT_NEAR(jac[3 * i + k], fd, 1e-4 * (1 + std::fabs(fd)))
              << "channel " << i << " param " << k;
        }
      }
    }
  }
}

// contact_field_jacobian_ut() against the template's jets over the same unknowns, for each layout
// the fits use, on both surfaces, with the design's in-plane drag, anisotropy and tip crush.
template <int K>
void expect_field_jacobian_equals_the_jets(const PatchModel& p, std::span<const Contact> cs,
                                           bool shear) {
  using D = Dual<K>;
  const int pc = shear ? 5 : 3;
  ASSERT_EQ(static_cast<int>(cs.size()) * pc, K);
  std::vector<ContactT<D>> cd;
  for (std::size_t j = 0; j < cs.size(); ++j) {
    const int o = static_cast<int>(j) * pc;
    ContactT<D> c{D::variable(cs[j].u_mm, o), D::variable(cs[j].v_mm, o + 1),
                  D::variable(cs[j].depth_mm, o + 2), cs[j].tip_radius_mm};
    c.shear_u_n = shear ? D::variable(cs[j].shear_u_n, o + 3) : D(cs[j].shear_u_n);
    c.shear_v_n = shear ? D::variable(cs[j].shear_v_n, o + 4) : D(cs[j].shear_v_n);
    cd.push_back(c);
  }
  const std::size_t nc = static_cast<std::size_t>(p.channel_count());
  std::vector<D> want(nc);
  p.contact_field_ut<D>(std::span<const ContactT<D>>(cd), want.data());
  std::vector<double> field(nc), jac(nc * K), fast(nc);
  ASSERT_TRUE(p.contact_field_jacobian_ut(cs, shear, field, jac));
  p.contact_field_ut(cs, fast);
  for (std::size_t i = 0; i < nc; ++i) {
    EXPECT_NEAR(field[i], want[i].v, 1e-9 * (1 + std::fabs(want[i].v))) << "channel " << i;
    EXPECT_NEAR(field[i], fast[i], 1e-9 * (1 + std::fabs(fast[i]))) << "channel " << i;
    for (int k = 0; k < K; ++k) {
      const double w = want[i].d[static_cast<std::size_t>(k)];
      EXPECT_NEAR(jac[i * K + static_cast<std::size_t>(k)], w, 1e-9 * (1 + std::fabs(w)))
          << "channel " << i << ", unknown " << k << ", " << cs.size() << " contacts";
    }
  }
}

TEST_F(PatchModelTest, FieldJacobianEqualsTheTemplatesJets) {
  design.inplane_drag = 0.3;
  design.anisotropy = 0.1;
  design.tip_crush_mm = 2.0;
  for (SurfaceKind kind : {SurfaceKind::kFlat, SurfaceKind::kCylinder}) {
    design.surface = kind;
    design.radius_mm = 45;
    auto made = PatchModel::fabricated(design, 0x5EED, FabricationVariation{});
    ASSERT_TRUE(made.ok()) << made.error().to_string();
    const PatchModel& p = *made;
    const Contact one[1] = {{3.3, -7.1, 1.5, 5.0, 0.4, -0.2}};
    const Contact two[2] = {{10, -20, 2.5, 8.0, 0.5, -0.3}, {-30, 35, 1.0, 5.0}};
    const Contact three[3] = {{0, 0, 3.0, 5.0}, {40, 10, 9.0, 4.0}, {-20, -45, 0.5, 0.0, 0.2}};
    expect_field_jacobian_equals_the_jets<3>(p, one, false);
    // One press without shear: the deformation's derivatives by hand (a single-contact fit's
    // path), a point tip on a magnet, a press deeper than the lattice takes, one at the edge of
    // its reach.
    for (const Contact c : {Contact{3.3, -7.1, 1.5, 5.0}, Contact{-40, 22, 3.5, 8.0},
                            Contact{p.magnets()[24].u, p.magnets()[24].v, 2.0},
                            Contact{10, 5, 12.0, 6.0}, Contact{61, 60, 0.7, 5.0}}) {
      expect_field_jacobian_equals_the_jets<3>(p, std::span<const Contact>(&c, 1), false);
    }
    expect_field_jacobian_equals_the_jets<5>(p, one, true);
    expect_field_jacobian_equals_the_jets<6>(p, two, false);
    expect_field_jacobian_equals_the_jets<10>(p, two, true);
    expect_field_jacobian_equals_the_jets<9>(p, three, false);
    expect_field_jacobian_equals_the_jets<15>(p, three, true);
  }
  // More contacts than the jets take, or outputs too short: refused, untouched.
  const PatchModel p = nominal();
  const Contact four[4] = {{0, 0, 1}, {10, 0, 1}, {20, 0, 1}, {30, 0, 1}};
  std::vector<double> field(48, 7.0), jac(48 * 12, 7.0);
  EXPECT_FALSE(p.contact_field_jacobian_ut(four, false, field, jac));
  EXPECT_FALSE(p.contact_field_jacobian_ut(std::span<const Contact>(four, 1), false, field,
                                           std::span<double>(jac.data(), 48 * 2)));
  EXPECT_EQ(field[0], 7.0);
  EXPECT_EQ(jac[0], 7.0);
}

TEST_F(PatchModelTest, FastPathEqualsTheTemplate) {
  design.surface = SurfaceKind::kCylinder;
  design.radius_mm = 50;
  auto made = PatchModel::fabricated(design, 77, FabricationVariation{});
  ASSERT_TRUE(made.ok());
  const Contact cs[2] = {{10, -20, 2.5, 8.0, 0.5, -0.3}, {-30, 35, 1.0}};
  std::vector<double> fast(48), slow(48);
  made->contact_field_ut(cs, fast);
  made->contact_field_ut<double>(std::span<const Contact>(cs, 2), slow.data());
  for (int i = 0; i < 48; ++i) EXPECT_NEAR(fast[i], slow[i], 1e-9 * (1 + std::fabs(slow[i])));
}

// The crushed top (physics outside the identified class): with a point press the plate bends
// d / (1 + d / c), so the field equals the plain unit's at that depth, on both paths.
TEST_F(PatchModelTest, ACrushedTopBendsThePlateLess) {
  const double c = 20;
  const PatchModel plain = nominal();
  design.tip_crush_mm = c;
  const PatchModel crushed = nominal();
  for (double d : {0.5, 2.0, 4.0}) {
    const Contact deep{12, -7, d, 0}, shallow{12, -7, d / (1 + d / c), 0};
    std::vector<double> a(48), b(48), t(48);
    crushed.contact_field_ut(std::span<const Contact>(&deep, 1), a);
    crushed.contact_field_ut<double>(std::span<const Contact>(&deep, 1), t.data());
    plain.contact_field_ut(std::span<const Contact>(&shallow, 1), b);
    double diff = 0, norm = 0;
    for (int i = 0; i < 48; ++i) {
      EXPECT_NEAR(a[i], b[i], 1e-9 * (1 + std::fabs(b[i]))) << "depth " << d;
      EXPECT_NEAR(a[i], t[i], 1e-9 * (1 + std::fabs(b[i]))) << "depth " << d;
      norm += b[i] * b[i];
    }
    // ... and not the plain unit's at the full depth.
    const Contact full{12, -7, d, 0};
    plain.contact_field_ut(std::span<const Contact>(&full, 1), b);
    for (int i = 0; i < 48; ++i) diff += (a[i] - b[i]) * (a[i] - b[i]);
    EXPECT_GT(diff, 1e-4 * norm) << "depth " << d;
  }
  design.tip_crush_mm = -1;
  EXPECT_FALSE(PatchModel::nominal(design).ok());
}

// The drag law (PatchDesign::inplane_drag, physics outside the identified class): both field
// paths agree, a magnet beside a press moves toward it (its field changes), and one on the far
// side of the kernel's reach does not.
TEST_F(PatchModelTest, TheDragLawMovesTheSurfaceTowardThePressOnBothPaths) {
  const PatchModel plain = nominal();
  design.inplane_drag = 0.15;
  const PatchModel dragged = nominal();
  const Contact cs[2] = {{12, -7, 3.0, 5.0}, {-30, 25, 1.5, 0}};
  std::vector<double> fast(48), slow(48), base(48);
  dragged.contact_field_ut(cs, fast);
  dragged.contact_field_ut<double>(std::span<const Contact>(cs, 2), slow.data());
  plain.contact_field_ut(cs, base);
  double diff = 0, norm = 0;
  for (int i = 0; i < 48; ++i) {
    EXPECT_NEAR(fast[i], slow[i], 1e-9 * (1 + std::fabs(slow[i])));
    diff += (fast[i] - base[i]) * (fast[i] - base[i]);
    norm += base[i] * base[i];
  }
  EXPECT_GT(diff, 1e-4 * norm);  // many times the noise on a 3 mm press
  design.inplane_drag = 1.5;
  EXPECT_FALSE(PatchModel::nominal(design).ok());
}

// Disc magnets: the cubature's field on a magnet's axis is nearer the exact finite cylinder's
// than the point dipole is, and a press's field differs from the model's unit (each magnet a
// dipole and its cylinder's octupole) by about a percent (the cubature's points bend with the
// plate, a rigid magnet does not): small, but many times the sensor noise on a deep press.
TEST_F(PatchModelTest, DiscMagnetsAreNearerTheExactCylinderThanADipole) {
  const PatchModel dipoles = nominal();
  const Result<PatchModel> discs = PatchModel::with_disc_magnets(dipoles);
  ASSERT_TRUE(discs.ok()) << discs.error().to_string();
  ASSERT_EQ(discs->magnets().size(), dipoles.magnets().size() * PatchModel::kDiscPoints);
  // Magnet 0's points, seen from below on its axis.
  const PatchModel::Magnet& m0 = dipoles.magnets()[0];
  for (double z : {8.0, 12.0, 17.75}) {
    const Vec3<double> at{m0.u, m0.v, m0.h - z};
    double cubature = 0;
    for (int k = 0; k < PatchModel::kDiscPoints; ++k) {
      const PatchModel::Magnet& p = discs->magnets()[static_cast<std::size_t>(k)];
      cubature += dipole_field_ut(p.m_loc, at - Vec3<double>{p.u, p.v, p.h}).z;
    }
    const double dipole = dipole_field_ut(m0.m_loc, at - Vec3<double>{m0.u, m0.v, m0.h}).z;
    const double exact =
        std::copysign(cylinder_axial_field_ut(design.remanence_t, design.magnet_diameter_mm,
                                              design.magnet_height_mm, z),
                      m0.m_loc.z);
    EXPECT_LT(std::fabs(cubature - exact), 0.2 * std::fabs(dipole - exact)) << "z " << z;
  }
  // A press: the two units differ by 0.2-5 % of the field.
  const Contact c{5, 5, 3.0, 5};
  std::vector<double> a(48), b(48);
  dipoles.contact_field_ut(std::span<const Contact>(&c, 1), a);
  discs->contact_field_ut(std::span<const Contact>(&c, 1), b);
  double diff = 0, norm = 0;
  for (int i = 0; i < 48; ++i) {
    diff += (a[i] - b[i]) * (a[i] - b[i]);
    norm += a[i] * a[i];
  }
  const double rel = std::sqrt(diff / norm);
  std::printf("disc vs the model: %.3f %% of a 3 mm press's field\n", 100 * rel);
  EXPECT_GT(rel, 0.002);
  EXPECT_LT(rel, 0.05);
}

TEST_F(PatchModelTest, ShearMovesTheSurfaceAlongTheForce) {
  const PatchModel p = nominal();
  const PatchModel::Magnet* centre = nullptr;  // the magnet at the patch centre
  for (const auto& m : p.magnets()) {
    if (m.u == 0 && m.v == 0) centre = &m;
  }
  ASSERT_NE(centre, nullptr);
  // A press right on the magnet: bending moves it straight down, shear along the force by
  // F / k_t under the tip; 8 mm away the shift has decayed by exp(-8 / l_t) (a point tip).
  for (double tip : {0.0, 5.0}) {
    ContactT<double> c{0, 0, 2.0, tip, 0.7, -0.35};
    Vec3<double> pos, moment;
    ASSERT_TRUE(p.magnet_pose<double>(centre->u, centre->v, centre->h, centre->m_loc,
                                      p.spread_u_mm(), p.spread_v_mm(), p.lateral_mm(),
                                      std::span<const Contact>(&c, 1), &pos, &moment));
    EXPECT_NEAR(pos.x, 0.7 / design.shear_stiffness_n_per_mm, 1e-12) << tip;
    EXPECT_NEAR(pos.y, -0.35 / design.shear_stiffness_n_per_mm, 1e-12) << tip;
  }
  ContactT<double> off{-8, 0, 2.0, 0.0, 0.7, 0};
  Vec3<double> pos, moment, pos0, moment0;
  p.magnet_pose<double>(centre->u, centre->v, centre->h, centre->m_loc, p.spread_u_mm(),
                        p.spread_v_mm(), p.lateral_mm(), std::span<const Contact>(&off, 1), &pos,
                        &moment);
  off.shear_u_n = 0;
  p.magnet_pose<double>(centre->u, centre->v, centre->h, centre->m_loc, p.spread_u_mm(),
                        p.spread_v_mm(), p.lateral_mm(), std::span<const Contact>(&off, 1), &pos0,
                        &moment0);
  EXPECT_NEAR(pos.x - pos0.x, 0.7 / design.shear_stiffness_n_per_mm * std::exp(-8.0 / 8.0), 1e-12);
  EXPECT_EQ(pos.y, pos0.y);
  // No press, no shear: a tangential force needs a contact.
  const Contact lifted{0, 0, 0, 5.0, 2.0, 2.0};
  std::vector<double> out(48, 1.0);
  p.contact_field_ut(std::span<const Contact>(&lifted, 1), out);
  for (double x : out) EXPECT_EQ(x, 0.0);
}

TEST_F(PatchModelTest, ShearFieldIsOddInTheForceAndSeenBySensors) {
  const PatchModel p = nominal();
  std::vector<double> f0(48), fp(48), fm(48);
  Contact c{-41, -44, 2.5, 5.0};
  p.contact_field_ut(std::span<const Contact>(&c, 1), f0);
  c.shear_u_n = 0.3;
  p.contact_field_ut(std::span<const Contact>(&c, 1), fp);
  c.shear_u_n = -0.3;
  p.contact_field_ut(std::span<const Contact>(&c, 1), fm);
  double change = 0, even = 0;
  for (int i = 0; i < 48; ++i) {
    change += (fp[i] - f0[i]) * (fp[i] - f0[i]);
    even += (fp[i] + fm[i] - 2 * f0[i]) * (fp[i] + fm[i] - 2 * f0[i]);
  }
  EXPECT_GT(std::sqrt(change), 5.0);  // uT: many times the 0.7 uT noise for 0.3 N
  EXPECT_LT(std::sqrt(even), 0.05 * std::sqrt(change));  // nearly linear at this force
}

TEST_F(PatchModelTest, ShearJacobianMatchesFiniteDifferences) {
  auto made = PatchModel::fabricated(design, 0x5EA5, FabricationVariation{});
  ASSERT_TRUE(made.ok());
  const PatchModel& p = *made;
  // Derivatives at zero shear must not be skipped: the fit starts there.
  for (const Contact c : {Contact{3.3, -7.1, 1.5, 5.0}, Contact{-40, 22, 3.5, 5.0, 0.4, -0.2}}) {
    using D = Dual<2>;
    const ContactT<D> cd{c.u_mm,
                         c.v_mm,
                         c.depth_mm,
                         c.tip_radius_mm,
                         D::variable(c.shear_u_n, 0),
                         D::variable(c.shear_v_n, 1)};
    D out[48];
    p.contact_field_ut<D>(std::span<const ContactT<D>>(&cd, 1), out);
    double largest = 0;
    for (int k = 0; k < 2; ++k) {
      const double h = 1e-5;
      Contact cp = c, cm = c;
      (k == 0 ? cp.shear_u_n : cp.shear_v_n) += h;
      (k == 0 ? cm.shear_u_n : cm.shear_v_n) -= h;
      std::vector<double> fp(48), fm(48);
      p.contact_field_ut(std::span<const Contact>(&cp, 1), fp);
      p.contact_field_ut(std::span<const Contact>(&cm, 1), fm);
      for (int i = 0; i < 48; ++i) {
        const double fd = (fp[i] - fm[i]) / (2 * h);
        EXPECT_NEAR(out[i].d[k], fd, 1e-4 * (1 + std::fabs(fd))) << i << " " << k;
        largest = std::fmax(largest, std::fabs(fd));
      }
    }
    EXPECT_GT(largest, 2.0);  // uT per N (the noise: 0.7 uT)
  }
}

TEST_F(PatchModelTest, FabricatedUnitsAreDeterministicPerUid) {
  auto a = PatchModel::fabricated(design, 42, FabricationVariation{});
  auto b = PatchModel::fabricated(design, 42, FabricationVariation{});
  auto c = PatchModel::fabricated(design, 43, FabricationVariation{});
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  std::vector<double> fa(48), fb(48), fc(48);
  const Contact k{5, 5, 2};
  a->contact_field_ut(std::span<const Contact>(&k, 1), fa);
  b->contact_field_ut(std::span<const Contact>(&k, 1), fb);
  c->contact_field_ut(std::span<const Contact>(&k, 1), fc);
  EXPECT_EQ(fa, fb);
  EXPECT_NE(fa, fc);
  EXPECT_EQ(a->magnets()[3].u, b->magnets()[3].u);
}

TEST_F(PatchModelTest, NoNanOrInfAtExtremes) {
  for (SurfaceKind kind : {SurfaceKind::kFlat, SurfaceKind::kCylinder}) {
    design.surface = kind;
    design.radius_mm = 40;
    const PatchModel p = nominal();
    std::vector<double> out(48), jac(144), rest(48);
    p.rest_field_ut(rest);
    for (double x : rest) ASSERT_TRUE(std::isfinite(x));
    const double edge = 70, corner = 70;
    for (const Contact c :
         {Contact{0, 0, 0}, Contact{0, 0, 1e-9}, Contact{0, 0, 50}, Contact{0, 0, 1e9},
          Contact{edge, 0, 4}, Contact{corner, corner, 4}, Contact{-corner, corner, 9},
          Contact{500, -500, 4}, Contact{60, 60, -3}, Contact{-60, -60, 4},
          Contact{std::nan(""), 0, 3}, Contact{0, 0, std::nan("")}, Contact{1e300, 0, 3},
          Contact{0, 0, 4, 500}, Contact{0, 0, 1e-12, 5}, Contact{70, 70, 9, 20}}) {
      p.contact_field_ut(std::span<const Contact>(&c, 1), out);
      for (double x : out)
        ASSERT_TRUE(std::isfinite(x)) << c.u_mm << "," << c.v_mm << "," << c.depth_mm;
      if (std::isfinite(c.u_mm) && std::isfinite(c.depth_mm) && std::fabs(c.u_mm) < 1e6) {
        p.contact_jacobian(c, jac);
        for (double x : jac)
          ASSERT_TRUE(std::isfinite(x)) << c.u_mm << "," << c.v_mm << "," << c.depth_mm;
      }
    }
  }
}

TEST_F(PatchModelTest, RoundTipSpreadsWiderAtTheSameDepth) {
  const PatchModel p = nominal();
  std::vector<double> point(48), round(48), tiny(48);
  const Contact a{-15, -15, 2}, b{-15, -15, 2, 8.0}, c{-15, -15, 2, 1e-6};
  p.contact_field_ut(std::span<const Contact>(&a, 1), point);
  p.contact_field_ut(std::span<const Contact>(&b, 1), round);
  p.contact_field_ut(std::span<const Contact>(&c, 1), tiny);
  // A neighbouring sensor (30 mm away) sees more of the wider bowl.
  EXPECT_GT(std::fabs(round[3 * 6 + 2]), std::fabs(point[3 * 6 + 2]));
  for (int i = 0; i < 48; ++i) EXPECT_NEAR(tiny[i], point[i], 1e-3);  // a vanishing tip is a point
}

TEST_F(PatchModelTest, DepthIsClampedAndForceGrows) {
  const PatchModel p = nominal();
  std::vector<double> a(48), b(48);
  const Contact deep{0, 0, p.max_depth_mm()}, deeper{0, 0, 100};
  p.contact_field_ut(std::span<const Contact>(&deep, 1), a);
  p.contact_field_ut(std::span<const Contact>(&deeper, 1), b);
  EXPECT_EQ(a, b);
  EXPECT_EQ(p.force_n(0), 0);
  EXPECT_EQ(p.force_n(-1), 0);
  EXPECT_NEAR(p.force_n(2), 2 * 2.0 + 0.05 * 8, 1e-12);
  EXPECT_GT(p.force_n(4), p.force_n(3));
}

TEST_F(PatchModelTest, BadDesignsNameTheParameter) {
  design.spread_mm = -1;
  auto m = PatchModel::nominal(design);
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.error().message.find("spread_mm"), std::string::npos);
  design = PatchDesign{};
  design.surface = SurfaceKind::kCylinder;
  design.radius_mm = 10;
  m = PatchModel::nominal(design);
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.error().message.find("radius_mm"), std::string::npos);
  design = PatchDesign{};
  design.sensor_pitch_mm = 60;
  EXPECT_FALSE(PatchModel::nominal(design).ok());
  for (double bad : {0.0, -1.0}) {
    design = PatchDesign{};
    design.shear_spread_mm = bad;
    m = PatchModel::nominal(design);
    ASSERT_FALSE(m.ok());
    EXPECT_NE(m.error().message.find("shear_spread_mm"), std::string::npos);
  }
  design = PatchDesign{};
  design.shear_stiffness_n_per_mm = -1;
  m = PatchModel::nominal(design);
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.error().message.find("shear_stiffness_n_per_mm"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::sim
