// Measurement model, press plans, datasets (generation and CSV) and the Cramer-Rao bound.
#include "skinbus/sim/dataset.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <optional>

#include "skinbus/sim/crlb.h"

namespace skinbus::sim {
namespace {

SimulatedPatch make_patch(uint64_t noise_seed = 1) {
  return SimulatedPatch(*PatchModel::nominal(PatchDesign{}), noise_seed);
}

std::string temp_path(const char* name) {
  return ::testing::TempDir() + name;
}

TEST(MeasurementTest, NoiseLevelQuantisationAndDeterminism) {
  SimulatedPatch a = make_patch(5), b = make_patch(5);
  std::vector<double> ma(48), mb(48), rest(48);
  a.model().rest_field_ut(rest);
  double sum2 = 0;
  const int n = 4000;
  for (int k = 0; k < n; ++k) {
    a.measure({}, {}, ma);
    b.measure({}, {}, mb);
    ASSERT_EQ(ma, mb);  // same seed, same numbers
    sum2 += (ma[0] - rest[0]) * (ma[0] - rest[0]);
    // Every value is a whole number of LSBs (0.150 uT on x/y at gain 7).
    EXPECT_NEAR(std::remainder(ma[0], 0.15), 0.0, 1e-9);
  }
  const double expected = std::sqrt(a.noise_xy_ut() * a.noise_xy_ut() + 0.15 * 0.15 / 12);
  EXPECT_NEAR(std::sqrt(sum2 / n), expected, 0.08 * expected);
}

TEST(MeasurementTest, AmbientTemperatureAndSaturation) {
  SimulatedPatch p = make_patch();
  std::vector<double> base(48), amb(48);
  p.tare({}, 64, base);
  Environment e;
  e.ambient_ut = {0, 0, 50};
  p.tare(e, 64, amb);
  for (int s = 0; s < 16; ++s)
    EXPECT_NEAR(amb[3 * s + 2] - base[3 * s + 2], 50.0, 0.6);  // flat, nominal: every sensor
  Environment hot;
  hot.temperature_c = 45;
  std::vector<double> warm(48);
  p.tare(hot, 64, warm);
  EXPECT_LT(std::fabs(warm[2]), std::fabs(base[2]));  // -2.4 % remanence at +20 degC
  EXPECT_NEAR(warm[2] / base[2], 1 - 0.0012 * 20, 0.01);
  Environment huge;
  huge.ambient_ut = {1e5, 0, 0};
  std::vector<double> m(48);
  std::vector<uint8_t> sat(16);
  const uint64_t mask = p.measure({}, huge, m, sat);
  EXPECT_EQ(mask, 0xFFFFu);
  for (uint8_t s : sat) EXPECT_TRUE(s);
  for (double x : m) EXPECT_TRUE(std::isfinite(x));
}

TEST(DatasetTest, PressPlans) {
  const auto g = plan_grid(19, 7.5);
  ASSERT_EQ(g.size(), 361u);
  EXPECT_DOUBLE_EQ(g.front().u_mm, -67.5);
  EXPECT_DOUBLE_EQ(g.back().v_mm, 67.5);
  const auto j = plan_jittered_grid(19, 7.5, 0.5, 3);
  for (std::size_t i = 0; i < j.size(); ++i)
    EXPECT_LE(std::fabs(j[i].u_mm - g[i].u_mm), 7.5 * 0.25 + 1e-12);
  const auto h = plan_halton(361, 67.5);
  ASSERT_EQ(h.size(), 361u);
  // Low discrepancy: every 15 x 15 mm cell of the square holds a press.
  int empty = 0;
  for (int cu = 0; cu < 9; ++cu) {
    for (int cv = 0; cv < 9; ++cv) {
      bool any = false;
      for (const auto& p : h)
        any |= p.u_mm >= -67.5 + 15 * cu && p.u_mm < -52.5 + 15 * cu && p.v_mm >= -67.5 + 15 * cv &&
               p.v_mm < -52.5 + 15 * cv;
      empty += !any;
    }
  }
  EXPECT_EQ(empty, 0);
}

// A patch pressed over a rectangle off its centre: the plans fill that rectangle and no more, and
// on the square centred on the patch they are the square plans to the bit.
TEST(DatasetTest, PlansPressTheRectangleTheyAreGiven) {
  const PressedArea area{-90, 70, -20, 40};
  for (const auto& points :
       {plan_halton(400, area), plan_random(400, area, 5), plan_grid(5, 3, 7.5)}) {
    for (const PressPoint& p : points) EXPECT_TRUE(area.contains(p.u_mm, p.v_mm, 0));
  }
  const std::vector<PressPoint> h = plan_halton(400, area);
  // Low discrepancy over the rectangle: each of its 8 x 3 cells of 20 x 20 mm holds a press.
  for (int cu = 0; cu < 8; ++cu) {
    for (int cv = 0; cv < 3; ++cv) {
      bool any = false;
      for (const PressPoint& p : h) {
        any |= p.u_mm >= -90 + 20 * cu && p.u_mm < -70 + 20 * cu && p.v_mm >= -20 + 20 * cv &&
               p.v_mm < 20 * cv;
      }
      EXPECT_TRUE(any) << "cell " << cu << ", " << cv;
    }
  }
  const std::vector<PressPoint> g = plan_grid(5, 3, 7.5);
  ASSERT_EQ(g.size(), 15u);
  EXPECT_DOUBLE_EQ(g.front().u_mm, -15);
  EXPECT_DOUBLE_EQ(g.front().v_mm, -7.5);
  EXPECT_DOUBLE_EQ(g.back().u_mm, 15);
  EXPECT_DOUBLE_EQ(g.back().v_mm, 7.5);
  // The square centred on the patch is the square plans' own, bit for bit.
  const auto same = [](const std::vector<PressPoint>& a, const std::vector<PressPoint>& b) {
    bool equal = a.size() == b.size();
    for (std::size_t i = 0; equal && i < a.size(); ++i)
      equal = a[i].u_mm == b[i].u_mm && a[i].v_mm == b[i].v_mm;
    return equal;
  };
  EXPECT_TRUE(same(plan_halton(100, PressedArea::square(67.5), 3), plan_halton(100, 67.5, 3)));
  EXPECT_TRUE(same(plan_random(100, PressedArea::square(67.5), 9), plan_random(100, 67.5, 9)));

  SimulatedPatch patch = make_patch();
  const Dataset test = generate_random_test_set(patch, 200, area, 3.0, 4);
  for (std::size_t r = 0; r < test.rows(); ++r)
    EXPECT_TRUE(area.contains(test.u_mm[r], test.v_mm[r], 0)) << r;
  EXPECT_NE(test.meta.at("protocol").find("u_mm=-90..70 v_mm=-20..40"), std::string::npos)
      << test.meta.at("protocol");
}

// The area of a dataset's presses: every finite row's (u, v), and none without one.
TEST(DatasetTest, ThePressedAreaHoldsEveryFiniteRow) {
  Dataset d;
  EXPECT_FALSE(pressed_area(d).has_value());
  const double field[1] = {0};
  d.append(0, 0, std::nan(""), 3, 1, 0, field);
  EXPECT_FALSE(pressed_area(d).has_value());
  d.append(0, 0, 2, -1, 1, 0, field);
  d.append(1, 0, -5, 4, 1, 0, field);
  d.append(2, 0, 1, std::numeric_limits<double>::infinity(), 1, 0, field);
  const std::optional<PressedArea> a = pressed_area(d);
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->u_min_mm, -5);
  EXPECT_EQ(a->u_max_mm, 2);
  EXPECT_EQ(a->v_min_mm, -1);
  EXPECT_EQ(a->v_max_mm, 4);
  EXPECT_TRUE(a->contains(-5.5, 4.5, 1.0));
  EXPECT_FALSE(a->contains(-6.5, 0, 1.0));
  EXPECT_FALSE(a->contains(0, -1.5, 0.0));
}

TEST(DatasetTest, RampDatasetKeepsContactSamplesOnly) {
  SimulatedPatch p = make_patch();
  RampProtocol pr;
  const Dataset d = generate_ramp_dataset(p, plan_grid(3, 30), pr);
  // 4 mm at 2 mm/s down and up = 4 s at 41.7 Hz: 166 or 167 samples a press, all in contact.
  EXPECT_GE(d.rows(), 9u * 166);
  EXPECT_LE(d.rows(), 9u * 167);
  for (std::size_t r = 0; r < d.rows(); ++r) {
    EXPECT_GT(d.depth_mm[r], 0);
    EXPECT_LE(d.depth_mm[r], pr.max_depth_mm);
    EXPECT_NEAR(d.force_n[r], p.model().force_n(d.depth_mm[r]), 1e-12);
  }
  for (double x : d.field_ut) ASSERT_TRUE(std::isfinite(x));
  // Deterministic per noise seed.
  SimulatedPatch q = make_patch();
  const Dataset e = generate_ramp_dataset(q, plan_grid(3, 30), pr);
  EXPECT_EQ(d.field_ut, e.field_ut);
  EXPECT_EQ(dataset_fingerprint(d), dataset_fingerprint(e));
}

// A channel stuck at one value over a simulated unit's presses (a chip that stopped converting)
// is found and left out as dead, named; a live channel never is (its noise), nor a channel over
// too few rows to tell, and a dead one (NaN) stays as it is.
TEST(DatasetTest, AStuckChannelIsFoundAndLeftOutAsDead) {
  SimulatedPatch p = make_patch();
  Dataset d = generate_ramp_dataset(p, plan_grid(3, 30), RampProtocol{});
  EXPECT_TRUE(stuck_channels(d).empty());
  EXPECT_EQ(leave_out_stuck_channels(&d), "");
  const std::size_t nc = static_cast<std::size_t>(d.channels());
  for (std::size_t r = 0; r < d.rows(); ++r) {
    for (std::size_t c : {9, 10, 11}) d.field_ut[r * nc + c] = 0;  // sensor 3 stuck at its tare
    d.field_ut[r * nc + 20] = r % 7 == 0 ? std::nan("") : 4.5;     // one reading, some rows dead
    d.field_ut[r * nc + 30] = std::nan("");                        // dead throughout
  }
  EXPECT_EQ(stuck_channels(d), (std::vector<int>{9, 10, 11, 20}));
  const Dataset before = d;
  EXPECT_EQ(leave_out_stuck_channels(&d),
            "s03_bx_ut, s03_by_ut, s03_bz_ut, s06_bz_ut hold one value in every row (a stuck "
            "sensor): left out as dead");
  for (std::size_t r = 0; r < d.rows(); ++r) {
    for (std::size_t c = 0; c < nc; ++c) {
      const bool left_out = c == 9 || c == 10 || c == 11 || c == 20 || c == 30;
      if (left_out) {
        EXPECT_TRUE(std::isnan(d.field_ut[r * nc + c]));
      } else {
        EXPECT_EQ(d.field_ut[r * nc + c], before.field_ut[r * nc + c]);
      }
    }
  }
  EXPECT_TRUE(stuck_channels(d).empty());
  // Fewer rows than kMinStuckRows: nothing can be told.
  Dataset few;
  few.sensors.resize(1);
  const double field[3] = {0, 0, 0};
  for (std::size_t r = 0; r + 1 < kMinStuckRows; ++r) few.append(0, 0, 0, 0, 1, 0, field);
  EXPECT_TRUE(stuck_channels(few).empty());
  few.append(0, 0, 0, 0, 1, 0, field);
  EXPECT_EQ(stuck_channels(few).size(), 3u);
  EXPECT_EQ(field_column_name(0), "s00_bx_ut");
  EXPECT_EQ(field_column_name(47), "s15_bz_ut");
}

// Presses deeper than a model's lattice compresses are taken out whole-row: every column moves
// with its row, the rest keep their order, and the note counts samples and presses.
TEST(DatasetTest, RowsDeeperThanTheLatticeTakesAreLeftOut) {
  Dataset d;
  d.sensors.resize(1);
  d.extra_columns = {"pose"};
  const double depths[] = {1, 2, 3.5, 2.5, 4, 1.5, std::nan("")};
  for (int r = 0; r < 7; ++r) {
    const double field[3] = {10.0 * r, 10.0 * r + 1, 10.0 * r + 2};
    d.append(r / 3, 0.1 * r, r, -r, depths[r], 0.5 * r, field);
    d.extra.push_back(100 + r);
  }
  EXPECT_EQ(leave_out_rows_deeper_than(&d, 3.0),
            "2 of 7 samples (2 presses) deeper than 3.00 mm: left out");
  const std::vector<int> kept = {0, 1, 3, 5, 6};
  ASSERT_EQ(d.rows(), kept.size());
  ASSERT_EQ(d.field_ut.size(), 3 * kept.size());
  ASSERT_EQ(d.extra.size(), kept.size());
  for (std::size_t i = 0; i < kept.size(); ++i) {
    const int r = kept[i];
    EXPECT_EQ(d.press[i], r / 3);
    EXPECT_EQ(d.t_s[i], 0.1 * r);
    EXPECT_EQ(d.u_mm[i], r);
    EXPECT_EQ(d.v_mm[i], -r);
    EXPECT_EQ(d.force_n[i], 0.5 * r);
    EXPECT_EQ(d.field(i)[2], 10.0 * r + 2);
    EXPECT_EQ(d.extra[i], 100 + r);
  }
  EXPECT_TRUE(std::isnan(d.depth_mm.back()));  // an unknown depth is not known to be deeper
  EXPECT_EQ(leave_out_rows_deeper_than(&d, 3.0), "");
  // The lattice's rule: a 5 mm lattice stops a press at 3 mm, the tools keep to 2.7 (plus a
  // unit's depth zero), and say why.
  PatchDesign thin;
  thin.thickness_mm = 5;
  EXPECT_EQ(leave_out_presses_past_the_lattice(&d, thin), "");  // 2.5 mm is within 2.7
  EXPECT_EQ(leave_out_presses_past_the_lattice(&d, thin, -0.3),
            "1 of 5 samples (1 presses) deeper than 2.40 mm: left out, 10 % short of where the "
            "design's 5 mm lattice stops a press in the model (3.00 mm, 0.6 x thickness_mm)");
  EXPECT_EQ(d.rows(), 4u);
}

// The tip a recording's presses were made with: its protocol header's, written by every
// generator and read back through the CSV, else the design's indenter; a bad value is an error.
TEST(DatasetTest, TheRecordingsTipIsReadFromItsProtocolHeader) {
  SimulatedPatch p = make_patch();
  RampProtocol pr;
  pr.tip_radius_mm = 3.25;
  const Dataset ramps = generate_ramp_dataset(p, plan_grid(2, 30), pr);
  const Dataset statics = generate_random_test_set(p, 4, 30, 3, 7, {}, 32, 0);
  const std::string path = temp_path("tip_header.csv");
  ASSERT_TRUE(write_dataset_csv(ramps, path).ok());
  Result<Dataset> back = read_dataset_csv(path);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  std::remove(path.c_str());
  PatchDesign design;
  design.indenter_tip_radius_mm = 8;
  std::string from;
  Result<double> tip = presses_tip_radius_mm(*back, design, &from);
  ASSERT_TRUE(tip.ok()) << tip.error().to_string();
  EXPECT_EQ(*tip, 3.25);
  EXPECT_EQ(from, "the recording's protocol header");
  tip = presses_tip_radius_mm(statics, design, &from);
  ASSERT_TRUE(tip.ok());
  EXPECT_EQ(*tip, 0.0);  // a point tip, said so
  // A lab recording that does not say: the design's indenter.
  Dataset lab = ramps;
  lab.meta.erase("protocol");
  tip = presses_tip_radius_mm(lab, design, &from);
  ASSERT_TRUE(tip.ok());
  EXPECT_EQ(*tip, 8.0);
  EXPECT_EQ(from, "the design's indenter");
  lab.meta["protocol"] = "ramp by hand, max_tip_radius_mm=9";  // another key holds the name
  ASSERT_TRUE(presses_tip_radius_mm(lab, design).ok());
  EXPECT_EQ(*presses_tip_radius_mm(lab, design), 8.0);
  for (const char* bad : {"ramp tip_radius_mm=", "ramp tip_radius_mm=5mm presses=3",
                          "ramp tip_radius_mm=-1", "ramp tip_radius_mm=nan", "tip_radius_mm=51"}) {
    lab.meta["protocol"] = bad;
    Result<double> r = presses_tip_radius_mm(lab, design);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_NE(r.error().message.find("protocol header: tip_radius_mm="), std::string::npos)
        << r.error().message;
  }
  lab.meta["protocol"] = "tip_radius_mm=2.5";  // the key may start the line
  ASSERT_TRUE(presses_tip_radius_mm(lab, design).ok());
  EXPECT_EQ(*presses_tip_radius_mm(lab, design), 2.5);
  lab.meta["protocol"] = "ramp\ttip_radius_mm=3\tpresses=4";  // or follow a tab
  ASSERT_TRUE(presses_tip_radius_mm(lab, design).ok());
  EXPECT_EQ(*presses_tip_radius_mm(lab, design), 3.0);
}

// A recording's sensors against the design's: the same layout passes (a fabricated unit's
// positions scatter by a tenth of a millimetre), another order or another patch is named, a
// recording without positions is not judged.
TEST(DatasetTest, ARecordingsSensorLayoutIsCheckedAgainstTheDesign) {
  const PatchModel nominal = *PatchModel::nominal(PatchDesign{});
  SimulatedPatch fabricated(*PatchModel::fabricated(PatchDesign{}, 0x5B01, {}), 1);
  Dataset d = generate_ramp_dataset(fabricated, plan_grid(2, 30), RampProtocol{});
  const std::string path = temp_path("layout.csv");
  ASSERT_TRUE(write_dataset_csv(d, path).ok());
  Result<Dataset> back = read_dataset_csv(path);
  std::remove(path.c_str());
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_TRUE(back->sensor_layout_known);
  EXPECT_TRUE(check_sensor_layout(*back, nominal).ok());
  Dataset swapped = *back;
  std::swap(swapped.sensors[1], swapped.sensors[4]);  // listed column by column, say
  const Status s = check_sensor_layout(swapped, nominal);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("sensor 1 is at u_mm=-45.0 v_mm=-14.9"), std::string::npos)
      << s.error().message;
  PatchDesign wider;
  wider.sensor_pitch_mm = 34;
  EXPECT_FALSE(check_sensor_layout(*back, *PatchModel::nominal(wider)).ok());
  PatchDesign more;
  more.sensors_u = more.sensors_v = 3;
  EXPECT_FALSE(check_sensor_layout(*back, *PatchModel::nominal(more)).ok());
  swapped.sensor_layout_known = false;  // a lab recording without `sensor <i>:` lines
  EXPECT_TRUE(check_sensor_layout(swapped, nominal).ok());

