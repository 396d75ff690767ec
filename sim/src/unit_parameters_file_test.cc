#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/unit_model.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::sim {
namespace {

UnitParameters fabricated_unit() {
  auto m = PatchModel::fabricated(PatchDesign{}, 0x5B00000000000001ull, FabricationVariation{});
  EXPECT_TRUE(m.ok());
  return m->parameters();
}

bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

// Each bad text in place of the whole `key` field of `good` (an object of numbers and arrays: its
// first '}' closes it) is refused as a parse error naming what is wrong.
using BadFields = std::vector<std::pair<std::string, std::string>>;  // {text, what the error says}
void expect_each_named(const std::string& good, const std::string& key, const BadFields& bads) {
  const std::size_t from = good.find("\"" + key + "\"");
  ASSERT_NE(from, std::string::npos) << key;
  const std::size_t to = good.find('}', from) + 1;
  for (const auto& [bad, want] : bads) {
    std::string t = good;
    t.replace(from, to - from, bad);
    auto e = parse_unit_parameters(t);
    ASSERT_FALSE(e.ok()) << want;
    EXPECT_EQ(e.error().code, ErrorCode::kParse);
    EXPECT_NE(e.error().message.find(want), std::string::npos) << e.error().message;
  }
}

TEST(UnitParametersFileTest, RoundTripIsExactAndRebuildsTheSameUnit) {
  const UnitParameters p = fabricated_unit();
  UnitFileNote note;
  auto back = parse_unit_parameters(unit_parameters_json(p, {"fit of unit 7", {}, {}}), &note);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_EQ(note.source, "fit of unit 7");
  EXPECT_EQ(note.refused, "");  // a kept fit: the field is absent
  EXPECT_EQ(unit_parameters_json(p).find("\"refused\""), std::string::npos);
  ASSERT_EQ(back->magnets.size(), p.magnets.size());
  ASSERT_EQ(back->sensors.size(), p.sensors.size());
  EXPECT_TRUE(same_bits(back->spread_mm, p.spread_mm));
  EXPECT_TRUE(same_bits(back->lateral_mm, p.lateral_mm));
  for (std::size_t i = 0; i < p.magnets.size(); ++i) {
    EXPECT_TRUE(same_bits(back->magnets[i].h_mm, p.magnets[i].h_mm)) << i;
    EXPECT_TRUE(same_bits(back->magnets[i].moment_am2.z, p.magnets[i].moment_am2.z)) << i;
  }
  for (std::size_t i = 0; i < p.sensors.size(); ++i) {
    EXPECT_TRUE(same_bits(back->sensors[i].gain.y, p.sensors[i].gain.y)) << i;
    EXPECT_TRUE(same_bits(back->sensors[i].mounting.r[2].x, p.sensors[i].mounting.r[2].x)) << i;
  }
  // The rebuilt model computes the same fields as the original unit.
  auto original = PatchModel::from_parameters(PatchDesign{}, p);
  auto rebuilt = PatchModel::from_parameters(PatchDesign{}, *back);
  ASSERT_TRUE(original.ok() && rebuilt.ok());
  std::vector<double> a(static_cast<std::size_t>(original->channel_count()));
  std::vector<double> b(a.size());
  const Contact press[1] = {{3.0, -7.5, 2.0, 5.0}};
  original->contact_field_ut(press, a);
  rebuilt->contact_field_ut(press, b);
  for (std::size_t c = 0; c < a.size(); ++c) EXPECT_TRUE(same_bits(a[c], b[c])) << c;
}

// A unit's field correction travels in its file, bit for bit; a malformed one is named.
TEST(UnitParametersFileTest, TheFieldCorrectionRoundTripsAndBadOnesAreNamed) {
  UnitParameters p = fabricated_unit();
  FieldCorrection::Grid g;
  g.u0_mm = -66;
  g.v0_mm = -61.5;
  g.step_mm = 7.25;
  g.nu = 6;
  g.nv = 5;
  g.max_depth_mm = 4.125;
  std::vector<double> coef(g.terms() * 48);
  for (std::size_t i = 0; i < coef.size(); ++i)
    coef[i] = std::sin(0.37 * static_cast<double>(i)) / 3;
  auto made = FieldCorrection::make(g, 48, coef);
  ASSERT_TRUE(made.ok());
  p.field_correction = std::make_shared<const FieldCorrection>(std::move(*made));
  const std::string text = unit_parameters_json(p);
  auto back = parse_unit_parameters(text);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  ASSERT_NE(back->field_correction, nullptr);
  const FieldCorrection& f = *back->field_correction;
  EXPECT_TRUE(same_bits(f.grid().u0_mm, g.u0_mm) && same_bits(f.grid().step_mm, g.step_mm));
  EXPECT_EQ(f.grid().nu, 6);
  EXPECT_EQ(f.grid().nv, 5);
  ASSERT_EQ(f.coefficients().size(), coef.size());
  for (std::size_t i = 0; i < coef.size(); ++i)
    EXPECT_TRUE(same_bits(f.coefficients()[i], coef[i]));
  // Without one, the file has none and reads back none.
  EXPECT_EQ(unit_parameters_json(fabricated_unit()).find("field_correction"), std::string::npos);
  EXPECT_EQ(parse_unit_parameters(unit_parameters_json(fabricated_unit()))->field_correction,
            nullptr);
  auto error_of = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    const std::size_t at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    t.replace(at, from.size(), to);
    auto r = parse_unit_parameters(t);
    EXPECT_FALSE(r.ok()) << from;
    return r.ok() ? std::string() : r.error().message;
  };
  EXPECT_NE(error_of("\"nu\": 6", "\"nu\": 7").find("4320 coefficients, 5040 expected"),
            std::string::npos);
  EXPECT_NE(error_of("\"nv\": 5", "\"nv\": 5.5").find("field_correction.nv is not an integer"),
            std::string::npos);
  EXPECT_NE(error_of("\"depth_terms\": 3", "\"depth_terms\": 2").find("depth_terms"),
            std::string::npos);
  EXPECT_NE(error_of("\"step_mm\": 7.25", "\"step_mm\": -1").find("step_mm must be > 0"),
            std::string::npos);
  EXPECT_NE(error_of("\"coefficients_ut\": [", "\"coefficients_ut\": [\"x\",")
                .find("field_correction.coefficients_ut[0] is not a number"),
            std::string::npos);
}

