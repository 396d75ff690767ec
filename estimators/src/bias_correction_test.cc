#include "skinbus/estimators/bias_correction.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>

namespace skinbus::estimators {
namespace {

constexpr uint64_t kSeed = 424242;

// A smooth bias of the kind a model mismatch leaves: position- and depth-dependent.
void bias_at(double u, double v, double d, double* out) {
  out[0] = 0.6 * std::sin(u / 25.0) * (0.5 + 0.2 * d);
  out[1] = -0.4 * std::cos(v / 30.0 + u / 60.0);
  out[2] = 0.05 * d * std::sin(v / 40.0);
}

struct Samples {
  std::vector<ContactEstimate> est;
  std::vector<double> u, v, d;
};

// n presses at random places within +-half_mm and depths from min_depth_mm to 4 mm, each
// estimate off by `bias` and noise in u and v.
template <typename Bias>
Samples make_with(int n, uint64_t seed, double noise_mm, Bias bias, double half_mm,
                  double min_depth_mm) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> pos(-half_mm, half_mm), depth(min_depth_mm, 4.0);
  std::normal_distribution<double> noise(0, noise_mm);
  Samples s;
  for (int i = 0; i < n; ++i) {
    const double u = pos(rng), v = pos(rng), d = depth(rng);
    double b[3];
    bias(u, v, d, b);
    ContactEstimate e;
    e.u_mm = u - b[0] + noise(rng);
    e.v_mm = v - b[1] + noise(rng);
    e.depth_mm = d - b[2];
    s.est.push_back(e);
    s.u.push_back(u);
    s.v.push_back(v);
    s.d.push_back(d);
  }
  return s;
}

Samples make(int n, uint64_t seed, double noise_mm) {
  return make_with(n, seed, noise_mm, bias_at, 65, 0.2);
}

double mean_xy(const Samples& s, const BiasCorrection* c, double min_depth) {
  double sum = 0;
  int n = 0;
  for (std::size_t i = 0; i < s.est.size(); ++i) {
    if (s.d[i] < min_depth) continue;
    const ContactEstimate e = c ? c->apply(s.est[i]) : s.est[i];
    sum += std::hypot(e.u_mm - s.u[i], e.v_mm - s.v[i]);
    ++n;
  }
  return sum / n;
}

// Samples enough for a low degree but not for a high one: the high degree is left out, named, and
// the choice made among the others; with too few for any degree, the lowest's error.
TEST(BiasCorrection, ADegreeTheSamplesCannotFitIsLeftOut) {
  BiasCorrectionOptions o;
  o.half_u_mm = o.half_v_mm = 65;
  const Samples s = make(1500, kSeed, 0.2);
  o.degree_uv = 12;
  ASSERT_EQ(BiasCorrection::cross_validate(s.est, s.u, s.v, s.d, o).error().code,
            ErrorCode::kDegenerate);
  const int degrees[] = {4, 12};
  Result<BiasCorrection::Choice> c = BiasCorrection::choose(s.est, s.u, s.v, s.d, o, degrees);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  ASSERT_EQ(c->tried.size(), 1u);
  EXPECT_EQ(c->tried[0].first, 4);
  ASSERT_EQ(c->skipped.size(), 1u);
  EXPECT_EQ(c->skipped[0].first, 12);
  EXPECT_NE(c->skipped[0].second.find("usable samples"), std::string::npos);
  EXPECT_EQ(c->options.degree_uv, 4);
  EXPECT_TRUE(c->options.correct_position) << "the bias is there to learn at degree 4";
  const Samples few = make(30, kSeed, 0.2);
  EXPECT_EQ(BiasCorrection::choose(few.est, few.u, few.v, few.d, o, degrees).error().code,
            ErrorCode::kDegenerate);
}

TEST(BiasCorrection, LearnsASmoothBiasAndRemovesItOnNewSamples) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  const Samples train = make(8000, kSeed, 0.2), test = make(2000, kSeed + 1, 0.2);
  BiasCorrectionOptions o;
  o.degree_uv = 8;
  o.half_u_mm = o.half_v_mm = 65;
  Result<BiasCorrection> c = BiasCorrection::fit(train.est, train.u, train.v, train.d, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  const double before = mean_xy(test, nullptr, 1.0), after = mean_xy(test, &*c, 1.0);
  std::printf("mean XY error on new samples >= 1 mm deep: %.3f -> %.3f mm\n", before, after);
  EXPECT_LT(after, 0.5 * before);
  EXPECT_GT(c->rms_correction_mm(), 0.2);
}

// The held-out check says a correction helps where there is a bias to learn, and does not
// where the estimates only carry noise (a correction then fits the noise).
TEST(BiasCorrection, TheHeldOutCheckTellsABiasFromNoise) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  BiasCorrectionOptions o;
  o.degree_uv = 8;
  o.half_u_mm = o.half_v_mm = 65;
  Samples biased = make(4000, kSeed, 0.2);
  Result<CorrectionCheck> a =
      BiasCorrection::cross_validate(biased.est, biased.u, biased.v, biased.d, o);
  ASSERT_TRUE(a.ok()) << a.error().to_string();
  std::printf("biased: %d held out, %.3f -> %.3f mm, explains %.0f %%\n", a->samples,
              a->xy_mean_without_mm, a->xy_mean_with_mm, 100 * a->explained);
  EXPECT_TRUE(a->helps_position());
  EXPECT_TRUE(a->helps_depth());
  EXPECT_GT(a->explained, 0.5);
  // The same samples without their bias: nothing to learn.
  Samples unbiased = biased;
  for (std::size_t i = 0; i < unbiased.est.size(); ++i) {
    double b[3];
    bias_at(unbiased.u[i], unbiased.v[i], unbiased.d[i], b);
    unbiased.est[i].u_mm += b[0];
    unbiased.est[i].v_mm += b[1];
    unbiased.est[i].depth_mm += b[2];
  }
  Result<CorrectionCheck> n =
      BiasCorrection::cross_validate(unbiased.est, unbiased.u, unbiased.v, unbiased.d, o);
  ASSERT_TRUE(n.ok()) << n.error().to_string();
  std::printf("noise only: %.3f -> %.3f mm, explains %.1f %%\n", n->xy_mean_without_mm,
              n->xy_mean_with_mm, 100 * n->explained);
  EXPECT_FALSE(n->helps_position());
  EXPECT_LT(n->explained, 0.0);
  // Choosing among degrees: a correction for the biased samples, none for the position of the
  // unbiased ones.
  const int degrees[] = {4, 8};
  Result<BiasCorrection::Choice> ca =
      BiasCorrection::choose(biased.est, biased.u, biased.v, biased.d, o, degrees);
  ASSERT_TRUE(ca.ok()) << ca.error().to_string();
  EXPECT_TRUE(ca->options.correct_position);
  EXPECT_LT(ca->check.xy_mean_with_mm, a->xy_mean_with_mm + 0.05);
  Result<BiasCorrection::Choice> cn =
      BiasCorrection::choose(unbiased.est, unbiased.u, unbiased.v, unbiased.d, o, degrees);
  ASSERT_TRUE(cn.ok()) << cn.error().to_string();
  EXPECT_FALSE(cn->options.correct_position);
  std::printf("chosen degrees: biased %d, noise only %d (corrects position: %d)\n",
              ca->options.degree_uv, cn->options.degree_uv, cn->options.correct_position);
  const std::vector<double> short_u(biased.u.begin(), biased.u.begin() + 10);
  EXPECT_EQ(BiasCorrection::cross_validate(biased.est, short_u, biased.v, biased.d, o).error().code,
            ErrorCode::kInvalidArgument);
  const std::span<const ContactEstimate> few(biased.est.data(), 40);
  EXPECT_EQ(BiasCorrection::cross_validate(few, std::span<const double>(biased.u.data(), 40),
                                           std::span<const double>(biased.v.data(), 40),
                                           std::span<const double>(biased.d.data(), 40), o)
                .error()
                .code,
            ErrorCode::kDegenerate);
}