  // The surface: a cylinder's recording against the flat design and the reverse, or another
  // radius, is named; the same cylinder passes.
  PatchDesign limb;
  limb.surface = SurfaceKind::kCylinder;
  limb.radius_mm = 45;
  const PatchModel on_limb = *PatchModel::nominal(limb);
  SimulatedPatch limb_patch(on_limb, 2);
  const Dataset rolled = generate_ramp_dataset(limb_patch, plan_grid(2, 30), RampProtocol{});
  EXPECT_TRUE(check_sensor_layout(rolled, on_limb).ok());
  const Status flat_design = check_sensor_layout(rolled, nominal);
  ASSERT_FALSE(flat_design.ok());
  EXPECT_NE(flat_design.error().message.find("cylinder radius_mm=45"), std::string::npos)
      << flat_design.error().message;
  EXPECT_FALSE(check_sensor_layout(*back, on_limb).ok());
  limb.radius_mm = 60;
  const Status other = check_sensor_layout(rolled, *PatchModel::nominal(limb));
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.error().message.find("radius 45 mm, the design 60 mm"), std::string::npos)
      << other.error().message;
}

// Creep (PatchDesign::creep_fraction): the plate lags the press, so a ramp bends it less than
// the press is deep while loading and more while unloading: the same rows as without creep, the
// same recorded depths, a weaker field going down and a stronger one coming up (once the lag has
// overtaken the press: below 2.5 mm at 2 mm/s, 2.5 time constants after the turn).
TEST(DatasetTest, CreepBendsThePlateLessLoadingThanUnloading) {
  PatchDesign creeping;
  creeping.creep_fraction = 0.3;
  creeping.creep_time_s = 0.3;
  SimulatedPatch plain = make_patch(), lagging(*PatchModel::nominal(creeping), 1);
  RampProtocol pr;
  const Dataset a = generate_ramp_dataset(plain, plan_grid(3, 30), pr);
  const Dataset b = generate_ramp_dataset(lagging, plan_grid(3, 30), pr);
  ASSERT_EQ(a.rows(), b.rows());
  EXPECT_EQ(a.depth_mm, b.depth_mm);
  EXPECT_EQ(a.force_n, b.force_n);
  const auto nc = static_cast<std::size_t>(a.channels());
  int loading = 0, loading_weaker = 0, unloading = 0, unloading_stronger = 0;
  for (std::size_t r = 1; r + 1 < a.rows(); ++r) {
    if (a.depth_mm[r] < 1.0 || a.press[r - 1] != a.press[r] || a.press[r + 1] != a.press[r]) {
      continue;
    }
    double na = 0, nb = 0;
    for (std::size_t c = 0; c < nc; ++c) {
      na += a.field_ut[r * nc + c] * a.field_ut[r * nc + c];
      nb += b.field_ut[r * nc + c] * b.field_ut[r * nc + c];
    }
    if (a.depth_mm[r + 1] > a.depth_mm[r] && a.depth_mm[r - 1] < a.depth_mm[r]) {
      ++loading;
      loading_weaker += nb < na;
    } else if (a.depth_mm[r + 1] < a.depth_mm[r] && a.depth_mm[r - 1] > a.depth_mm[r] &&
               a.depth_mm[r] < 2.5) {
      ++unloading;
      unloading_stronger += nb > na;
    }
  }
  std::printf("loading: %d of %d rows weaker; unloading: %d of %d stronger\n", loading_weaker,
              loading, unloading_stronger, unloading);
  EXPECT_GT(loading, 300);
  EXPECT_GT(unloading, 150);
  EXPECT_GE(loading_weaker, loading * 95 / 100);
  EXPECT_GE(unloading_stronger, unloading * 95 / 100);
  // Without creep the design's time constant changes nothing.
  PatchDesign slow;
  slow.creep_time_s = 5;
  SimulatedPatch still(*PatchModel::nominal(slow), 1);
  EXPECT_EQ(generate_ramp_dataset(still, plan_grid(3, 30), pr).field_ut, a.field_ut);
}