// A refused fit written before the `refused` field (its source alone says so) reads as refused,
// with the source's reason; a kept fit's source that merely mentions the word does not.
TEST(UnitParametersFileTest, ARefusedFitFromBeforeTheFieldStaysRefused) {
  const UnitParameters p = fabricated_unit();
  const std::string source = "skinbus-identify lab.csv" + std::string(kRefusedInSource) +
                             "not_converged: residual 2.00 noise units";
  UnitFileNote note;
  ASSERT_TRUE(parse_unit_parameters(unit_parameters_json(p, {source, {}, {}}), &note).ok());
  EXPECT_EQ(note.refused, "not_converged: residual 2.00 noise units");
  ASSERT_TRUE(parse_unit_parameters(
                  unit_parameters_json(
                      p, {"skinbus-identify lab.csv" + std::string(kRefusedInSource), {}, {}}),
                  &note)
                  .ok());
  EXPECT_EQ(note.refused, "no reason given");
  ASSERT_TRUE(
      parse_unit_parameters(unit_parameters_json(p, {"REFUSED twice, then kept", {}, {}}), &note)
          .ok());
  EXPECT_EQ(note.refused, "");
}

TEST(UnitParametersFileTest, WritesAndReadsAFile) {
  const UnitParameters p = fabricated_unit();
  const std::string path = ::testing::TempDir() + "/unit_parameters_file_test.json";
  ASSERT_TRUE(write_unit_parameters(p, path, {"test", {}, {}}).ok());
  auto back = read_unit_parameters(path);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_EQ(back->magnets.size(), p.magnets.size());
  std::remove(path.c_str());
  auto missing = read_unit_parameters(path);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  EXPECT_NE(missing.error().message.find(path), std::string::npos);
  EXPECT_FALSE(write_unit_parameters(p, "/nonexistent-dir/unit.json").ok());
}