// A lab grid whose estimates are pulled toward the centre most at the edges (where a unit's
// misses are largest): the check holds out the edge places too, all but the four corners, and
// finds the correction that removes that pull.
TEST(BiasCorrection, TheHeldOutCheckJudgesTheEdgesToo) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  std::mt19937_64 rng(kSeed);
  std::normal_distribution<double> noise(0, 0.2);
  constexpr int kSide = 19;
  constexpr double kPitchMm = 7.5, kEdgeMm = 67.5;
  Samples s;
  double sum_not_corner = 0;
  int n_not_corner = 0;
  for (int i = 0; i < kSide; ++i) {
    for (int j = 0; j < kSide; ++j) {
      const double u = -kEdgeMm + kPitchMm * i, v = -kEdgeMm + kPitchMm * j;
      for (double d = 0.5; d <= 4.0; d += 0.25) {
        ContactEstimate e;
        e.u_mm = u * (1 - 0.02 * std::pow(u / kEdgeMm, 6)) + noise(rng);
        e.v_mm = v * (1 - 0.02 * std::pow(v / kEdgeMm, 6)) + noise(rng);
        e.depth_mm = d;
        s.est.push_back(e);
        s.u.push_back(u);
        s.v.push_back(v);
        s.d.push_back(d);
        const bool corner = (i == 0 || i == kSide - 1) && (j == 0 || j == kSide - 1);
        if (!corner && d >= 1.0) {
          sum_not_corner += std::hypot(e.u_mm - u, e.v_mm - v);
          ++n_not_corner;
        }
      }
    }
  }
  BiasCorrectionOptions o;
  o.degree_uv = 8;
  o.half_u_mm = o.half_v_mm = 70;
  Result<CorrectionCheck> c = BiasCorrection::cross_validate(s.est, s.u, s.v, s.d, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  std::printf("edge pull: %d held out of %d not at a corner, %.3f -> %.3f mm\n", c->samples,
              n_not_corner, c->xy_mean_without_mm, c->xy_mean_with_mm);
  EXPECT_EQ(c->samples, n_not_corner);
  EXPECT_NEAR(c->xy_mean_without_mm, sum_not_corner / n_not_corner, 1e-9);
  EXPECT_TRUE(c->helps_position());
  EXPECT_LT(c->xy_mean_with_mm, 0.8 * c->xy_mean_without_mm);
}