// A press held at its deepest (RampProtocol::hold_s): its rows stay at the deepest for the hold,
// in time order, and the lattice's lag relaxes there: the field comes to a unit's that does not
// creep (the same noise draws), where it was apart at the hold's start.
TEST(DatasetTest, AHeldPressStaysAtItsDeepestWhileTheLatticeRelaxes) {
  RampProtocol pr;
  pr.hold_s = 2;
  auto press = [&](double f) {
    PatchDesign d;
    d.creep_fraction = f;
    d.creep_time_s = 0.5;
    SimulatedPatch p(*PatchModel::nominal(d), 1);
    return generate_ramp_dataset(p, plan_grid(1, 10), pr);
  };
  const Dataset creeping = press(0.3), plain = press(0);
  EXPECT_NE(creeping.meta.at("protocol").find(" hold_s=2"), std::string::npos);
  ASSERT_EQ(creeping.rows(), plain.rows());
  std::vector<std::size_t> held;
  for (std::size_t r = 0; r < creeping.rows(); ++r) {
    if (r > 0) {
      EXPECT_GT(creeping.t_s[r], creeping.t_s[r - 1]);
    }
    if (creeping.depth_mm[r] == pr.max_depth_mm) held.push_back(r);
  }
  // 2 s at 41.7 Hz, in one run of rows.
  ASSERT_GE(held.size(), 82u);
  EXPECT_LE(held.size(), 84u);
  EXPECT_EQ(held.back() - held.front() + 1, held.size());
  const auto nc = static_cast<std::size_t>(creeping.channels());
  auto apart = [&](std::size_t r) {
    double s2 = 0;
    for (std::size_t c = 0; c < nc; ++c) {
      const double x = creeping.field_ut[r * nc + c] - plain.field_ut[r * nc + c];
      s2 += x * x;
    }
    return std::sqrt(s2);
  };
  std::printf(
      "field apart from the unit that does not creep: %.2f uT at the hold's start, %.3f uT "
      "at its end\n",
      apart(held.front()), apart(held.back()));
  // The lag left falls from 0.3 mm to 0.3 exp(-4) mm over the hold; what is left apart at its
  // end is the chips' quantisation (a step or two of 0.15-0.24 uT).
  EXPECT_GT(apart(held.front()), 1.0);
  EXPECT_LT(apart(held.back()), 0.3 * apart(held.front()));
  // Without a hold, the protocol is as it was: no hold in the header, the hold's rows fewer.
  pr.hold_s = 0;
  const Dataset ramp = press(0.3);
  EXPECT_EQ(ramp.meta.at("protocol").find("hold_s"), std::string::npos);
  EXPECT_NEAR(static_cast<double>(creeping.rows() - ramp.rows()), static_cast<double>(held.size()),
              1.0);
}

