// Learning a unit's field correction from its own presses (field_correction_fit.h).
#include "skinbus/estimators/field_correction_fit.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "skinbus/common/error_format.h"

namespace skinbus::estimators {
namespace {

using sim::FieldCorrection;

// Unknowns above which a knot spacing is not tried: its dense normal matrix would take more
// than about 70 MB a copy.
constexpr std::size_t kMaxUnknowns = 3000;

struct Sample {
  double u = 0, v = 0, d = 0;
  int fold = 0, bin = -1;
  long known = 0;  // channels with a finite value
};

// Knot spacings finer than this are not tried, however close the press places lie.
constexpr double kMinSpacingMm = 1.0;

// Squared whitened residual sums, overall and per depth bin.
struct Sums {
  std::vector<double> bin;
  std::vector<long> bin_values;
  double all = 0;
  long values = 0;
  explicit Sums(std::size_t bins) : bin(bins, 0.0), bin_values(bins, 0) {}
  void add(int b, double sq, long n) {
    all += sq;
    values += n;
    if (b >= 0) {
      bin[static_cast<std::size_t>(b)] += sq;
      bin_values[static_cast<std::size_t>(b)] += n;
    }
  }
  double rms() const { return values > 0 ? std::sqrt(all / static_cast<double>(values)) : 0.0; }
  double rms(std::size_t b) const {
    return bin_values[b] > 0 ? std::sqrt(bin[b] / static_cast<double>(bin_values[b])) : 0.0;
  }
};

// The grid of knots `step` apart over [lo, hi] along each axis, centred on it.
FieldCorrection::Grid grid_over(double u_lo, double u_hi, double v_lo, double v_hi, double step,
                                double max_depth) {
  FieldCorrection::Grid g;
  const int cu = std::max(1, static_cast<int>(std::ceil((u_hi - u_lo) / step - 1e-9)));
  const int cv = std::max(1, static_cast<int>(std::ceil((v_hi - v_lo) / step - 1e-9)));
  g.nu = cu + 3;
  g.nv = cv + 3;
  g.step_mm = step;
  g.u0_mm = 0.5 * (u_lo + u_hi) - 0.5 * cu * step;
  g.v0_mm = 0.5 * (v_lo + v_hi) - 0.5 * cv * step;
  g.max_depth_mm = max_depth;
  return g;
}

// Squared second differences of the coefficients along u and along v, per depth term.
Eigen::MatrixXd smoothing_penalty(const FieldCorrection::Grid& g) {
  const Eigen::Index k = static_cast<Eigen::Index>(g.terms());
  Eigen::MatrixXd p = Eigen::MatrixXd::Zero(k, k);
  const int nd = FieldCorrection::kDepthTerms;
  auto add = [&](Eigen::Index a, Eigen::Index b, Eigen::Index c) {
    const Eigen::Index at[3] = {a, b, c};
    const double w[3] = {1, -2, 1};
    for (int x = 0; x < 3; ++x)
      for (int y = 0; y < 3; ++y) p(at[x], at[y]) += w[x] * w[y];
  };
  auto index = [&](int i, int j, int t) {
    return static_cast<Eigen::Index>((j * g.nu + i) * nd + t);
  };
  for (int t = 0; t < nd; ++t) {
    for (int j = 0; j < g.nv; ++j)
      for (int i = 1; i + 1 < g.nu; ++i)
        add(index(i - 1, j, t), index(i, j, t), index(i + 1, j, t));
    for (int i = 0; i < g.nu; ++i)
      for (int j = 1; j + 1 < g.nv; ++j)
        add(index(i, j - 1, t), index(i, j, t), index(i, j + 1, t));
  }
  return p;
}

}  // namespace

double FieldCorrectionReport::explained() const {
  const double excess = rms_model * rms_model - 1;
  return excess > 0 ? (excess - std::max(rms_held_out * rms_held_out - 1, 0.0)) / excess : 0.0;
}

std::string FieldCorrectionReport::summary_text() const {
  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "field correction: residual %.3f -> %.3f noise units at held-out places (%.3f fitted; "
      "%.0f %% of the residual's excess over the noise explained), knots %.1f mm, smoothing %g, "
      "%d samples at %d places: %s",
      rms_model, rms_held_out, rms_fitted, 100 * explained(), step_mm, smoothing, samples, places,
      helps ? "helps" : "does not help");
  std::string s = buf;
  for (const Bin& b : bins) {
    if (b.samples == 0) continue;
    std::snprintf(
        buf, sizeof buf, "\n  depth %g-%g mm: %.3f -> %.3f held out (%.3f fitted), %d samples",
        b.depth_lo_mm, b.depth_hi_mm, b.rms_model, b.rms_held_out, b.rms_fitted, b.samples);
    s += buf;
  }
  return s;
}