// A part helps only when it removes at least kMinGain of its held-out error, the position's
// averaged over depth bins.
TEST(BiasCorrection, AGainWithinTheCheckMarginIsNotHelp) {
  CorrectionCheck c;
  c.samples = 1000;
  c.depth_mean_without_mm = 0.100;
  c.depth_mean_with_mm = 0.098;  // 2 %
  // The position by depth bin, each counting alike: 1 mm -> 0.995, 0.5 -> 0.4975 (0.5 % each).
  c.bin_samples[0] = 600;
  c.bin_samples[1] = 400;
  c.xy_bin_without_mm[0] = 1.0;
  c.xy_bin_with_mm[0] = 0.995;
  c.xy_bin_without_mm[1] = 0.5;
  c.xy_bin_with_mm[1] = 0.4975;
  EXPECT_NEAR(c.xy_ratio(), 0.995, 1e-12);
  EXPECT_FALSE(c.helps_position());
  EXPECT_TRUE(c.helps_depth());
  c.xy_bin_with_mm[1] = 0.49;  // the deeper bin gains 2 %: 1.25 % on average
  EXPECT_TRUE(c.helps_position());
  c.samples = 0;
  EXPECT_FALSE(c.helps_position());
  EXPECT_FALSE(c.helps_depth());
}

TEST(BiasCorrection, LeavesShallowAndRejectedEstimatesAlone) {
  const Samples train = make(4000, kSeed, 0.1);
  BiasCorrectionOptions o;
  o.degree_uv = 4;
  Result<BiasCorrection> c = BiasCorrection::fit(train.est, train.u, train.v, train.d, o);
  ASSERT_TRUE(c.ok());
  ContactEstimate shallow{10, 10, 0.5, 1, kEstimateOk, RejectReason::kNone};
  EXPECT_EQ(c->apply(shallow).u_mm, 10);
  ContactEstimate rejected;
  rejected.flags = kEstimateRejected;
  rejected.u_mm = std::nan("");
  EXPECT_TRUE(std::isnan(c->apply(rejected).u_mm));  // untouched, still marked rejected
  EXPECT_FALSE(c->apply(rejected).valid());
  // Far outside the fitted range the basis is clamped: finite output.
  ContactEstimate far{1e6, -1e6, 3, 1, kEstimateOk, RejectReason::kNone};
  const ContactEstimate f = c->apply(far);
  EXPECT_TRUE(std::isfinite(f.u_mm) && std::isfinite(f.v_mm) && std::isfinite(f.depth_mm));
}