// A second, slower lag (PatchDesign::creep_slow_fraction) is the same law with its own time
// constant, added: alone it is the first lag's twin, and with the first the plate bends by both.
TEST(DatasetTest, ASlowSecondLagIsTheSameLawAdded) {
  RampProtocol pr;
  auto ramps = [&](double f, double tau, double f_slow, double tau_slow) {
    PatchDesign d;
    d.creep_fraction = f;
    d.creep_time_s = tau;
    d.creep_slow_fraction = f_slow;
    d.creep_slow_time_s = tau_slow;
    SimulatedPatch p(*PatchModel::nominal(d), 1);
    return generate_ramp_dataset(p, plan_grid(3, 30), pr);
  };
  const Dataset fast = ramps(0.2, 0.3, 0, 3);
  EXPECT_EQ(ramps(0, 3, 0.2, 0.3).field_ut, fast.field_ut);  // twins
  const Dataset both = ramps(0.2, 0.3, 0.15, 3), slow = ramps(0, 0.3, 0.15, 3);
  const Dataset plain = ramps(0, 0.3, 0, 3);
  ASSERT_EQ(both.rows(), fast.rows());
  EXPECT_EQ(both.depth_mm, fast.depth_mm);
  // Over the rows >= 1 mm: the field's change from the plain unit's against the two lags' own
  // changes summed. The field is nearly linear in a small change of the bend, so the sum holds to
  // a few percent of the change (4.3 % measured); were either lag left out of the pair, it would
  // miss by that lag's whole share (a third or more).
  const auto nc = static_cast<std::size_t>(both.channels());
  double change = 0, miss = 0;
  int rows = 0;
  for (std::size_t r = 0; r < both.rows(); ++r) {
    if (both.depth_mm[r] < 1.0) continue;
    ++rows;
    for (std::size_t c = 0; c < nc; ++c) {
      const std::size_t i = r * nc + c;
      const double d_both = both.field_ut[i] - plain.field_ut[i];
      const double d_fast = fast.field_ut[i] - plain.field_ut[i];
      const double d_slow = slow.field_ut[i] - plain.field_ut[i];
      change += d_both * d_both;
      miss += (d_both - d_fast - d_slow) * (d_both - d_fast - d_slow);
    }
  }
  const double ratio = std::sqrt(miss / change);
  std::printf("%d rows: the lags' summed changes miss the pair's by %.2f %% (RMS)\n", rows,
              100 * ratio);
  EXPECT_GT(rows, 100);
  EXPECT_GT(change, 0);
  EXPECT_LT(ratio, 0.1);
  // Each lag on its own makes every loading row >= 1 mm weaker, and the pair weaker still.
  int loading = 0, ordered = 0;
  auto norm = [nc](const Dataset& d, std::size_t r) {
    double n = 0;
    for (std::size_t c = 0; c < nc; ++c) n += d.field_ut[r * nc + c] * d.field_ut[r * nc + c];
    return n;
  };
  for (std::size_t r = 1; r + 1 < both.rows(); ++r) {
    if (both.depth_mm[r] < 1.0 || both.press[r - 1] != both.press[r] ||
        both.press[r + 1] != both.press[r] || !(both.depth_mm[r + 1] > both.depth_mm[r])) {
      continue;
    }
    ++loading;
    const double p = norm(plain, r), b = norm(both, r);
    ordered += norm(fast, r) < p && norm(slow, r) < p && b < norm(fast, r) && b < norm(slow, r);
  }
  EXPECT_GT(loading, 300);
  EXPECT_GE(ordered, loading * 95 / 100) << ordered << " of " << loading;
}

