// Baseline, drift tracking and contact gating: on synthetic fields and on the patch physics.
#include "skinbus/patch_fw/gate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "skinbus/sim/design_file.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/rng.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::patch_fw {
namespace {

constexpr uint64_t kPeriodUs = 23981;  // 41.7 Hz

// A patch at rest: sensor i reads a fixed field plus noise; `press` adds a local bump.
struct Synthetic {
  sim::Rng rng{7};
  uint64_t t_us = 1000;
  double ambient[3] = {0, 0, 0};
  double drift_per_sensor[16] = {};  // added to x
  double press_ut = 0;               // on sensors 5, 6 (z), half on their neighbours
  double noise_ut = 1.0;
  uint16_t faults = 0;

  ArraySample next() {
    ArraySample s;
    s.timestamp_us = t_us;
    t_us += kPeriodUs;
    for (int i = 0; i < 16; ++i) {
      for (int a = 0; a < 3; ++a) {
        double v = 50.0 * ((i + a) % 5) - 100 + ambient[a] + noise_ut * rng.normal();
        if (a == 0) v += drift_per_sensor[i];
        if (a == 2 && (i == 5 || i == 6)) v += press_ut;
        if (a == 2 && (i == 1 || i == 9 || i == 10)) v += 0.5 * press_ut;
        s.field_ut[3 * i + a] = v;
      }
    }
    s.fault_mask = faults;
    return s;
  }
};

TEST(GateTest, TareThenContactWithHysteresis) {
  ContactGate gate;
  Synthetic syn;
  GateOutput out;
  for (int k = 0; k < gate.config().tare_samples; ++k) {
    gate.update(syn.next(), &out);
    EXPECT_EQ(out.tare_active, k + 1 < gate.config().tare_samples);
    EXPECT_FALSE(out.contact);
  }
  EXPECT_TRUE(out.tared);
  EXPECT_EQ(out.unbased_mask, 0);
  for (int k = 0; k < 100; ++k) {
    gate.update(syn.next(), &out);
    ASSERT_FALSE(out.contact) << "noise alone must not gate on, score " << out.score_ut;
  }
  EXPECT_LT(out.score_ut, gate.config().off_threshold_ut);
  syn.press_ut = 30;
  gate.update(syn.next(), &out);
  EXPECT_TRUE(out.contact);  // one sample of latency at most
  EXPECT_NEAR(out.tared_ut[3 * 5 + 2], 30, 5);
  // Between the thresholds: stays on.
  syn.press_ut = 0.5 * (gate.config().on_threshold_ut + gate.config().off_threshold_ut);
  for (int k = 0; k < 20; ++k) {
    gate.update(syn.next(), &out);
    EXPECT_TRUE(out.contact);
  }
  // Released: off after off_samples samples below the off threshold.
  syn.press_ut = 0;
  for (int k = 0; k < gate.config().off_samples - 1; ++k) {
    gate.update(syn.next(), &out);
    EXPECT_TRUE(out.contact);
  }
  gate.update(syn.next(), &out);
  EXPECT_FALSE(out.contact);
}

TEST(GateTest, SustainedPressIsNeverAbsorbed) {
  ContactGate gate;
  Synthetic syn;
  GateOutput out;
  for (int k = 0; k < 100; ++k) gate.update(syn.next(), &out);
  const auto base = gate.baseline_ut();
  syn.press_ut = 25;
  const int ten_minutes = static_cast<int>(600e6 / kPeriodUs);
  for (int k = 0; k < ten_minutes; ++k) {
    gate.update(syn.next(), &out);
    ASSERT_TRUE(out.contact) << "after " << k << " samples";
  }
  EXPECT_FALSE(out.drift_tracking);
  for (int i = 0; i < bus::kChannelCount; ++i) EXPECT_EQ(gate.baseline_ut()[i], base[i]);
  EXPECT_NEAR(out.tared_ut[3 * 5 + 2], 25, 5);
}

TEST(GateTest, SlowDriftIsFollowedWithoutFalseContacts) {
  ContactGate gate;
  Synthetic syn;
  GateOutput out;
  for (int k = 0; k < 100; ++k) gate.update(syn.next(), &out);
  // Ten minutes of a different slow drift per sensor (temperature), up to 30 uT.
  const int n = static_cast<int>(600e6 / kPeriodUs);
  int drift_samples = 0;
  for (int k = 0; k < n; ++k) {
    for (int i = 0; i < 16; ++i) syn.drift_per_sensor[i] = 30.0 * (i / 15.0) * k / n;
    gate.update(syn.next(), &out);
    ASSERT_FALSE(out.contact) << "drift read as a touch at sample " << k << " score "
                              << out.score_ut;
    drift_samples += out.drift_tracking;
  }
  EXPECT_GT(drift_samples, n / 2);
  EXPECT_NEAR(out.tared_ut[3 * 15], 0, 3.0);  // the baseline kept up with 30 uT
  // A press after the drift is still seen.
  syn.press_ut = 30;
  gate.update(syn.next(), &out);
  EXPECT_TRUE(out.contact);
}

TEST(GateTest, UniformAmbientChangeIsNotATouch) {
  ContactGate gate;
  Synthetic syn;
  GateOutput out;
  for (int k = 0; k < 100; ++k) gate.update(syn.next(), &out);
  // The limb turns: the Earth's field changes by 40 uT on every sensor at once.
  syn.ambient[0] = 25;
  syn.ambient[2] = -31;
  for (int k = 0; k < 50; ++k) {
    gate.update(syn.next(), &out);
    ASSERT_FALSE(out.contact) << out.score_ut;
  }
  // ... while a local press still is.
  syn.press_ut = 30;
  gate.update(syn.next(), &out);
  EXPECT_TRUE(out.contact);
}

TEST(GateTest, FaultySensorsAndNonFiniteValuesAreLeftOut) {
  ContactGate gate;
  Synthetic syn;
  syn.faults = 1u << 3;  // faulty through the tare: no baseline
  GateOutput out;
  for (int k = 0; k < 20; ++k) gate.update(syn.next(), &out);
  EXPECT_EQ(out.unbased_mask & 0xFFFF, 1u << 3);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(out.tared_ut[9 + a], 0.0);
  // A NaN from a sensor is treated as a fault: nothing non-finite comes out.
  ArraySample s = syn.next();
  s.field_ut[3 * 8 + 1] = std::nan("");
  s.field_ut[3 * 2] = INFINITY;
  gate.update(s, &out);
  for (double v : out.tared_ut) ASSERT_TRUE(std::isfinite(v));
  EXPECT_TRUE(std::isfinite(out.score_ut));
  EXPECT_FALSE(out.contact);
  // Sensor 3 comes back: it takes a baseline from its next untouched reading.
  syn.faults = 0;
  gate.update(syn.next(), &out);
  EXPECT_EQ(out.unbased_mask & 0xFFFF, 0);
  gate.update(syn.next(), &out);
  EXPECT_NEAR(out.tared_ut[9], 0, 6);
}

TEST(GateTest, TareCommandTakesANewBaseline) {
  ContactGate gate;
  Synthetic syn;
  GateOutput out;
  for (int k = 0; k < 30; ++k) gate.update(syn.next(), &out);
  syn.drift_per_sensor[4] = 80;  // a step no drift filter follows quickly
  gate.update(syn.next(), &out);
  EXPECT_NEAR(out.tared_ut[12], 80, 5);
  gate.start_tare();
  for (int k = 0; k < gate.config().tare_samples; ++k) gate.update(syn.next(), &out);
  gate.update(syn.next(), &out);
  EXPECT_NEAR(out.tared_ut[12], 0, 3);
}

// A press that lands during a capture: with kTareMinSamples readings or more before it, those are
// the baseline and the press is gated at once; with fewer, the capture starts again. A change
// common to every sensor (the Earth's field as the limb turns) does not stop a capture.
TEST(GateTest, ACaptureTakesOnlyASteadyField) {
  for (int before : {ContactGate::kTareMinSamples + 4, ContactGate::kTareMinSamples}) {
    SCOPED_TRACE(before);
    ContactGate gate;
    Synthetic syn;
    GateOutput out;
    for (int k = 0; k < before; ++k) {
      gate.update(syn.next(), &out);
      ASSERT_TRUE(out.tare_active);
      ASSERT_EQ(out.tare_changed_ut, 0.0);
    }
    syn.press_ut = 40;
    gate.update(syn.next(), &out);
    EXPECT_GT(out.tare_changed_ut, gate.config().on_threshold_ut);
    EXPECT_FALSE(out.tare_active);
    EXPECT_TRUE(out.tared);
    EXPECT_TRUE(out.contact) << "the press that stopped the capture is gated";
    EXPECT_NEAR(out.tared_ut[3 * 5 + 2], 40, 5) << "the baseline is the field before the press";
    for (int k = 0; k < 50; ++k) gate.update(syn.next(), &out);
    EXPECT_TRUE(out.contact);
    EXPECT_NEAR(out.tared_ut[3 * 6 + 2], 40, 5);
    syn.press_ut = 0;
    for (int k = 0; k < 10; ++k) gate.update(syn.next(), &out);
    EXPECT_FALSE(out.contact) << "released: the rest field again";
    EXPECT_NEAR(out.tared_ut[3 * 6 + 2], 0, 5);
  }
  {  // Too few readings before the press: the capture starts again, from the pressed field.
    ContactGate gate;
    Synthetic syn;
    GateOutput out;
    for (int k = 0; k < ContactGate::kTareMinSamples - 1; ++k) gate.update(syn.next(), &out);
    syn.press_ut = 40;
    gate.update(syn.next(), &out);
    EXPECT_GT(out.tare_changed_ut, 0.0);
    EXPECT_TRUE(out.tare_active);
    EXPECT_FALSE(out.contact);
    for (int k = 1; k < gate.config().tare_samples; ++k) {
      ASSERT_TRUE(out.tare_active) << k;
      gate.update(syn.next(), &out);
      ASSERT_EQ(out.tare_changed_ut, 0.0) << k;
    }
    EXPECT_FALSE(out.tare_active) << "a whole capture after the restart";
    EXPECT_TRUE(out.tared);
  }
  {  // An ambient step common to all sensors leaves the capture alone.
    ContactGate gate;
    Synthetic syn;
    GateOutput out;
    for (int k = 0; k < gate.config().tare_samples; ++k) {
      if (k == 6) syn.ambient[0] = syn.ambient[2] = 40;
      gate.update(syn.next(), &out);
      ASSERT_EQ(out.tare_changed_ut, 0.0) << k;
    }
    EXPECT_FALSE(out.tare_active);
    EXPECT_TRUE(out.tared);
  }
}

// A gate fed by the simulated patch with its sensor noise model, one sample per kPeriodUs.
struct PhysicsGate {
  PhysicsGate(sim::PatchModel model, uint64_t noise_seed) : patch(std::move(model), noise_seed) {}
  void feed(const std::vector<sim::Contact>& contacts) {
    patch.measure(contacts, env, sample.field_ut);
    sample.timestamp_us = t_us += kPeriodUs;
    gate.update(sample, &out);
  }
  sim::SimulatedPatch patch;
  sim::Environment env;
  ContactGate gate;
  GateOutput out;
  ArraySample sample;
  uint64_t t_us = 0;
};

// On the patch physics with the sensor noise model: an hour of idle noise never gates on, and
// presses of 1 mm over the sensor grid (2 mm anywhere) do.
TEST(GateTest, DetectsLightPressesOnThePhysicsAndNeverFiresOnNoise) {
  auto model = sim::PatchModel::fabricated(sim::PatchDesign{}, 77, sim::FabricationVariation{});
  ASSERT_TRUE(model.ok());
  PhysicsGate g(std::move(model).value(), 3);
  ContactGate& gate = g.gate;
  const GateOutput& out = g.out;
  auto feed = [&](const std::vector<sim::Contact>& contacts) { g.feed(contacts); };
  const int hour = static_cast<int>(3600e6 / kPeriodUs);
  double worst_idle = 0, worst_idle_rms = 0;
  for (int k = 0; k < hour; ++k) {
    feed({});
    ASSERT_FALSE(out.contact) << "false contact at sample " << k << ", score " << out.score_ut
                              << ", rms " << out.rms_ut;
    worst_idle = std::max(worst_idle, out.score_ut);
    worst_idle_rms = std::max(worst_idle_rms, out.rms_ut);
  }
  // Detection rate of presses (5 mm tip) held for kHoldSamples, over the sensor grid (|u|, |v| <=
  // 50 mm) and over the whole patch (the outer 20 mm lie beyond the outermost sensors).
  constexpr int kHoldSamples = 10, kReleaseSamples = 15;
  sim::Rng rng(11);
  for (double depth : {0.5, 1.0, 2.0}) {
    int inner = 0, inner_hit = 0, all_hit = 0;
    const int presses = 300;
    for (int p = 0; p < presses; ++p) {
      sim::Contact c;
      c.u_mm = rng.uniform(-65, 65);
      c.v_mm = rng.uniform(-65, 65);
      c.depth_mm = depth;
      c.tip_radius_mm = 5;
      // Held for kHoldSamples: detected if the gate turns on while it lasts.
      bool hit = false;
      for (int k = 0; k < kHoldSamples; ++k) {
        feed({c});
        hit = hit || out.contact;
      }
      const bool is_inner = std::fabs(c.u_mm) <= 50 && std::fabs(c.v_mm) <= 50;
      inner += is_inner;
      inner_hit += is_inner && hit;
      all_hit += hit;
      // Released: over within kReleaseSamples (the rms path's smoothing decays).
      for (int k = 0; k < kReleaseSamples; ++k) feed({});
      ASSERT_FALSE(out.contact) << "still in contact " << kReleaseSamples << " samples after a "
                                << depth << " mm press at " << c.u_mm << ", " << c.v_mm;
    }
    const double inner_rate = static_cast<double>(inner_hit) / inner;
    const double all_rate = static_cast<double>(all_hit) / presses;
    std::printf("%.1f mm presses detected: %.1f %% over the sensor grid, %.1f %% anywhere\n", depth,
                100 * inner_rate, 100 * all_rate);
    if (depth >= 1.0) {
      EXPECT_GE(inner_rate, 0.9) << depth;
    }
    if (depth >= 2.0) {
      EXPECT_GE(all_rate, 0.95) << depth;
    }
  }
  std::printf(
      "idle: largest score %.2f uT in an hour (on threshold %.1f uT), largest rms %.2f uT "
      "(on threshold %.1f uT)\n",
      worst_idle, gate.config().on_threshold_ut, worst_idle_rms, gate.config().rms_on_threshold_ut);
}

// A press at the patch's centre moves every sensor a little and none much (the checkerboard of
// magnets): the largest-sensor score stays under its threshold at any depth, the RMS catches it.
TEST(GateTest, DetectsPressesAtThePatchCentreByTheirRms) {
  auto model = sim::PatchModel::nominal(sim::PatchDesign{});
  ASSERT_TRUE(model.ok());
  PhysicsGate g(std::move(model).value(), 5);
  const ContactGate& gate = g.gate;
  const GateOutput& out = g.out;
  auto feed = [&](const std::vector<sim::Contact>& contacts) { g.feed(contacts); };
  for (int k = 0; k < 100; ++k) feed({});
  ASSERT_FALSE(out.contact);
  for (double depth : {1.0, 2.0, 3.0, 4.0}) {
    sim::Contact c;
    c.depth_mm = depth;
    c.tip_radius_mm = 5;
    // Held for 20 samples (130 ms); the rms path needs a few to rise.
    int onset = -1;
    double max_score = 0;
    for (int k = 0; k < 20; ++k) {
      feed({c});
      max_score = std::max(max_score, out.score_ut);
      if (out.contact && onset < 0) onset = k;
    }
    std::printf("centre press %.1f mm: score %.2f uT, rms %.2f uT, contact from sample %d\n", depth,
                max_score, out.rms_ut, onset);
    EXPECT_LT(max_score, gate.config().on_threshold_ut) << depth << " mm: the rms decides";
    if (depth >= 2.0) {
      EXPECT_GE(onset, 0) << depth;
      EXPECT_LE(onset, 8) << depth;
      EXPECT_TRUE(out.contact) << depth << ": held as long as the press";
    }
    // Released: the contact ends once the smoothed rms has decayed (a few samples).
    int end = -1;
    for (int k = 0; k < 30 && end < 0; ++k) {
      feed({});
      if (!out.contact) end = k;
    }
    EXPECT_GE(end, 0) << depth << ": the contact never ended";
    EXPECT_LE(end, 15) << depth;
  }
  // Idle again: no contact.
  for (int k = 0; k < 200; ++k) {
    feed({});
    ASSERT_FALSE(out.contact) << k;
  }
}

// A press the score saw ends once at its release: the rms path, still carrying the press in its
// smoothing, must not turn the contact straight back on.
TEST(GateTest, APressEndsOnceAtItsRelease) {
  for (auto [u, v] : {std::pair{10.0, 10.0}, std::pair{-20.0, 5.0}, std::pair{0.0, 0.0}}) {
    auto model = sim::PatchModel::nominal(sim::PatchDesign{});
    ASSERT_TRUE(model.ok());
    PhysicsGate g(std::move(model).value(), 9);
    for (int k = 0; k < 50; ++k) g.feed({});
    sim::Contact c;
    c.u_mm = u;
    c.v_mm = v;
    c.depth_mm = 1.5;
    c.tip_radius_mm = 8;
    int starts = 0;
    bool was = false;
    for (int k = 0; k < 100; ++k) {
      g.feed(k < 40 ? std::vector<sim::Contact>{c} : std::vector<sim::Contact>{});
      starts += g.out.contact && !was;
      was = g.out.contact;
    }
    EXPECT_EQ(starts, 1) << "press at " << u << ", " << v;
    EXPECT_FALSE(g.out.contact) << "press at " << u << ", " << v;
  }
}

// On the patch physics with the sensor noise model: captures of idle noise are never stopped
// (2000 of them); a press ramping in (0.15 s, as the simulated patch daemon's) during a capture on
// the built-in design and the 9 x 9 one is gated with the rest field as baseline: its tared field
// is the press's own field to within the noise.
TEST(GateTest, APressLandingDuringACaptureIsGatedAgainstTheRestField) {
  const char* src = std::getenv("SKINBUS_SOURCE_DIR");
  ASSERT_NE(src, nullptr) << "run through ctest (sets SKINBUS_SOURCE_DIR)";
  for (const char* design_path : {"", "docs/benchmarks/design_9x9_uniform.yaml"}) {
    SCOPED_TRACE(design_path);
    auto design =
        sim::read_design_or_builtin(design_path[0] ? std::string(src) + "/" + design_path : "");
    ASSERT_TRUE(design.ok()) << design.error().message;
    auto model = sim::PatchModel::fabricated(*design, 78, sim::FabricationVariation{});
    ASSERT_TRUE(model.ok());
    const sim::PatchModel unit = *model;
    PhysicsGate g(std::move(model).value(), 5);
    double worst_idle = 0;
    for (int capture = 0; capture < 2000; ++capture) {
      g.gate.start_tare();
      for (int k = 0; k < g.gate.config().tare_samples; ++k) {
        g.feed({});
        worst_idle = std::max(worst_idle, g.out.tare_changed_ut);
      }
    }
    EXPECT_EQ(worst_idle, 0.0) << "an idle capture was stopped";
    sim::Rng rng(12);
    const int ramp_samples = 6;  // 0.15 s at 41.7 Hz
    int gated = 0, presses = 0;
    double worst_error_ut = 0;
    std::vector<double> truth(static_cast<std::size_t>(unit.channel_count()));
    for (int p = 0; p < 40; ++p) {
      sim::Contact c;
      c.u_mm = rng.uniform(-40, 40);
      c.v_mm = rng.uniform(-40, 40);
      c.depth_mm = rng.uniform(1.0, 3.0);
      c.tip_radius_mm = 5;
      const int land = ContactGate::kTareMinSamples + static_cast<int>(rng.uniform(0, 10));
      g.gate.start_tare();
      for (int k = 0; k < land; ++k) g.feed({});
      ++presses;
      bool on = false;
      for (int k = 1; k <= ramp_samples + 10; ++k) {
        sim::Contact now = c;
        now.depth_mm = c.depth_mm * std::min(1.0, static_cast<double>(k) / ramp_samples);
        g.feed({now});
        on = on || g.out.contact;
      }
      ASSERT_FALSE(g.out.tare_active) << "press " << p;
      gated += on;
      unit.contact_field_ut(std::span<const sim::Contact>(&c, 1), truth);
      for (std::size_t i = 0; i < truth.size(); ++i) {
        worst_error_ut = std::max(worst_error_ut, std::fabs(g.out.tared_ut[i] - truth[i]));
      }
      for (int k = 0; k < 20; ++k) g.feed({});
      ASSERT_FALSE(g.out.contact) << "released, press " << p;
    }
    std::printf(
        "%s: idle captures: none stopped; presses landing in a capture: %d of %d gated, "
        "tared field within %.1f uT of the press's own\n",
        design_path[0] ? design_path : "built-in", gated, presses, worst_error_ut);
    EXPECT_EQ(gated, presses);
    // A ramp's first reading below the stop level can enter the capture; the rest is noise.
    EXPECT_LT(worst_error_ut, g.gate.config().on_threshold_ut + 6.0);
  }
}

}  // namespace
}  // namespace skinbus::patch_fw