TEST(BiasCorrection, TooFewSamplesAreDegenerateAndBadInputIsRefused) {
  const Samples few = make(100, kSeed, 0.1);
  Result<BiasCorrection> c = BiasCorrection::fit(few.est, few.u, few.v, few.d);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, ErrorCode::kDegenerate);
  EXPECT_NE(c.error().message.find("usable samples"), std::string::npos);
  std::vector<double> shorter(few.u.begin(), few.u.end() - 1);
  EXPECT_EQ(BiasCorrection::fit(few.est, shorter, few.v, few.d).error().code,
            ErrorCode::kInvalidArgument);
  BiasCorrectionOptions bad;
  bad.degree_uv = 40;
  EXPECT_EQ(BiasCorrection::fit(few.est, few.u, few.v, few.d, bad).error().code,
            ErrorCode::kInvalidArgument);
  // Gross misses (beyond outlier_mm) are left out of the fit instead of bending it.
  Samples noisy = make(8000, kSeed + 2, 0.1);
  for (std::size_t i = 0; i < noisy.est.size(); i += 10) noisy.est[i].u_mm += 40;
  BiasCorrectionOptions o;
  o.degree_uv = 6;
  Result<BiasCorrection> robust = BiasCorrection::fit(noisy.est, noisy.u, noisy.v, noisy.d, o);
  ASSERT_TRUE(robust.ok());
  int deep = 0, deep_missed = 0;
  for (std::size_t i = 0; i < noisy.est.size(); ++i) {
    if (noisy.d[i] < 1.0 || noisy.est[i].depth_mm < 1.0) continue;
    ++deep;
    deep_missed += i % 10 == 0;
  }
  EXPECT_EQ(robust->samples_used(), deep - deep_missed);
  const Samples test = make(2000, kSeed + 3, 0.1);
  EXPECT_LT(mean_xy(test, &*robust, 1.0), 0.6 * mean_xy(test, nullptr, 1.0));
}

// A correction written to its file and read back applies bit for bit the same, with what it was
// chosen to correct; the note comes back.
TEST(BiasCorrection, TheFileRoundTripAppliesTheSame) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  const Samples train = make(4000, kSeed, 0.2), test = make(500, kSeed + 1, 0.2);
  BiasCorrectionOptions o;
  o.degree_uv = 6;
  o.degree_depth = 2;
  o.half_u_mm = 66;
  o.half_v_mm = 64;
  o.correct_position = false;  // depth only: the flag must survive the trip
  Result<BiasCorrection> c = BiasCorrection::fit(train.est, train.u, train.v, train.d, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  CorrectionCheck check;
  check.samples = 12;
  check.explained = 0.25;
  const std::string text = c->to_json(&check, "made by a test");
  EXPECT_NE(text.find("\"explained\": 0.25"), std::string::npos) << text.substr(0, 400);
  std::string note;
  Result<BiasCorrection> back = BiasCorrection::parse(text, &note);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_EQ(note, "made by a test");
  EXPECT_EQ(back->terms(), c->terms());
  EXPECT_EQ(back->samples_used(), c->samples_used());
  EXPECT_FALSE(back->options().correct_position);
  EXPECT_TRUE(back->options().correct_depth);
  EXPECT_EQ(back->options().half_v_mm, 64);
  int changed = 0;
  for (const ContactEstimate& e : test.est) {
    const ContactEstimate a = c->apply(e), b = back->apply(e);
    EXPECT_EQ(a.u_mm, e.u_mm);  // the position is not corrected
    changed += a.depth_mm != e.depth_mm;
    EXPECT_EQ(std::memcmp(&a.depth_mm, &b.depth_mm, sizeof(double)), 0);
    EXPECT_EQ(std::memcmp(&a.u_mm, &b.u_mm, sizeof(double)), 0);
  }
  EXPECT_GT(changed, 300);
  // Through a file: written whole, read back, and a missing one named.
  const std::string path = ::testing::TempDir() + "bias_correction_test.json";
  ASSERT_TRUE(c->write(path).ok());
  Result<BiasCorrection> from_file = BiasCorrection::read(path);
  ASSERT_TRUE(from_file.ok()) << from_file.error().to_string();
  EXPECT_EQ(from_file->terms(), c->terms());
  std::remove(path.c_str());
  Result<BiasCorrection> missing = BiasCorrection::read(path);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().to_string().find(path), std::string::npos);
}