TEST(DatasetTest, CsvRoundTrip) {
  SimulatedPatch p = make_patch();
  Dataset d = generate_random_test_set(p, 50, 65, 4, 9);
  d.meta["unit_uid"] = "0x1234";
  const std::string path = temp_path("roundtrip.csv");
  ASSERT_TRUE(write_dataset_csv(d, path).ok());
  auto r = read_dataset_csv(path);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  ASSERT_EQ(r->rows(), d.rows());
  ASSERT_EQ(r->sensors.size(), 16u);
  EXPECT_EQ(r->meta.at("unit_uid"), "0x1234");
  EXPECT_EQ(r->meta.at("format"), "skinbus-dataset 1");
  EXPECT_NEAR(r->sensors[5].u_mm, d.sensors[5].u_mm, 1e-9);
  for (std::size_t i = 0; i < d.field_ut.size(); ++i)
    EXPECT_NEAR(r->field_ut[i], d.field_ut[i], 1e-6 * (1 + std::fabs(d.field_ut[i])));
  for (std::size_t i = 0; i < d.rows(); ++i) EXPECT_NEAR(r->depth_mm[i], d.depth_mm[i], 1e-8);
}

void write_file(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

TEST(DatasetTest, OtherSkinsAndLabColumns) {
  // A lab recording of a 3-sensor skin with the robot's pose as extra columns, no header block.
  const std::string path = temp_path("lab.csv");
  write_file(path,
             "# source: lab indenter\n"
             "u_mm,v_mm,depth_mm,robot_z_mm,s0_bx_ut,s0_by_ut,s0_bz_ut,s1_bx_ut,s1_by_ut,s1_bz_ut,"
             "s2_bx_ut,s2_by_ut,s2_bz_ut\n"
             "1,2,0.5,100.5,1,2,3,4,5,6,7,8,9\n"
             "1,2,1.0,100.0,1,2,3,4,5,nan,7,8,9\n");
  auto r = read_dataset_csv(path);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  EXPECT_EQ(r->channels(), 9);
  ASSERT_EQ(r->extra_columns, std::vector<std::string>{"robot_z_mm"});
  EXPECT_DOUBLE_EQ(r->extra[1], 100.0);
  EXPECT_TRUE(std::isnan(r->field(1)[5]));  // a dead channel stays visible as NaN
  EXPECT_EQ(r->meta.at("source"), "lab indenter");
}

TEST(DatasetTest, CorruptFilesGetClearErrors) {
  struct Case {
    std::string text;
    const char* expect;
  };
  const Case cases[] = {
      {"", "no column header"},
      {"u_mm,v_mm,depth_mm\n1,2,3\n", "no sensor columns"},
      {"u_mm,v_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5\n", "missing one of the columns"},
      {"u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5\n", ":2: row has 5 fields"},
      {"u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5,6\n1,x,3,4,5,6\n",
       ":3: bad number in u_mm"},
      {"u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,inf,6\n", "infinite value"},
      {"u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut\n1,2,3,4,5\n", "each with bx, by and bz"},
      {"# sensors: 2\nu_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5,6\n",
       "header says 2 sensors"},
      {"# format: skinbus-dataset 7\nu_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5,6\n",
       "unsupported format"},
      {"u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n", "no data rows"},
      {"u_mm,u_mm2,v_mm,depth_mm,s0_bx_ut,s0_bx_ut,s0_by_ut,s0_bz_ut\n",
       "column 's0_bx_ut' (column 6) repeats column 5"},
      // A repeated label column would replace the first silently (the docs say: refused).
      {"u_mm,v_mm,depth_mm,u_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5,6,7\n",
       ":1: column 'u_mm' (column 4) repeats column 1"},
      {"x_mm,v_mm,depth_mm,u_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5,6,7\n",
       "column 'u_mm' (column 4) repeats column 1 ('x_mm')"},
      {"u_mm,v_mm,depth_mm,lab,s0_bx_ut,s0_by_ut,s0_bz_ut,lab\n1,2,3,4,5,6,7,8\n",
       "column 'lab' (column 8) repeats column 4"},
      {"# a comment\nu_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5," +
           std::string(2 << 20, '6') + "\n",
       ":3: longer than 1048576 bytes"},
  };
  int i = 0;
  for (const Case& c : cases) {
    const std::string path = temp_path(("bad" + std::to_string(i++) + ".csv").c_str());
    write_file(path, c.text);
    auto r = read_dataset_csv(path);
    ASSERT_FALSE(r.ok()) << c.text;
    EXPECT_NE(r.error().message.find(c.expect), std::string::npos) << r.error().message;
  }
  auto missing = read_dataset_csv("/nonexistent/skinbus.csv");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  auto dir = read_dataset_csv("/tmp");
  ASSERT_FALSE(dir.ok());
  EXPECT_NE(dir.error().message.find("is a directory"), std::string::npos);
}

// A byte-order mark (spreadsheets write one) is not part of the first column's name: with it,
// `press` became an unknown column and every sample its own press.
TEST(DatasetTest, AByteOrderMarkIsSkipped) {
  const std::string path = temp_path("bom.csv");
  write_file(path,
             "\xEF\xBB\xBFpress,u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n"
             "7,1,2,3,4,5,6\n7,1,2,3.5,4,5,6\n");
  auto r = read_dataset_csv(path);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_TRUE(r->extra_columns.empty());
  EXPECT_EQ(r->press, (std::vector<int64_t>{7, 7}));
  // Also before a header block.
  write_file(path,
             "\xEF\xBB\xBF# format: skinbus-dataset 1\n"
             "u_mm,v_mm,depth_mm,s0_bx_ut,s0_by_ut,s0_bz_ut\n1,2,3,4,5,6\n");
  auto h = read_dataset_csv(path);
  ASSERT_TRUE(h.ok()) << h.error().message;
  EXPECT_EQ(h->meta.at("format"), "skinbus-dataset 1");
}

TEST(CrlbTest, SmallMatrixInverse) {
  double a[9] = {4, 1, 0, 1, 3, 1, 0, 1, 2};
  const double orig[9] = {4, 1, 0, 1, 3, 1, 0, 1, 2};
  ASSERT_TRUE(invert_small(a, 3));
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      double s = 0;
      for (int k = 0; k < 3; ++k) s += orig[r * 3 + k] * a[k * 3 + c];
      EXPECT_NEAR(s, r == c ? 1 : 0, 1e-12);
    }
  }
  double sing[4] = {1, 2, 2, 4};
  EXPECT_FALSE(invert_small(sing, 2));
}

