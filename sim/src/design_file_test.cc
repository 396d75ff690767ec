#include "skinbus/sim/design_file.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "skinbus/common/test_seed.h"

namespace skinbus::sim {
namespace {

std::string source_dir() {
  const char* d = std::getenv("SKINBUS_SOURCE_DIR");
  return d ? d : ".";
}

// Every field of two designs, by the complete file each gives (design_to_yaml writes every
// setting with the digits that read back exactly).
void expect_same(const PatchDesign& a, const PatchDesign& b) {
  EXPECT_EQ(design_to_yaml(a), design_to_yaml(b));
  EXPECT_EQ(a.magnets_u, b.magnets_u);
  EXPECT_EQ(a.sensor_depth_mm, b.sensor_depth_mm);
  EXPECT_EQ(a.polarity, b.polarity);
  EXPECT_EQ(a.surface, b.surface);
  EXPECT_EQ(a.sensor_config.gain_sel, b.sensor_config.gain_sel);
}

TEST(DesignFile, TheShippedNominalFileIsTheBuiltInDesign) {
  Result<PatchDesign> d = read_design_file(source_dir() + "/sim/designs/nominal.yaml");
  ASSERT_TRUE(d.ok()) << d.error().to_string();
  expect_same(d.value(), PatchDesign{});
}

TEST(DesignFile, AnEmptyDesignBesidesTheFormatIsTheBuiltInDesign) {
  Result<PatchDesign> d = parse_design("format: skinbus-patch-design\n", "x.yaml");
  ASSERT_TRUE(d.ok()) << d.error().to_string();
  expect_same(d.value(), PatchDesign{});
}

TEST(DesignFile, RandomDesignsRoundTripExactly) {
  const uint64_t seed = test_seed("DesignFile.RandomDesignsRoundTripExactly");
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u01(0, 1);
  for (int i = 0; i < 200; ++i) {
    PatchDesign d;
    d.surface = u01(rng) < 0.5 ? SurfaceKind::kFlat : SurfaceKind::kCylinder;
    d.thickness_mm = 5 + 20 * u01(rng);
    d.sensor_depth_mm = d.thickness_mm + 3 * u01(rng);
    d.radius_mm = d.surface == SurfaceKind::kCylinder ? d.sensor_depth_mm + 40 + 60 * u01(rng) : 0;
    d.sensors_u = 1 + static_cast<int>(5 * u01(rng));
    d.sensors_v = 1 + static_cast<int>(5 * u01(rng));
    d.sensor_pitch_mm = 10 + 20 * u01(rng);
    d.size_u_mm = (d.sensors_u - 1) * d.sensor_pitch_mm + 10 + 50 * u01(rng);
    d.size_v_mm = (d.sensors_v - 1) * d.sensor_pitch_mm + 10 + 50 * u01(rng);
    if (d.surface == SurfaceKind::kCylinder) d.size_u_mm = std::min(d.size_u_mm, 4 * d.radius_mm);
    d.magnets_u = 1 + static_cast<int>(12 * u01(rng));
    d.magnets_v = 1 + static_cast<int>(12 * u01(rng));
    d.magnet_pitch_mm = 5 + 20 * u01(rng);
    d.polarity = u01(rng) < 0.5 ? Polarity::kUniform : Polarity::kCheckerboard;
    d.magnet_centre_height_mm = -2 + 4 * u01(rng);
    d.remanence_t = 0.5 + u01(rng);
    d.spread_mm = 3 + 15 * u01(rng);
    d.lateral_mm = 4 * u01(rng);
    d.anisotropy = -0.3 + 0.6 * u01(rng);
    d.tip_crush_mm = u01(rng) < 0.5 ? 0.0 : 5 + 30 * u01(rng);
    d.inplane_drag = u01(rng) < 0.5 ? 0.0 : 0.3 * u01(rng);
    d.creep_fraction = u01(rng) < 0.5 ? 0.0 : 0.5 * u01(rng);
    d.creep_time_s = 0.05 + u01(rng);
    d.creep_slow_fraction = u01(rng) < 0.5 ? 0.0 : 0.4 * u01(rng);
    d.creep_slow_time_s = 1 + 10 * u01(rng);
    d.stiffness_n_per_mm = 0.5 + 3 * u01(rng);
    d.shear_stiffness_n_per_mm = 0.3 + 3 * u01(rng);
    d.shear_spread_mm = 2 + 12 * u01(rng);
    d.indenter_tip_radius_mm = u01(rng) < 0.2 ? 0.0 : 15 * u01(rng);
    d.sensor_config.gain_sel = static_cast<uint8_t>(rng() % 8);
    d.sensor_config.osr = static_cast<uint8_t>(rng() % 4);
    d.sensor_config.temperature = rng() % 2 == 1;
    ASSERT_TRUE(validate(d).ok()) << "seed " << seed << " design " << i << ": "
                                  << validate(d).error().to_string();
    Result<PatchDesign> back = parse_design(design_to_yaml(d), "round-trip.yaml");
    ASSERT_TRUE(back.ok()) << "seed " << seed << ": " << back.error().to_string();
    expect_same(back.value(), d);
    EXPECT_EQ(back->size_u_mm, d.size_u_mm) << "seed " << seed;
    EXPECT_EQ(back->anisotropy, d.anisotropy) << "seed " << seed;
    EXPECT_EQ(back->tip_crush_mm, d.tip_crush_mm) << "seed " << seed;
    EXPECT_EQ(back->inplane_drag, d.inplane_drag) << "seed " << seed;
    EXPECT_EQ(back->creep_fraction, d.creep_fraction) << "seed " << seed;
    EXPECT_EQ(back->creep_time_s, d.creep_time_s) << "seed " << seed;
    EXPECT_EQ(back->creep_slow_fraction, d.creep_slow_fraction) << "seed " << seed;
    EXPECT_EQ(back->creep_slow_time_s, d.creep_slow_time_s) << "seed " << seed;
    EXPECT_EQ(back->indenter_tip_radius_mm, d.indenter_tip_radius_mm) << "seed " << seed;
  }
}

TEST(DesignFile, WriteThenReadGivesTheSameDesign) {
  PatchDesign d;
  d.magnets_u = d.magnets_v = 9;
  d.magnet_pitch_mm = 15;
  d.polarity = Polarity::kUniform;
  d.magnet_centre_height_mm = -1;
  d.sensor_depth_mm = 18;
  const std::string path = ::testing::TempDir() + "/design_file_test.yaml";
  ASSERT_TRUE(write_design_file(d, path).ok());
  Result<PatchDesign> back = read_design_file(path);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  expect_same(back.value(), d);
  std::remove(path.c_str());
}

// The built-in grid written out as lists.
PatchDesign as_lists(const PatchDesign& grid) {
  PatchDesign d = grid;
  for (int j = 0; j < grid.magnets_v; ++j) {
    for (int i = 0; i < grid.magnets_u; ++i) {
      d.magnet_list.push_back({(i - (grid.magnets_u - 1) / 2.0) * grid.magnet_pitch_mm,
                               (j - (grid.magnets_v - 1) / 2.0) * grid.magnet_pitch_mm,
                               grid.magnet_centre_height_mm, (i + j) % 2 ? -1 : 1});
    }
  }
  for (int j = 0; j < grid.sensors_v; ++j) {
    for (int i = 0; i < grid.sensors_u; ++i) {
      d.sensor_list.push_back({(i - (grid.sensors_u - 1) / 2.0) * grid.sensor_pitch_mm,
                               (j - (grid.sensors_v - 1) / 2.0) * grid.sensor_pitch_mm,
                               grid.sensor_depth_mm, 0});
    }
  }
  return d;
}

std::vector<double> field_of(const PatchModel& m, const Contact& c) {
  std::vector<double> f(static_cast<std::size_t>(m.channel_count()));
  m.contact_field_ut(std::span<const Contact>(&c, 1), f);
  return f;
}

TEST(DesignFile, MagnetsAndSensorsAsListsRoundTripAndModelTheSamePatchAsTheGrid) {
  const PatchDesign grid;  // checkerboard
  const PatchDesign lists = as_lists(grid);
  ASSERT_EQ(lists.magnet_count(), grid.magnet_count());
  ASSERT_EQ(lists.sensor_count(), grid.sensor_count());
  Result<PatchDesign> back = parse_design(design_to_yaml(lists), "lists.yaml");
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_EQ(design_to_yaml(back.value()), design_to_yaml(lists));
  ASSERT_EQ(back->magnet_list.size(), lists.magnet_list.size());
  EXPECT_EQ(back->magnet_list[1].polarity, -1);
  // The same physics, bit for bit: nominal and a fabricated unit (the same draws in the same
  // order), at rest and pressed.
  for (bool fabricated : {false, true}) {
    Result<PatchModel> a =
        fabricated ? PatchModel::fabricated(grid, 0x5B07, {}) : PatchModel::nominal(grid);
    Result<PatchModel> b = fabricated ? PatchModel::fabricated(back.value(), 0x5B07, {})
                                      : PatchModel::nominal(back.value());
    ASSERT_TRUE(a.ok() && b.ok());
    const Contact press{12.5, -7.25, 2.0, 5};
    EXPECT_EQ(field_of(a.value(), press), field_of(b.value(), press)) << fabricated;
  }
}

TEST(DesignFile, ASensorTurnedAQuarterAboutTheNormalSwapsItsXAndY) {
  PatchDesign one;
  one.sensor_list = {{10, 5, 17, 0}};
  PatchDesign turned = one;
  turned.sensor_list[0].yaw_deg = 90;
  Result<PatchModel> a = PatchModel::nominal(one), b = PatchModel::nominal(turned);
  ASSERT_TRUE(a.ok() && b.ok());
  const Contact press{22, 3, 2.5, 5};
  const std::vector<double> fa = field_of(a.value(), press), fb = field_of(b.value(), press);
  ASSERT_EQ(fa.size(), 3u);
  // The press gives x and y fields of clearly different size, so a turn that did nothing fails.
  EXPECT_GT(std::fabs(std::fabs(fa[0]) - std::fabs(fa[1])), 1.0) << fa[0] << " " << fa[1];
  EXPECT_NEAR(std::fabs(fb[0]), std::fabs(fa[1]), 1e-9);
  EXPECT_NEAR(std::fabs(fb[1]), std::fabs(fa[0]), 1e-9);
  EXPECT_NEAR(fb[2], fa[2], 1e-9);
}

// Each bad file and what its error must say (the file, the setting, its line).
TEST(DesignFile, EveryBadSettingIsNamedWithItsLine) {
  const std::string head = "format: skinbus-patch-design\nversion: 1\n";
  const struct {
    std::string text;
    std::string expected;
  } cases[] = {
      {"version: 1\n", "format (line 1): missing"},
      {"format: skin-map\n", "format (line 1): 'skin-map' is not skinbus-patch-design"},
      {"format: skinbus-patch-design\nversion: 2\n", "version (line 2)"},
      {head + "magnet:\n  polarity: uniform\n", "magnet (line 3): unknown setting"},
      {head + "magnets:\n  polarity: striped\n", "magnets.polarity (line 4): 'striped'"},
      {head + "magnets:\n  grid: {u: 0, v: 7, pitch_mm: 20}\n", "magnets.grid.u (line 4)"},
      {head + "magnets:\n  grid: {u: 7, v: 7, pitch: 20}\n", "magnets.grid.pitch (line 4)"},
      {head + "magnets:\n  remanence_t: strong\n", "magnets.remanence_t (line 4): 'strong' is not"},
      {head + "surface:\n  kind: sphere\n", "surface.kind (line 4): 'sphere'"},
      {head + "surface:\n  size_u_mm: -3\n", "surface.size_u_mm (line 4): -3 is outside"},
      {head + "surface:\n  thickness_mm: 5\n  thickness_mm: 6\n",
       "surface.thickness_mm (line 5): given twice"},
      {head + "sensors:\n  chip: {gain_sel: 9}\n", "sensors.chip.gain_sel (line 4)"},
      {head + "sensors:\n  chip: {temperature: maybe}\n", "sensors.chip.temperature (line 4)"},
      {head + "lattice:\n  anisotropy: 0.7\n", "lattice.anisotropy (line 4)"},
      {head + "lattice:\n  tip_crush_mm: -1\n", "lattice.tip_crush_mm (line 4)"},
      {head + "lattice:\n  inplane_drag: 2\n", "lattice.inplane_drag (line 4)"},
      {head + "lattice:\n  creep_fraction: 1\n", "lattice.creep_fraction (line 4)"},
      {head + "lattice:\n  creep_time_s: 0\n", "lattice.creep_time_s (line 4)"},
      {head + "lattice:\n  creep_slow_time_s: -1\n", "lattice.creep_slow_time_s (line 4)"},
      {head + "lattice:\n  creep_fraction: 0.6\n  creep_slow_fraction: 0.5\n",
       "creep_fraction + creep_slow_fraction < 1"},
      {head + "force_law:\n  stiffness_n_per_mm: nan\n", "force_law.stiffness_n_per_mm (line 4)"},
      {head + "indenter:\n  tip_radius_mm: 60\n", "indenter.tip_radius_mm (line 4): 60 is outside"},
      {head + "indenter:\n  radius_mm: 4\n", "indenter.radius_mm (line 4): unknown setting"},
      {head + "sensors:\n  grid: {u: 8, v: 8, pitch_mm: 30}\n",
       "patch design: the sensor grid does not fit inside the patch"},
      {head + "sensors:\n  depth_mm: 10\n", "patch design: sensor_depth_mm must be >= thickness"},
      {head + "surface: {kind: cylinder, radius_mm: 10}\n", "patch design: cylinder radius_mm"},
      {head + "lattice: [1, 2\n", "line "},
      {head + "magnets:\n  list:\n    - {u_mm: 0, v_mm: 0, polarity: 0}\n",
       "magnets.list[0].polarity (line 5): must be 1 or -1"},
      {head + "magnets:\n  list:\n    - {u_mm: 0}\n", "magnets.list[0] (line 5): u_mm and v_mm"},
      {head + "magnets:\n  list: []\n", "magnets.list (line 4): expected a non-empty list"},
      {head + "magnets:\n  grid: {u: 3, v: 3, pitch_mm: 9}\n  list:\n    - {u_mm: 0, v_mm: 0}\n",
       "magnets.list (line 6): give the magnets as a grid or as a list"},
      {head + "sensors:\n  list:\n    - {u_mm: 0, v_mm: 0, tilt: 3}\n",
       "sensors.list[0].tilt (line 5): unknown setting"},
      {head + "sensors:\n  list:\n    - {u_mm: 90, v_mm: 0}\n",
       "patch design: sensor_list[0]: outside the patch"},
      {"- a\n- b\n", "(top level)"},
  };
  for (const auto& c : cases) {
    Result<PatchDesign> d = parse_design(c.text, "my_patch.yaml");
    ASSERT_FALSE(d.ok()) << c.text;
    EXPECT_NE(d.error().message.find("my_patch.yaml: "), std::string::npos) << d.error().message;
    EXPECT_NE(d.error().message.find(c.expected), std::string::npos)
        << "expected '" << c.expected << "' in: " << d.error().message;
  }
}

TEST(DesignFile, AMissingFileIsNamed) {
  Result<PatchDesign> d = read_design_file("/nonexistent/patch.yaml");
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.error().code, ErrorCode::kNotFound);
  EXPECT_NE(d.error().message.find("/nonexistent/patch.yaml"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::sim