// The position and the depth are each corrected at the degree where they help most on held-out
// presses: here a position bias that turns over every 25 mm (a low degree cannot follow it) and
// a depth bias of one gentle slope under noise (a high degree only fits the noise).
TEST(BiasCorrection, EachPartIsCorrectedAtItsOwnDegree) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  std::mt19937_64 rng(kSeed);
  std::uniform_real_distribution<double> pos(-65, 65), depth(1.0, 4.0);
  std::normal_distribution<double> noise(0, 0.1);
  Samples s;
  for (int i = 0; i < 8000; ++i) {
    const double u = pos(rng), v = pos(rng), d = depth(rng);
    ContactEstimate e;
    e.u_mm = u - 0.5 * std::sin(u / 8.0) + noise(rng);
    e.v_mm = v - 0.5 * std::cos(v / 8.0) + noise(rng);
    e.depth_mm = d - 0.1 * v / 65 + noise(rng);
    s.est.push_back(e);
    s.u.push_back(u);
    s.v.push_back(v);
    s.d.push_back(d);
  }
  BiasCorrectionOptions o;
  o.half_u_mm = o.half_v_mm = 65;
  const int degrees[] = {4, 12};
  Result<BiasCorrection::Choice> c = BiasCorrection::choose(s.est, s.u, s.v, s.d, o, degrees);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  for (const auto& [degree, t] : c->tried) std::printf("%s\n", t.held_out_text(degree).c_str());
  std::printf("chosen: %s\n", c->degree_text().c_str());
  ASSERT_EQ(c->tried.size(), 2u);
  const CorrectionCheck &low = c->tried[0].second, &high = c->tried[1].second;
  ASSERT_LT(high.xy_ratio(), low.xy_ratio());                  // the position: 12
  ASSERT_LT(low.depth_mean_with_mm, high.depth_mean_with_mm);  // the depth: 4
  // Every press at a place of its own: no check at the places, the held-out one alone judges.
  EXPECT_EQ(low.at_places.samples, 0);
  EXPECT_EQ(high.xy_ratio(), high.held_out_xy_ratio());
  EXPECT_NE(high.held_out_text(12).find("no check at the places"), std::string::npos);
  EXPECT_TRUE(c->options.correct_position && c->options.correct_depth);
  EXPECT_EQ(c->options.degree_uv, 12);
  EXPECT_EQ(c->options.depth_uv(), 4);
  EXPECT_EQ(c->degree_text(), "degree 12 (position), 4 (depth)");
  std::printf("%s\n", c->summary_text().c_str());
  EXPECT_NE(c->summary_text().find(": corrects the position, corrects the depth"),
            std::string::npos);
  EXPECT_EQ(c->check.xy_mean_with_mm, high.xy_mean_with_mm);
  EXPECT_EQ(c->check.depth_mean_with_mm, low.depth_mean_with_mm);
  // Fitted apart: each part is what its own degree alone gives, bit for bit.
  Result<BiasCorrection> both = BiasCorrection::fit(s.est, s.u, s.v, s.d, c->options);
  ASSERT_TRUE(both.ok()) << both.error().to_string();
  BiasCorrectionOptions at4 = o, at12 = o;
  at4.degree_uv = 4;
  at12.degree_uv = 12;
  Result<BiasCorrection> only4 = BiasCorrection::fit(s.est, s.u, s.v, s.d, at4);
  Result<BiasCorrection> only12 = BiasCorrection::fit(s.est, s.u, s.v, s.d, at12);
  ASSERT_TRUE(only4.ok() && only12.ok());
  EXPECT_EQ(both->terms(), only12->terms());
  EXPECT_EQ(both->depth_terms(), only4->terms());
  // Through its file: the depth's degree is written and read back, and applies the same.
  const std::string text = both->to_json();
  EXPECT_NE(text.find("\"depth_degree_uv\": 4"), std::string::npos) << text.substr(0, 400);
  Result<BiasCorrection> back = BiasCorrection::parse(text);
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  EXPECT_EQ(back->options().depth_uv(), 4);
  for (std::size_t i = 0; i < 200; ++i) {
    const ContactEstimate a = both->apply(s.est[i]), b = back->apply(s.est[i]);
    EXPECT_EQ(a.u_mm, only12->apply(s.est[i]).u_mm);
    EXPECT_EQ(a.depth_mm, only4->apply(s.est[i]).depth_mm);
    EXPECT_EQ(std::memcmp(&a.depth_mm, &b.depth_mm, sizeof(double)), 0);
    EXPECT_EQ(std::memcmp(&a.v_mm, &b.v_mm, sizeof(double)), 0);
  }
}