TEST(CrlbTest, BoundScalesWithNoiseAndFlagsNoInformation) {
  const PatchModel m = *PatchModel::nominal(PatchDesign{});
  const Contact c{7, -3, 2};
  const CrlbPoint a = crlb_at(m, c, 0.8, 1.3);
  const CrlbPoint b = crlb_at(m, c, 0.4, 0.65);
  ASSERT_TRUE(a.identifiable);
  EXPECT_GT(a.sd_xy_mm, 0);
  EXPECT_LT(a.sd_xy_mm, 1.0);
  EXPECT_NEAR(b.sd_xy_mm / a.sd_xy_mm, 0.5, 1e-9);  // linear in the noise
  EXPECT_NEAR(b.sd_depth_mm / a.sd_depth_mm, 0.5, 1e-9);
  const CrlbPoint amb = crlb_at(m, c, 0.8, 1.3, true);
  EXPECT_GE(amb.sd_xy_mm, a.sd_xy_mm * (1 - 1e-9));  // a nuisance never helps
  const CrlbPoint off = crlb_at(m, Contact{400, 0, 2}, 0.8, 1.3);
  EXPECT_FALSE(off.identifiable);
  EXPECT_EQ(off.sd_xy_mm, kUnidentifiableMm);
  // Deeper presses are localised better.
  EXPECT_LT(crlb_at(m, Contact{7, -3, 4}, 0.8, 1.3).sd_xy_mm,
            crlb_at(m, Contact{7, -3, 1}, 0.8, 1.3).sd_xy_mm);
}