// Every kind of damage gets a kParse error naming what is wrong.
TEST(UnitParametersFileTest, CorruptFilesAreRefusedWithTheField) {
  const std::string good = unit_parameters_json(fabricated_unit());
  auto refused = [](const std::string& text, const std::string& want) {
    auto r = parse_unit_parameters(text);
    ASSERT_FALSE(r.ok()) << "accepted: " << want;
    EXPECT_EQ(r.error().code, ErrorCode::kParse);
    EXPECT_NE(r.error().message.find(want), std::string::npos) << r.error().message;
  };
  auto replaced = [&](const std::string& from, const std::string& to) {
    std::string t = good;
    const std::size_t at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return t.replace(at, from.size(), to);
  };
  refused("", "not valid JSON");
  refused("[1, 2]", "not a JSON object");
  refused(good.substr(0, good.size() / 2), "not valid JSON");
  refused(replaced("\"skinbus-unit 1\"", "\"skinbus-dataset 1\""), "not a unit file");
  refused(replaced("\"skinbus-unit 1\"", "\"skinbus-unit 2\""), "this reader knows");
  refused(replaced("\"spread_mm\"", "\"spread\""), "spread_mm is missing");
  refused(replaced("\"lateral_mm\":", "\"lateral_mm\": \"2\", \"x\":"), "lateral_mm is not");
  refused(replaced("\"magnets\": [", "\"magnets\": 3, \"m\": ["), "magnets must be an array");
  refused(replaced("\"moment_am2\": [", "\"moment_am2\": [1, "), "magnets[0].moment_am2 must");
  refused(replaced("\"gain\": [", "\"gain\": [null, "), "sensors[0].gain");
  refused(replaced("\"mounting\": [", "\"mounting\": [[1, 2], "), "sensors[0].mounting");
  // A number no double holds: said, with where, not only "not valid JSON".
  refused(replaced("\"spread_mm\": ", "\"spread_mm\": 1e400, \"x\": "), "1e400");
  refused(good.substr(0, good.size() / 2), "parse error at line");
  refused(replaced("\"source\": \"\"", "\"source\": 7"), "source is not a string");
  refused(replaced("\"source\": \"\"", "\"source\": \"\", \"refused\": true"),
          "refused is not a string");
}

// A fit identification refused keeps why in the file, read back apart from the free note.
TEST(UnitParametersFileTest, ARefusedFitSaysSoAndWhy) {
  const UnitFileNote note{
      "identify rec.csv: REFUSED", "residual 5.80 noise units (limit 4.00)", {}};
  UnitFileNote back;
  auto p = parse_unit_parameters(unit_parameters_json(fabricated_unit(), note), &back);
  ASSERT_TRUE(p.ok()) << p.error().to_string();
  EXPECT_EQ(back.source, note.source);
  EXPECT_EQ(back.refused, note.refused);
}

// Where the unit was pressed travels in the note, bit for bit; absent, it is not known; a
// malformed one is named.
TEST(UnitParametersFileTest, ThePressedAreaRoundTripsAndBadOnesAreNamed) {
  const UnitParameters p = fabricated_unit();
  UnitFileNote note{"identify rec.csv", {}, PressedArea{-54.0, 54.0, -53.25, 0.1}};
  UnitFileNote back;
  auto r = parse_unit_parameters(unit_parameters_json(p, note), &back);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  ASSERT_TRUE(back.pressed_area.has_value());
  EXPECT_TRUE(same_bits(back.pressed_area->u_min_mm, -54.0));
  EXPECT_TRUE(same_bits(back.pressed_area->u_max_mm, 54.0));
  EXPECT_TRUE(same_bits(back.pressed_area->v_min_mm, -53.25));
  EXPECT_TRUE(same_bits(back.pressed_area->v_max_mm, 0.1));
  ASSERT_TRUE(parse_unit_parameters(unit_parameters_json(p), &back).ok());
  EXPECT_FALSE(back.pressed_area.has_value());

  expect_each_named(
      unit_parameters_json(p, note), "pressed_area_mm",
      {
          {"\"pressed_area_mm\": 3", "pressed_area_mm is not an object"},
          {"\"pressed_area_mm\": {\"u\": [1]}", "pressed_area_mm.u must be"},
          {"\"pressed_area_mm\": {\"u\": [1, 2], \"v\": [1, \"2\"]}", "pressed_area_mm.v must be"},
          {"\"pressed_area_mm\": {\"u\": [2, 1], \"v\": [1, 2]}",
           "pressed_area_mm.u must be finite"},
      });
}