// Every bad field of a correction file is refused with its name (or the JSON's line).
TEST(BiasCorrection, EveryBadFieldOfItsFileIsNamed) {
  const Samples train = make(2000, kSeed, 0.2);
  BiasCorrectionOptions o;
  o.degree_uv = 4;
  o.degree_depth = 1;
  Result<BiasCorrection> c = BiasCorrection::fit(train.est, train.u, train.v, train.d, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  const std::string good = c->to_json();
  ASSERT_TRUE(BiasCorrection::parse(good).ok());
  // (text to replace, its replacement, what the error must say)
  const struct {
    const char* from;
    const char* to;
    const char* says;
  } cases[] = {
      {"\"skinbus-correction 1\"", "\"skinbus-unit 1\"", "not a correction file"},
      {"\"skinbus-correction 1\"", "\"skinbus-correction 2\"", "this reader knows"},
      {"\"degree_uv\": 4", "\"degree_uv\": 17", "options.degree_uv must be an integer from 0"},
      {"\"degree_uv\": 4", "\"degree_uv\": 3", "coefficients.u_mm must be an array of 32"},
      {"\"degree_uv\": 4", "\"degree_uv\": 4, \"depth_degree_uv\": 17",
       "options.depth_degree_uv must be an integer from 0"},
      {"\"degree_uv\": 4", "\"degree_uv\": 4, \"depth_degree_uv\": 3",
       "coefficients.depth_mm must be an array of 32"},
      {"\"degree_depth\": 1", "\"degree_depth\": 1.5", "options.degree_depth must be an integer"},
      {"\"half_u_mm\": 70", "\"half_u_mm\": 0", "options.half_u_mm must be positive"},
      {"\"max_depth_mm\": 4.5", "\"max_depth_mm\": \"deep\"", "options.max_depth_mm is not a"},
      {"\"correct_depth\": true", "\"correct_depth\": 1", "options.correct_depth must be true"},
      {"\"min_depth_mm\": 1.0", "\"min_depth\": 1.0", "options.min_depth_mm is missing"},
      {"\"depth_mm\": [", "\"depth_mm\": [\"x\", ", "coefficients.depth_mm must be an array"},
      {"\"samples\":", "\"samples\": -1, \"x\":", "samples must be an integer"},
      {"\"format\"", "\"format\" \"", "parse error at line "},
  };
  for (const auto& k : cases) {
    std::string text = good;
    const std::size_t at = text.find(k.from);
    ASSERT_NE(at, std::string::npos) << k.from;
    text.replace(at, std::strlen(k.from), k.to);
    Result<BiasCorrection> r = BiasCorrection::parse(text);
    ASSERT_FALSE(r.ok()) << k.to;
    EXPECT_EQ(r.error().code, ErrorCode::kParse);
    EXPECT_NE(r.error().message.find(k.says), std::string::npos)
        << "'" << k.to << "' gave: " << r.error().message;
  }
  // A coefficient too large for a double (JSON has no literal for a non-finite one).
  std::string text = good;
  const std::size_t at = text.find("\"v_mm\": [") + 9;
  text.insert(at, "1e999, ");
  Result<BiasCorrection> r = BiasCorrection::parse(text);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("number overflow"), std::string::npos) << r.error().message;
}