TEST(CrlbTest, TwoContactsFarApartAreBoundAsEachAlone) {
  const PatchModel m = *PatchModel::nominal(PatchDesign{});
  // 100 mm apart: each contact's field is its own; the pair's bound is each single bound (to the
  // finite differences' precision).
  const Contact a{-50, 10, 2, 5}, b{50, -10, 3, 5};
  for (bool ambient : {false, true}) {
    const CrlbPair pair = crlb_pair_at(m, a, b, 0.8, 1.3, ambient);
    const CrlbPoint one = crlb_at(m, a, 0.8, 1.3, ambient), two = crlb_at(m, b, 0.8, 1.3, ambient);
    ASSERT_TRUE(pair.first.identifiable && pair.second.identifiable);
    EXPECT_NEAR(pair.first.sd_xy_mm / one.sd_xy_mm, 1, 0.02) << ambient;
    EXPECT_NEAR(pair.second.sd_xy_mm / two.sd_xy_mm, 1, 0.02) << ambient;
    EXPECT_NEAR(pair.first.sd_depth_mm / one.sd_depth_mm, 1, 0.02) << ambient;
  }
}

TEST(CrlbTest, TwoContactsCostMoreTheCloserTheyAreAndCoincidentOnesHaveNoBound) {
  const PatchModel m = *PatchModel::nominal(PatchDesign{});
  double previous = 0;
  for (double separation : {60.0, 30.0, 15.0}) {
    const CrlbPair pair = crlb_pair_at(m, Contact{-separation / 2, 5, 2, 5},
                                       Contact{separation / 2, 5, 2, 5}, 0.8, 1.3);
    ASSERT_TRUE(pair.first.identifiable) << separation;
    EXPECT_GT(pair.first.sd_xy_mm, previous) << separation;
    previous = pair.first.sd_xy_mm;
  }
  const Contact c{7, -3, 2, 5};
  const CrlbPair same = crlb_pair_at(m, c, c, 0.8, 1.3);
  EXPECT_FALSE(same.first.identifiable);
  EXPECT_FALSE(same.second.identifiable);
  EXPECT_EQ(same.first.sd_xy_mm, kUnidentifiableMm);
  const CrlbPair nan = crlb_pair_at(m, Contact{std::nan(""), 0, 2, 5}, c, 0.8, 1.3);
  EXPECT_FALSE(nan.first.identifiable);
  EXPECT_EQ(nan.second.sd_depth_mm, kUnidentifiableMm);
  const CrlbPair off = crlb_pair_at(m, c, Contact{400, 0, 2, 5}, 0.8, 1.3);  // one out of reach
  EXPECT_FALSE(off.first.identifiable);
}

TEST(CrlbTest, ThreeContactsCostEachOtherAndCoincidentOnesHaveNoBound) {
  const PatchModel m = *PatchModel::nominal(PatchDesign{});
  // One contact: the single bound; two: the pair's (the same Fisher information, exact Jacobian).
  const Contact a{-30, -20, 2, 5}, b{30, -20, 3, 5}, c{0, 35, 2.5, 5};
  CrlbPoint out[3];
  crlb_contacts_at(m, std::span<const Contact>(&a, 1), 0.8, 1.3, true, out);
  EXPECT_NEAR(out[0].sd_xy_mm / crlb_at(m, a, 0.8, 1.3, true).sd_xy_mm, 1, 1e-6);
  const Contact ab[2] = {a, b}, abc[3] = {a, b, c};
  crlb_contacts_at(m, ab, 0.8, 1.3, true, out);
  const CrlbPoint pair_a = out[0];
  crlb_contacts_at(m, abc, 0.8, 1.3, true, out);
  for (const CrlbPoint& p : out) ASSERT_TRUE(p.identifiable);
  // A third press can only cost the first two, and a closer one costs more.
  EXPECT_GE(out[0].sd_xy_mm, pair_a.sd_xy_mm * (1 - 1e-9));
  const double far = out[0].sd_xy_mm;
  const Contact closer[3] = {a, b, {-15, -5, 2.5, 5}};
  crlb_contacts_at(m, closer, 0.8, 1.3, true, out);
  EXPECT_GT(out[0].sd_xy_mm, far);
  // Two of the three at one place: no bound for any, never NaN; nor for bad input.
  const Contact same[3] = {a, b, b};
  crlb_contacts_at(m, same, 0.8, 1.3, true, out);
  for (const CrlbPoint& p : out) {
    EXPECT_FALSE(p.identifiable);
    EXPECT_EQ(p.sd_xy_mm, kUnidentifiableMm);
  }
  const Contact bad[3] = {a, b, {0, std::nan(""), 2, 5}};
  crlb_contacts_at(m, bad, 0.8, 1.3, true, out);
  EXPECT_FALSE(out[2].identifiable);
  EXPECT_EQ(out[0].sd_depth_mm, kUnidentifiableMm);
  const Contact four[4] = {a, b, c, c};
  CrlbPoint out4[4];
  crlb_contacts_at(m, four, 0.8, 1.3, true, out4);  // more than kCrlbMaxContacts
  for (const CrlbPoint& p : out4) EXPECT_FALSE(p.identifiable);
  crlb_contacts_at(m, abc, 0.8, 1.3, true, std::span<CrlbPoint>(out, 2));  // `out` too short
  EXPECT_FALSE(out[0].identifiable);
}