// The identified creep travels bit for bit and becomes the model's design's; absent, none; a
// malformed one is named.
TEST(UnitParametersFileTest, TheCreepRoundTripsIntoTheModelAndBadOnesAreNamed) {
  UnitParameters p = fabricated_unit();
  EXPECT_EQ(unit_parameters_json(p).find("\"creep\""), std::string::npos);  // none: absent
  p.creep_fraction = 0.2345678901234567;
  p.creep_time_s = 0.4321;
  auto back = parse_unit_parameters(unit_parameters_json(p));
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_TRUE(same_bits(back->creep_fraction, p.creep_fraction));
  EXPECT_TRUE(same_bits(back->creep_time_s, p.creep_time_s));
  PatchDesign creeping;  // a design's own creep is not the unit's: the file's replaces it
  creeping.creep_fraction = 0.5;
  auto model = PatchModel::of_unit_file(creeping, *back);
  ASSERT_TRUE(model.ok()) << model.error().to_string();
  EXPECT_TRUE(same_bits(model->design().creep_fraction, p.creep_fraction));
  EXPECT_TRUE(same_bits(model->design().creep_time_s, p.creep_time_s));
  auto plain = PatchModel::of_unit_file(creeping, fabricated_unit());
  ASSERT_TRUE(plain.ok());
  EXPECT_EQ(plain->design().creep_fraction, 0.0);
  // A second, slower lag: absent unless there is one; exact; the model's design's.
  EXPECT_EQ(unit_parameters_json(p).find("slow_fraction"), std::string::npos);
  UnitParameters two = p;
  two.creep_slow_fraction = 0.0987654321012345;
  two.creep_slow_time_s = 2.71828;
  auto back2 = parse_unit_parameters(unit_parameters_json(two));
  ASSERT_TRUE(back2.ok()) << back2.error().to_string();
  EXPECT_TRUE(same_bits(back2->creep_slow_fraction, two.creep_slow_fraction));
  EXPECT_TRUE(same_bits(back2->creep_slow_time_s, two.creep_slow_time_s));
  auto model2 = PatchModel::of_unit_file(creeping, *back2);
  ASSERT_TRUE(model2.ok()) << model2.error().to_string();
  EXPECT_TRUE(same_bits(model2->design().creep_slow_fraction, two.creep_slow_fraction));
  EXPECT_TRUE(same_bits(model2->design().creep_slow_time_s, two.creep_slow_time_s));

  expect_each_named(
      unit_parameters_json(p), "creep",
      {
          {"\"creep\": []", "creep is not an object"},
          {"\"creep\": {\"time_s\": 1}", "creep.fraction is missing"},
          {"\"creep\": {\"fraction\": 0.1, \"time_s\": \"1\"}", "creep.time_s is not a number"},
          {"\"creep\": {\"fraction\": 1, \"time_s\": 1}", "creep.fraction must be in [0, 1)"},
          {"\"creep\": {\"fraction\": 0.1, \"time_s\": 0}", "creep.time_s must be in (0, 3600]"},
          {"\"creep\": {\"fraction\": 0.1, \"time_s\": 1, \"slow_fraction\": 0.1}",
           "creep.slow_time_s is missing"},
          {"\"creep\": {\"fraction\": 0.5, \"time_s\": 1, \"slow_fraction\": 0.5, "
           "\"slow_time_s\": 3}",
           "fraction + slow_fraction < 1"},
          {"\"creep\": {\"fraction\": 0.1, \"time_s\": 1, \"slow_fraction\": 0.1, "
           "\"slow_time_s\": -3}",
           "creep.slow_time_s must be in (0, 3600]"},
      });
}