Result<sim::FieldCorrection> fit_field_correction(const sim::PatchModel& model_in,
                                                  const sim::Dataset& presses, double tip_radius_mm,
                                                  const FieldCorrectionOptions& opt,
                                                  FieldCorrectionReport* report) {
  const int nc = model_in.channel_count();
  if (presses.channels() != nc) {
    return make_error(ErrorCode::kInvalidArgument,
                      "field correction: the presses have " + std::to_string(presses.channels()) +
                          " channels, the model " + std::to_string(nc));
  }
  if (opt.steps_rel.empty() || opt.smoothing.empty() || opt.folds < 2) {
    return make_error(ErrorCode::kInvalidArgument,
                      "field correction: steps, smoothings and >= 2 folds required");
  }
  // The class's own model: the residual is taken against it (rebuilt only when `model_in` carries
  // a correction).
  std::optional<sim::PatchModel> bare_model;
  if (model_in.field_correction() != nullptr) {
    sim::UnitParameters bare = model_in.parameters();
    bare.field_correction = nullptr;
    Result<sim::PatchModel> m = sim::PatchModel::from_parameters(model_in.design(), bare);
    if (!m.ok()) return m.error();
    bare_model.emplace(std::move(*m));
  }
  const sim::PatchModel& model = bare_model ? *bare_model : model_in;
  const ChannelNoise noise =
      opt.noise.xy_ut > 0 && opt.noise.z_ut > 0 ? opt.noise : ChannelNoise::of(model.design());
  const std::vector<double>& edges = opt.depth_bin_edges_mm;
  const std::size_t nb = edges.size() > 1 ? edges.size() - 1 : 0;

  // The samples used, their residuals (whitened: each channel's solve is the same with or
  // without, and the sums below read them directly) and their press places.
  const std::size_t ncu = static_cast<std::size_t>(nc);
  std::vector<Sample> samples;
  std::vector<double> resid;   // samples x nc, noise units (0 where the value is not finite)
  std::vector<uint8_t> known;  // samples x nc: the value is finite
  std::vector<double> f(ncu);
  std::map<std::pair<long, long>, int> place_of;  // (u, v) to 1 um
  std::vector<std::pair<double, double>> places;
  double max_depth = 0;
  for (std::size_t r = 0; r < presses.rows(); ++r) {
    const double u = presses.u_mm[r], v = presses.v_mm[r], d = presses.depth_mm[r];
    if (!std::isfinite(u) || !std::isfinite(v) || !(d >= opt.min_depth_mm)) continue;
    // A dead channel (not finite) adds nothing to its own fit and is left out of the sums; a
    // row needs half its channels.
    const double* x = presses.field(r);
    long finite = 0;
    for (std::size_t c = 0; c < ncu; ++c) finite += std::isfinite(x[c]) ? 1 : 0;
    if (2 * finite < nc) continue;
    const sim::Contact contact{u, v, d, tip_radius_mm};
    model.contact_field_ut(std::span<const sim::Contact>(&contact, 1), f);
    for (std::size_t c = 0; c < ncu; ++c) {
      const bool ok = std::isfinite(x[c]);
      resid.push_back(ok ? (x[c] - f[c]) / noise.sigma(static_cast<int>(c)) : 0.0);
      known.push_back(ok ? 1 : 0);
    }
    Sample s;
    s.known = finite;
    s.u = u;
    s.v = v;
    s.d = d;
    for (std::size_t b = 0; b < nb; ++b) {
      if (d >= edges[b] && d < edges[b + 1]) s.bin = static_cast<int>(b);
    }
    const auto key = std::make_pair(std::lround(u * 1000), std::lround(v * 1000));
    if (place_of.emplace(key, static_cast<int>(places.size())).second) places.push_back({u, v});
    samples.push_back(s);
    max_depth = std::max(max_depth, d);
  }
  const int n_places = static_cast<int>(places.size());
  if (n_places < 10 * opt.folds) {
    return errorf(ErrorCode::kDegenerate,
                  "field correction: %d press places at least %g mm deep, %d needed", n_places,
                  opt.min_depth_mm, 10 * opt.folds);
  }
  // The places' spacing (median nearest-neighbour distance), extent and folds.
  std::vector<double> nearest(places.size(), 1e300);
  for (std::size_t i = 0; i < places.size(); ++i) {
    for (std::size_t j = 0; j < places.size(); ++j) {
      if (i == j) continue;
      const double du = places[i].first - places[j].first, dv = places[i].second - places[j].second;
      nearest[i] = std::min(nearest[i], std::sqrt(du * du + dv * dv));
    }
  }
  std::nth_element(nearest.begin(), nearest.begin() + static_cast<long>(nearest.size() / 2),
                   nearest.end());
  const double spacing = std::max(nearest[nearest.size() / 2], kMinSpacingMm);
  double u_lo = 1e300, u_hi = -1e300, v_lo = 1e300, v_hi = -1e300;
  for (const auto& [u, v] : places) {
    u_lo = std::min(u_lo, u), u_hi = std::max(u_hi, u);
    v_lo = std::min(v_lo, v), v_hi = std::max(v_hi, v);
  }
  for (Sample& s : samples) {
    const long i = std::lround(s.u / spacing), j = std::lround(s.v / spacing);
    s.fold = static_cast<int>(((i + 2 * j) % opt.folds + opt.folds) % opt.folds);
  }

  const std::size_t ns = samples.size();
  // The model's own residual.
  Sums model_sums(nb);
  for (std::size_t i = 0; i < ns; ++i) {
    double sq = 0;
    for (std::size_t c = 0; c < ncu; ++c) sq += resid[i * ncu + c] * resid[i * ncu + c];
    model_sums.add(samples[i].bin, sq, samples[i].known);
  }

  const int folds = opt.folds;
  struct Best {
    double rms = 1e300, step = 0, smoothing = 0;
    Sums held{0};
  } best;
  FieldCorrectionReport rep;
  rep.samples = static_cast<int>(ns);
  rep.places = n_places;
  rep.place_spacing_mm = spacing;
  constexpr int kSupport = FieldCorrection::kSupport;
  std::vector<int> idx(ns * kSupport);
  std::vector<double> wt(ns * kSupport);
  std::vector<int> count(ns);
  // The normal equations on the knot grid `step` apart: per fold and summed over every fold,
  // and their mean diagonal (the scale of the penalties). Leaves every sample's basis in idx,
  // wt and count.
  struct Normal {
    FieldCorrection::Grid grid;
    std::vector<Eigen::MatrixXd> n_f, b_f;  // per fold
    Eigen::MatrixXd n_all, b_all;
    double scale = 1;
  };
  auto normal_equations = [&](double step) -> Result<Normal> {
    Normal e;
    e.grid = grid_over(u_lo, u_hi, v_lo, v_hi, step, max_depth);
    Result<FieldCorrection> basis =
        FieldCorrection::make(e.grid, nc, std::vector<double>(e.grid.terms() * ncu, 0.0));
    if (!basis.ok()) return basis.error();
    const Eigen::Index k = static_cast<Eigen::Index>(e.grid.terms());
    e.n_f.assign(static_cast<std::size_t>(folds), Eigen::MatrixXd::Zero(k, k));
    e.b_f.assign(static_cast<std::size_t>(folds),
                 Eigen::MatrixXd::Zero(k, static_cast<Eigen::Index>(nc)));
    for (std::size_t i = 0; i < ns; ++i) {
      const Sample& s = samples[i];
      int* ix = &idx[i * kSupport];
      double* w = &wt[i * kSupport];
      count[i] = basis->basis(s.u, s.v, s.d, ix, w);
      Eigen::MatrixXd& n = e.n_f[static_cast<std::size_t>(s.fold)];
      Eigen::MatrixXd& b = e.b_f[static_cast<std::size_t>(s.fold)];
      const Eigen::Map<const Eigen::RowVectorXd> r(&resid[i * ncu], static_cast<Eigen::Index>(nc));
      for (int a = 0; a < count[i]; ++a) {
        for (int c = 0; c < count[i]; ++c) n(ix[a], ix[c]) += w[a] * w[c];
        b.row(ix[a]) += w[a] * r;
      }
    }
    e.n_all = e.n_f[0];
    e.b_all = e.b_f[0];
    for (int q = 1; q < folds; ++q) {
      e.n_all += e.n_f[static_cast<std::size_t>(q)];
      e.b_all += e.b_f[static_cast<std::size_t>(q)];
    }
    e.scale = std::max(e.n_all.trace() / static_cast<double>(k), 1e-300);
    return e;
  };
  // The squared residual left on sample i by coefficients `coef` (terms x channels).
  auto left = [&](std::size_t i, const Eigen::MatrixXd& coef) {
    double sq = 0;
    const int* ix = &idx[i * kSupport];
    const double* w = &wt[i * kSupport];
    for (std::size_t c = 0; c < ncu; ++c) {
      double p = 0;
      for (int a = 0; a < count[i]; ++a) p += w[a] * coef(ix[a], static_cast<Eigen::Index>(c));
      const double e = resid[i * ncu + c] - p;
      sq += known[i * ncu + c] ? e * e : 0.0;
    }
    return sq;
  };
  auto solve = [&](const Eigen::MatrixXd& n, const Eigen::MatrixXd& b, const Eigen::MatrixXd& pen,
                   double scale, double smoothing) -> std::optional<Eigen::MatrixXd> {
    Eigen::MatrixXd m = n + (smoothing * scale) * pen;
    m.diagonal().array() += opt.ridge * scale;
    Eigen::LLT<Eigen::MatrixXd> llt(m);
    if (llt.info() != Eigen::Success) return std::nullopt;
    return llt.solve(b);
  };
  for (double rel : opt.steps_rel) {
    const FieldCorrection::Grid g = grid_over(u_lo, u_hi, v_lo, v_hi, rel * spacing, max_depth);
    if (g.terms() > kMaxUnknowns || g.nu > FieldCorrection::kMaxKnots ||
        g.nv > FieldCorrection::kMaxKnots || 2 * g.terms() > ns) {
      continue;
    }
    Result<Normal> e = normal_equations(g.step_mm);
    if (!e.ok()) return e.error();
    const Eigen::MatrixXd pen = smoothing_penalty(g);
    for (double lambda : opt.smoothing) {
      Sums held(nb);
      bool ok = true;
      for (int q = 0; q < folds && ok; ++q) {
        const std::size_t fold = static_cast<std::size_t>(q);
        const std::optional<Eigen::MatrixXd> coef =
            solve(e->n_all - e->n_f[fold], e->b_all - e->b_f[fold], pen, e->scale, lambda);
        ok = coef.has_value();
        for (std::size_t i = 0; ok && i < ns; ++i) {
          if (samples[i].fold == q) held.add(samples[i].bin, left(i, *coef), samples[i].known);
        }
      }
      if (!ok) continue;
      rep.tried.push_back({g.step_mm, lambda, held.rms()});
      if (held.rms() < best.rms) {
        best.rms = held.rms();
        best.step = g.step_mm;
        best.smoothing = lambda;
        best.held = held;
      }
    }
  }
  if (rep.tried.empty()) {
    return make_error(ErrorCode::kDegenerate,
                      "field correction: " + std::to_string(ns) +
                          " samples are too few for any knot spacing tried (each needs twice "
                          "its unknowns, at most " +
                          std::to_string(kMaxUnknowns) + ")");
  }
  // The choice, fitted on every sample.
  Result<Normal> e = normal_equations(best.step);
  if (!e.ok()) return e.error();
  const FieldCorrection::Grid g = e->grid;
  const std::optional<Eigen::MatrixXd> coef =
      solve(e->n_all, e->b_all, smoothing_penalty(g), e->scale, best.smoothing);
  if (!coef.has_value()) {
    return make_error(ErrorCode::kNotConverged,
                      "field correction: the normal equations are not positive definite");
  }
  Sums fitted(nb);
  for (std::size_t i = 0; i < ns; ++i) {
    fitted.add(samples[i].bin, left(i, *coef), samples[i].known);
  }
  // Back to uT, term-major.
  std::vector<double> out(g.terms() * ncu);
  for (std::size_t t = 0; t < g.terms(); ++t) {
    for (std::size_t c = 0; c < ncu; ++c) {
      out[t * ncu + c] = (*coef)(static_cast<Eigen::Index>(t), static_cast<Eigen::Index>(c)) *
                         noise.sigma(static_cast<int>(c));
    }
  }
  rep.step_mm = best.step;
  rep.smoothing = best.smoothing;
  rep.rms_model = model_sums.rms();
  rep.rms_held_out = best.held.rms();
  rep.rms_fitted = fitted.rms();
  for (std::size_t b = 0; b < nb; ++b) {
    FieldCorrectionReport::Bin bin;
    bin.depth_lo_mm = edges[b];
    bin.depth_hi_mm = edges[b + 1];
    bin.samples =
        static_cast<int>(std::count_if(samples.begin(), samples.end(), [&](const Sample& x) {
          return x.bin == static_cast<int>(b);
        }));
    bin.rms_model = model_sums.rms(b);
    bin.rms_held_out = best.held.rms(b);
    bin.rms_fitted = fitted.rms(b);
    rep.bins.push_back(bin);
  }
  rep.helps = rep.rms_held_out <= (1 - opt.min_gain) * rep.rms_model;
  if (report != nullptr) *report = std::move(rep);
  return FieldCorrection::make(g, nc, std::move(out));
}