// A unit's presses as the seed's protocol makes them: a 19 x 19 grid at 7.5 mm, each place a
// ramp of `per_place` samples (depths 1-4 mm, in order), the estimates off by `bias` and noise.
template <typename Bias>
Samples make_grid(int per_place, uint64_t seed, double noise_mm, Bias bias) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, noise_mm);
  Samples s;
  for (int i = 0; i < 19; ++i) {
    for (int j = 0; j < 19; ++j) {
      const double u = -67.5 + 7.5 * i, v = -67.5 + 7.5 * j;
      for (int k = 0; k < per_place; ++k) {
        const double d = 1.0 + 3.0 * k / (per_place - 1);
        double b[3];
        bias(u, v, d, b);
        ContactEstimate e;
        e.u_mm = u - b[0] + noise(rng);
        e.v_mm = v - b[1] + noise(rng);
        e.depth_mm = d - b[2] + 0.2 * noise(rng);
        s.est.push_back(e);
        s.u.push_back(u);
        s.v.push_back(v);
        s.d.push_back(d);
      }
    }
  }
  return s;
}

// The ratio of corrected to uncorrected XY error by depth bin (mean over the bins, as
// CorrectionCheck::xy_ratio()) that presses `test` meet with correction `c`.
double measured_ratio(const Samples& test, const BiasCorrection& c) {
  double with[CorrectionCheck::kDepthBins] = {}, without[CorrectionCheck::kDepthBins] = {};
  for (std::size_t i = 0; i < test.est.size(); ++i) {
    if (test.d[i] < 1.0) continue;
    const int bin = static_cast<int>(std::fmin(CorrectionCheck::kDepthBins - 1, test.d[i] - 1.0));
    const ContactEstimate e = c.apply(test.est[i]);
    without[bin] += std::hypot(test.est[i].u_mm - test.u[i], test.est[i].v_mm - test.v[i]);
    with[bin] += std::hypot(e.u_mm - test.u[i], e.v_mm - test.v[i]);
  }
  double sum = 0;
  for (int b = 0; b < CorrectionCheck::kDepthBins; ++b) sum += with[b] / without[b];
  return sum / CorrectionCheck::kDepthBins;
}