// The lattice's anisotropy identification found: absent when 0, exact, the model's spreads along u
// and v from it (a design's adds to it only where a simulation asks, read_unit_model), and bad
// values named.
TEST(UnitParametersFileTest, TheAnisotropyRoundTripsIntoTheModelAndBadOnesAreNamed) {
  UnitParameters p = fabricated_unit();
  EXPECT_EQ(unit_parameters_json(p).find("\"anisotropy\""), std::string::npos);
  p.anisotropy = 0.0712345678901234;
  const std::string text = unit_parameters_json(p);
  auto back = parse_unit_parameters(text);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_TRUE(same_bits(back->anisotropy, p.anisotropy));
  PatchDesign drawn;
  drawn.anisotropy = 0.1;  // the drawing's: the class takes the unit's own
  auto model = PatchModel::of_unit_file(drawn, *back);
  ASSERT_TRUE(model.ok()) << model.error().to_string();
  EXPECT_EQ(model->spread_u_mm(), p.spread_mm * (1 + 0.0 + p.anisotropy));
  EXPECT_EQ(model->spread_v_mm(), p.spread_mm * (1 - 0.0 - p.anisotropy));
  EXPECT_TRUE(same_bits(model->parameters().anisotropy, p.anisotropy));
  const std::string path = ::testing::TempDir() + "/unit_anisotropy_test.json";
  ASSERT_TRUE(write_unit_parameters(p, path).ok());
  auto on_top = read_unit_model(path, drawn, 0.05);
  ASSERT_TRUE(on_top.ok()) << on_top.error().to_string();
  EXPECT_EQ(on_top->model.spread_u_mm(), p.spread_mm * (1 + 0.05 + p.anisotropy));
  EXPECT_FALSE(read_unit_model(path, drawn, 0.45).ok());  // 0.52 in all: named by the model

  const std::string field = "\"anisotropy\": 0.0712345678901234";
  const std::size_t at = text.find(field);
  ASSERT_NE(at, std::string::npos) << text;
  for (const auto& [bad, want] : std::vector<std::pair<std::string, std::string>>{
           {"\"anisotropy\": 0.5", "anisotropy must be in (-0.5, 0.5)"},
           {"\"anisotropy\": \"0.1\"", "anisotropy is not a number"}}) {
    std::string t = text;
    t.replace(at, field.size(), bad);
    auto e = parse_unit_parameters(t);
    ASSERT_FALSE(e.ok()) << want;
    EXPECT_NE(e.error().message.find(want), std::string::npos) << e.error().message;
  }
}