std::string CreepAndCorrection::summary_text() const {
  std::string s = "creep with the field correction:";
  char buf[160];
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const Candidate& c = candidates[i];
    s += i == 0 ? " " : ", ";
    s += c.what;
    if (!c.law.none()) {
      std::snprintf(buf, sizeof buf, " (%.3f of the bend lags by %.3f s", c.law.fraction,
                    c.law.time_s);
      s += buf;
      if (c.law.slow_fraction > 0) {
        std::snprintf(buf, sizeof buf, ", %.3f by %.3f s", c.law.slow_fraction, c.law.slow_time_s);
        s += buf;
      }
      s += ")";
    }
    std::snprintf(buf, sizeof buf, " %.3f", c.held_out_rms);
    s += buf;
  }
  s += " noise units at held-out places";
  if (!candidates.empty()) s += ": " + candidates[static_cast<std::size_t>(chosen)].what + " kept";
  return s;
}

Result<CreepAndCorrection> fit_creep_and_correction(
    const sim::PatchDesign& design, const sim::UnitParameters& unit, const sim::Dataset& presses,
    double tip_radius_mm, const FieldCorrectionOptions& correction_options,
    const CreepFitOptions& creep_options, bool choose_creep, int rounds) {
  // The unit's static model: no creep, no correction; each candidate adds its own.
  sim::UnitParameters plain = unit;
  plain.field_correction.reset();
  CreepLaw{}.write_to(&plain);
  CreepAndCorrection out;
  // Learns the correction at `law`'s bends, adds the candidate and keeps it if it is the best;
  // the correction is returned for the next round's creep fit.
  auto add = [&](std::string what, const CreepLaw& law) -> Result<sim::FieldCorrection> {
    sim::UnitParameters u = plain;
    law.write_to(&u);
    Result<sim::PatchModel> model = sim::PatchModel::of_unit_file(design, u);
    if (!model.ok()) return model.error();
    FieldCorrectionReport report;
    Result<sim::FieldCorrection> fc = fit_field_correction(
        *model, bent_dataset(law, presses), tip_radius_mm, correction_options, &report);
    if (!fc.ok()) return fc.error();
    out.candidates.push_back({std::move(what), law, report.rms_held_out});
    if (out.correction == nullptr || report.rms_held_out < out.report.rms_held_out) {
      out.chosen = static_cast<int>(out.candidates.size()) - 1;
      out.law = law;
      out.report = std::move(report);
      out.correction = std::make_shared<const sim::FieldCorrection>(*fc);
    }
    return fc;
  };
  const CreepLaw own = CreepLaw::of(unit);
  if (!choose_creep) {
    if (Result<sim::FieldCorrection> fc = add(own.none() ? "none" : "identified", own); !fc.ok()) {
      return fc.error();
    }
    return out;
  }
  if (!own.none()) {
    if (Result<sim::FieldCorrection> fc = add("identified", own); !fc.ok()) return fc.error();
  }
  // One lag a round (see the header).
  CreepFitOptions round_options = creep_options;
  round_options.slow_lag = false;
  Result<sim::FieldCorrection> previous = add("none", CreepLaw{});
  if (!previous.ok()) return previous.error();
  for (int r = 1; r <= rounds; ++r) {
    sim::UnitParameters corrected = plain;
    corrected.field_correction = std::make_shared<const sim::FieldCorrection>(*previous);
    Result<sim::PatchModel> model = sim::PatchModel::of_unit_file(design, corrected);
    if (!model.ok()) return model.error();
    Result<CreepFit> creep = fit_creep(*model, presses, round_options);
    if (!creep.ok()) return creep.error();
    if (!creep->kept) break;
    previous = add("round " + std::to_string(r), creep->law);
    if (!previous.ok()) return previous.error();
  }
  return out;
}

}  // namespace skinbus::estimators
