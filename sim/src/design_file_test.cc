#include "skinbus/sim/design_file.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>

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
    d.stiffness_n_per_mm = 0.5 + 3 * u01(rng);
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
      {head + "force_law:\n  stiffness_n_per_mm: nan\n", "force_law.stiffness_n_per_mm (line 4)"},
      {head + "sensors:\n  grid: {u: 8, v: 8, pitch_mm: 30}\n",
       "patch design: the sensor grid does not fit inside the patch"},
      {head + "sensors:\n  depth_mm: 10\n", "patch design: sensor_depth_mm must be >= thickness"},
      {head + "surface: {kind: cylinder, radius_mm: 10}\n", "patch design: cylinder radius_mm"},
      {head + "lattice: [1, 2\n", "line "},
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