// The presses' depth zero identification found: absent when 0, exact, and the model reads depth
// from it: a contact depth_zero_mm deeper gives the field, the Jacobian and the force of the same
// unit without one; a contact at the zero presses nothing; one out of range is named.
TEST(UnitParametersFileTest, TheDepthZeroRoundTripsAndTheModelPressesFromIt) {
  UnitParameters p = fabricated_unit();
  EXPECT_EQ(unit_parameters_json(p).find("\"depth_zero_mm\""), std::string::npos);
  const PatchModel plain = PatchModel::from_parameters(PatchDesign{}, p).value();
  p.depth_zero_mm = -0.2468013579;
  auto back = parse_unit_parameters(unit_parameters_json(p));
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_TRUE(same_bits(back->depth_zero_mm, p.depth_zero_mm));
  auto model = PatchModel::of_unit_file(PatchDesign{}, *back);
  ASSERT_TRUE(model.ok()) << model.error().to_string();
  EXPECT_TRUE(same_bits(model->parameters().depth_zero_mm, p.depth_zero_mm));
  const double dz = p.depth_zero_mm;
  const int nc = plain.channel_count();
  for (const double depth_mm : {0.3, 1.7, 3.9}) {
    const Contact c{4.2, -7.5, depth_mm, 5};
    const Contact read{c.u_mm, c.v_mm, depth_mm + dz, 5};
    std::vector<double> want(nc), got(nc), jw(3 * nc), jg(3 * nc);
    plain.contact_field_ut(std::span<const Contact>(&c, 1), want);
    model->contact_field_ut(std::span<const Contact>(&read, 1), got);
    for (int i = 0; i < nc; ++i) EXPECT_NEAR(got[i], want[i], 1e-9 * (1 + std::fabs(want[i])));
    plain.contact_jacobian(c, jw, want);
    model->contact_jacobian(read, jg, got);
    for (int i = 0; i < 3 * nc; ++i) EXPECT_NEAR(jg[i], jw[i], 1e-7 * (1 + std::fabs(jw[i])));
    EXPECT_NEAR(model->force_n(depth_mm + dz), plain.force_n(depth_mm), 1e-12);
  }
  const Contact at_zero{0, 0, dz, 5};
  EXPECT_FALSE(model->presses(at_zero));
  std::vector<double> touched(nc, 1.0);
  model->contact_field_ut(std::span<const Contact>(&at_zero, 1), touched);
  EXPECT_EQ(touched, std::vector<double>(nc, 0.0));  // no field change
  EXPECT_EQ(model->force_n(dz), 0);

  p.depth_zero_mm = 3.5;  // beyond 20 % of the built-in design's 15 mm lattice
  auto far = PatchModel::from_parameters(PatchDesign{}, p);
  ASSERT_FALSE(far.ok());
  EXPECT_NE(far.error().message.find("depth_zero_mm"), std::string::npos) << far.error().message;
}

// read_unit_model: the file modelled on its design's class with the file's creep and its note;
// an anisotropy asked for on top; a file that does not fit the design, or none, named.
TEST(UnitParametersFileTest, AUnitFileIsModelledOnItsDesignsClassWithItsCreep) {
  UnitParameters p = fabricated_unit();
  p.creep_fraction = 0.2;
  p.creep_time_s = 0.5;
  const std::string path = ::testing::TempDir() + "/unit_model_test.json";
  ASSERT_TRUE(write_unit_parameters(p, path, {"test", {}, PressedArea{-1, 1, -2, 2}}).ok());
  PatchDesign design;
  design.anisotropy = 0.1;  // the drawing's: an identified unit's own is in its file
  design.tip_crush_mm = 10;
  auto unit = read_unit_model(path, design);
  ASSERT_TRUE(unit.ok()) << unit.error().to_string();
  EXPECT_EQ(unit->model.design().anisotropy, 0.0);
  EXPECT_EQ(unit->model.design().tip_crush_mm, 0.0);
  EXPECT_EQ(unit->model.design().creep_fraction, 0.2);
  EXPECT_EQ(unit->model.design().creep_time_s, 0.5);
  EXPECT_EQ(unit->note.source, "test");
  ASSERT_TRUE(unit->note.pressed_area.has_value());
  auto on_top = read_unit_model(path, design, 0.05);
  ASSERT_TRUE(on_top.ok());
  EXPECT_EQ(on_top->model.design().anisotropy, 0.05);
  EXPECT_EQ(on_top->model.design().creep_fraction, 0.2);
  UnitParameters fewer = p;
  fewer.magnets.pop_back();
  ASSERT_TRUE(write_unit_parameters(fewer, path).ok());
  auto wrong = read_unit_model(path, design);
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().message.rfind(path + ": ", 0), 0u) << wrong.error().message;
  std::remove(path.c_str());
  auto missing = read_unit_model(path, design);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find(path), std::string::npos);
}

TEST(UnitParametersFileTest, APlausibleFileWithTheWrongCountsIsRefusedByTheModel) {
  UnitParameters p = fabricated_unit();
  p.magnets.pop_back();
  auto back = parse_unit_parameters(unit_parameters_json(p));
  ASSERT_TRUE(back.ok());  // the format is fine; the design does not match
  auto m = PatchModel::from_parameters(PatchDesign{}, *back);
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.error().message.find("magnets"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::sim