TEST(CrlbTest, ShearBoundScalesWithNoiseAndStiffnessAndCostsThePosition) {
  PatchDesign design;
  const PatchModel m = *PatchModel::nominal(design);
  design.shear_stiffness_n_per_mm *= 2;
  const PatchModel stiff = *PatchModel::nominal(design);
  for (const Contact c : {Contact{-41, -44, 2.5, 5.0}, Contact{7, -3, 1.0, 5.0, 0.3, 0.1}}) {
    const CrlbShear s = crlb_shear_at(m, c, 0.8, 1.3, true);
    ASSERT_TRUE(s.identifiable);
    EXPECT_GT(s.sd_shear_n, 0.0);
    EXPECT_LT(s.sd_shear_n, 1.0);  // N: a finger's drag is told from none
    EXPECT_NEAR(s.sd_shear_n * s.sd_shear_n,
                s.sd_shear_u_n * s.sd_shear_u_n + s.sd_shear_v_n * s.sd_shear_v_n, 1e-12);
    // Not knowing the shear can only cost the position.
    const CrlbPoint known = crlb_at(m, c, 0.8, 1.3, true);
    EXPECT_GE(s.contact.sd_xy_mm, known.sd_xy_mm * (1 - 1e-9));
    EXPECT_GE(s.contact.sd_depth_mm, known.sd_depth_mm * (1 - 1e-9));
    // The bound is linear in the noise; a stiffer lattice moves less per newton.
    const CrlbShear twice = crlb_shear_at(m, c, 1.6, 2.6, true);
    EXPECT_NEAR(twice.sd_shear_n / s.sd_shear_n, 2.0, 1e-9);
    const CrlbShear stiffer = crlb_shear_at(stiff, c, 0.8, 1.3, true);
    EXPECT_GT(stiffer.sd_shear_n / s.sd_shear_n, 1.8);
  }
  EXPECT_FALSE(crlb_shear_at(m, Contact{400, 0, 2, 5}, 0.8, 1.3).identifiable);
  const CrlbShear nan = crlb_shear_at(m, Contact{0, 0, 2, 5, std::nan("")}, 0.8, 1.3);
  EXPECT_FALSE(nan.identifiable);
  EXPECT_EQ(nan.sd_shear_n, kUnidentifiableN);
  EXPECT_EQ(nan.contact.sd_xy_mm, kUnidentifiableMm);
}

TEST(CrlbTest, TwoShearedContactsFarApartAreBoundAsEachAlone) {
  const PatchModel m = *PatchModel::nominal(PatchDesign{});
  const Contact a{-50, 10, 2, 5, 0.4, -0.2}, b{50, -10, 3, 5, -0.3, 0.5};
  for (bool ambient : {false, true}) {
    const CrlbPairShear pair = crlb_pair_shear_at(m, a, b, 0.8, 1.3, ambient);
    const CrlbShear one = crlb_shear_at(m, a, 0.8, 1.3, ambient),
                    two = crlb_shear_at(m, b, 0.8, 1.3, ambient);
    ASSERT_TRUE(pair.first.identifiable && pair.second.identifiable);
    // 100 mm apart the presses barely share sensors; the ambient is shared by both (cost < 5 %).
    EXPECT_NEAR(pair.first.sd_shear_n / one.sd_shear_n, 1, 0.05) << ambient;
    EXPECT_NEAR(pair.second.sd_shear_n / two.sd_shear_n, 1, 0.05) << ambient;
    EXPECT_NEAR(pair.first.contact.sd_xy_mm / one.contact.sd_xy_mm, 1, 0.05) << ambient;
    EXPECT_GE(pair.first.sd_shear_n, one.sd_shear_n * (1 - 1e-9));  // a second press never helps
  }
  // Closer, the second press costs the first; coincident or non-finite: no bound, never NaN.
  const CrlbPairShear near =
      crlb_pair_shear_at(m, Contact{-8, 5, 2, 5}, Contact{8, 5, 2, 5}, 0.8, 1.3, true);
  const CrlbShear alone = crlb_shear_at(m, Contact{-8, 5, 2, 5}, 0.8, 1.3, true);
  ASSERT_TRUE(near.first.identifiable);
  EXPECT_GT(near.first.sd_shear_n, 1.1 * alone.sd_shear_n);
  const Contact c{7, -3, 2, 5};
  EXPECT_FALSE(crlb_pair_shear_at(m, c, c, 0.8, 1.3).first.identifiable);
  const CrlbPairShear nan =
      crlb_pair_shear_at(m, Contact{0, 0, 2, 5, std::nan("")}, Contact{30, 0, 2, 5}, 0.8, 1.3);
  EXPECT_FALSE(nan.second.identifiable);
  EXPECT_EQ(nan.second.sd_shear_n, kUnidentifiableN);
}

}  // namespace
}  // namespace skinbus::sim