// The check judges a correction as new presses between the grid places will meet it: nearer a
// fitted place than a held-out place is (on a square grid, 0.38 of the way from the places to
// one spacing off). Its figure for new presses is nearer what new presses measure than the
// held-out places' alone, and its check at the places gives a correction no credit for noise.
TEST(BiasCorrection, TheCheckJudgesAsNewPressesWillMeetIt) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  // A position bias that turns over every 30 mm or so: a degree-12 correction follows it between
  // places 7.5 mm apart, less well across a held-out place's 15 mm gap.
  auto fine = [](double u, double v, double d, double* b) {
    b[0] = 0.5 * std::sin(u / 5.0 + v / 9.0) * (0.6 + 0.1 * d);
    b[1] = 0.4 * std::cos(v / 5.5 - u / 11.0);
    b[2] = 0.03 * d * std::sin(u / 20.0);
  };
  const Samples grid = make_grid(24, kSeed, 0.4, fine);
  BiasCorrectionOptions o;
  o.degree_uv = 12;
  o.half_u_mm = o.half_v_mm = 70;
  Result<CorrectionCheck> c = BiasCorrection::cross_validate(grid.est, grid.u, grid.v, grid.d, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  std::printf("%s; share %.3f\n", c->held_out_text(12).c_str(), c->new_press_share);
  EXPECT_NEAR(c->new_press_share, 0.3826, 0.02);
  EXPECT_EQ(c->at_places.samples, 19 * 19 * 5);  // the second of every five samples of a place
  // New presses anywhere between the places, the correction fitted on every grid press.
  const Samples fresh = make_with(20000, kSeed + 7, 0.4, fine, 67.5, 1.0);
  Result<BiasCorrection> all = BiasCorrection::fit(grid.est, grid.u, grid.v, grid.d, o);
  ASSERT_TRUE(all.ok()) << all.error().to_string();
  const double measured = measured_ratio(fresh, *all);
  std::printf(
      "new presses measure x %.3f; the check says x %.3f (held-out places alone x %.3f, "
      "the places alone x %.3f)\n",
      measured, c->xy_ratio(), c->held_out_xy_ratio(), c->at_places_xy_ratio());
  EXPECT_LT(std::fabs(c->xy_ratio() - measured),
            0.5 * std::fabs(c->held_out_xy_ratio() - measured));
  EXPECT_LT(c->xy_ratio(), c->held_out_xy_ratio());
  // choose() goes by the same figures and keeps the depth's check at its own degree, at the
  // places too.
  const int degrees[] = {4, 12};
  Result<BiasCorrection::Choice> ch =
      BiasCorrection::choose(grid.est, grid.u, grid.v, grid.d, o, degrees);
  ASSERT_TRUE(ch.ok()) << ch.error().to_string();
  ASSERT_EQ(ch->tried.size(), 2u);
  const CorrectionCheck& at12 = ch->tried[1].second;
  EXPECT_EQ(at12.xy_ratio(), c->xy_ratio());
  EXPECT_LT(at12.xy_ratio(), ch->tried[0].second.xy_ratio());
  EXPECT_EQ(ch->options.degree_uv, 12);
  EXPECT_TRUE(ch->options.correct_position);
  const CorrectionCheck& depth_at = ch->tried[ch->options.depth_uv() == 4 ? 0 : 1].second;
  EXPECT_EQ(ch->check.depth_ratio(), depth_at.depth_ratio());
  EXPECT_EQ(ch->check.at_places.depth_mean_with_mm, depth_at.at_places.depth_mean_with_mm);
  // Noise alone: the places' check is fitted on other samples than it judges, so a degree-12
  // correction wins nothing there (judged on its own samples, it would seem to).
  const Samples noise = make_grid(
      24, kSeed + 1, 0.4, [](double, double, double, double* b) { b[0] = b[1] = b[2] = 0; });
  Result<CorrectionCheck> n =
      BiasCorrection::cross_validate(noise.est, noise.u, noise.v, noise.d, o);
  ASSERT_TRUE(n.ok()) << n.error().to_string();
  Result<BiasCorrection> own = BiasCorrection::fit(noise.est, noise.u, noise.v, noise.d, o);
  ASSERT_TRUE(own.ok()) << own.error().to_string();
  const double on_own = measured_ratio(noise, *own);
  std::printf("noise only: at the places x %.3f (on its own samples x %.3f), new presses x %.3f\n",
              n->at_places_xy_ratio(), on_own, n->xy_ratio());
  EXPECT_LT(on_own, 0.97);
  EXPECT_GT(n->at_places_xy_ratio(), 1.0);
  EXPECT_FALSE(n->helps_position());
  EXPECT_FALSE(n->helps_depth());
}

// Places pressed twice each: the fit at the places keeps half the samples, too few for the
// basis where every fold's fit has enough; the held-out check then judges alone, it does not fail.
TEST(BiasCorrection, TooFewSamplesAtThePlacesLeaveTheHeldOutCheckAlone) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  const Samples twice = make_grid(2, kSeed, 0.2, bias_at);  // 722 samples, 361 per half
  BiasCorrectionOptions o;
  o.degree_uv = 4;  // 100 terms: a fit needs 400 samples
  o.half_u_mm = o.half_v_mm = 70;
  Result<CorrectionCheck> c =
      BiasCorrection::cross_validate(twice.est, twice.u, twice.v, twice.d, o);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  std::printf("%s\n", c->held_out_text(4).c_str());
  EXPECT_GT(c->samples, 0);
  EXPECT_EQ(c->at_places.samples, 0);
  EXPECT_EQ(c->xy_ratio(), c->held_out_xy_ratio());
  EXPECT_NE(c->held_out_text(4).find("no check at the places"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::estimators
