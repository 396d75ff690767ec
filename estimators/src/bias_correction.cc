#include "skinbus/estimators/bias_correction.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace skinbus::estimators {
namespace {

constexpr int kMaxTerms = (BiasCorrection::kMaxDegreeUv + 1) * (BiasCorrection::kMaxDegreeUv + 1) *
                          (BiasCorrection::kMaxDegreeDepth + 1);

// Legendre polynomials P0..Pn at x (clamped to [-1, 1]).
void legendre(double x, int n, double* p) {
  x = std::clamp(x, -1.0, 1.0);
  p[0] = 1;
  if (n >= 1) p[1] = x;
  for (int k = 2; k <= n; ++k) p[k] = ((2 * k - 1) * x * p[k - 1] - (k - 1) * p[k - 2]) / k;
}

}  // namespace

void BiasCorrection::basis(double u, double v, double d, int degree_uv, double* out) const {
  double pu[kMaxDegreeUv + 1], pv[kMaxDegreeUv + 1], pd[kMaxDegreeDepth + 1];
  const BiasCorrectionOptions& o = options_;
  legendre(u / o.half_u_mm, degree_uv, pu);
  legendre(v / o.half_v_mm, degree_uv, pv);
  legendre(2 * d / o.max_depth_mm - 1, o.degree_depth, pd);
  int k = 0;
  for (int i = 0; i <= degree_uv; ++i) {
    for (int j = 0; j <= degree_uv; ++j) {
      for (int l = 0; l <= o.degree_depth; ++l) out[k++] = pu[i] * pv[j] * pd[l];
    }
  }
}

Result<BiasCorrection> BiasCorrection::fit(std::span<const ContactEstimate> estimates,
                                           std::span<const double> true_u_mm,
                                           std::span<const double> true_v_mm,
                                           std::span<const double> true_depth_mm,
                                           const BiasCorrectionOptions& options) {
  const BiasCorrectionOptions& o = options;
  if (o.degree_uv < 0 || o.degree_uv > kMaxDegreeUv || o.depth_degree_uv > kMaxDegreeUv ||
      o.degree_depth < 0 || o.degree_depth > kMaxDegreeDepth || !(o.half_u_mm > 0) ||
      !(o.half_v_mm > 0) || !(o.max_depth_mm > 0) || !(o.ridge >= 0)) {
    return make_error(ErrorCode::kInvalidArgument, "bias correction: bad options");
  }
  const std::size_t n = estimates.size();
  if (true_u_mm.size() != n || true_v_mm.size() != n || true_depth_mm.size() != n) {
    return make_error(ErrorCode::kInvalidArgument,
                      "bias correction: estimates and truth differ in length");
  }
  BiasCorrection c;
  c.options_ = o;
  c.size_terms();
  // The samples the fit learns from: deep enough (estimate and truth), finite, not a gross miss.
  auto fitted = [&](std::size_t i) {
    const ContactEstimate& e = estimates[i];
    return e.valid() && e.depth_mm >= o.min_depth_mm && true_depth_mm[i] >= o.min_depth_mm &&
           std::isfinite(true_u_mm[i]) && std::isfinite(true_v_mm[i]) &&
           std::hypot(true_u_mm[i] - e.u_mm, true_v_mm[i] - e.v_mm) < o.outlier_mm;
  };
  for (std::size_t i = 0; i < n; ++i) c.samples_ += fitted(i) ? 1 : 0;
  const int most = std::max(c.terms_, c.depth_terms_);
  if (c.samples_ < 4 * most) {
    return make_error(ErrorCode::kDegenerate, "bias correction: " + std::to_string(c.samples_) +
                                                  " usable samples (deep enough, valid) for " +
                                                  std::to_string(most) + " terms; need at least " +
                                                  std::to_string(4 * most));
  }
  // Ridge-regularised least squares of the parts in `columns` (0 u, 1 v, 2 depth) on the basis
  // of `degree_uv`, into `into` (t coefficients each, in order).
  auto solve = [&](int degree_uv, std::initializer_list<int> columns, double* into) -> Status {
    const int t = terms_of(degree_uv, o.degree_depth);
    const auto cols = static_cast<int>(columns.size());
    Eigen::MatrixXd ata = Eigen::MatrixXd::Zero(t, t);
    Eigen::MatrixXd atb = Eigen::MatrixXd::Zero(t, cols);
    std::vector<double> phi(static_cast<std::size_t>(t));
    for (std::size_t i = 0; i < n; ++i) {
      const ContactEstimate& e = estimates[i];
      if (!fitted(i)) continue;
      c.basis(e.u_mm, e.v_mm, e.depth_mm, degree_uv, phi.data());
      const Eigen::Map<const Eigen::VectorXd> p(phi.data(), t);
      ata.selfadjointView<Eigen::Lower>().rankUpdate(p);
      const double r[3] = {true_u_mm[i] - e.u_mm, true_v_mm[i] - e.v_mm,
                           true_depth_mm[i] - e.depth_mm};
      int k = 0;
      for (int col : columns) atb.col(k++) += p * r[col];
    }
    ata.triangularView<Eigen::Upper>() = ata.transpose();
    const double lambda = o.ridge * ata.diagonal().mean();
    ata.diagonal().array() += lambda;
    Eigen::LDLT<Eigen::MatrixXd> ldlt(ata);
    if (ldlt.info() != Eigen::Success) {
      return make_error(ErrorCode::kDegenerate, "bias correction: normal equations are singular");
    }
    const Eigen::MatrixXd coef = ldlt.solve(atb);
    if (!coef.allFinite()) {
      return make_error(ErrorCode::kDegenerate, "bias correction: non-finite solution");
    }
    for (int k = 0; k < cols; ++k) {
      for (int j = 0; j < t; ++j) into[k * t + j] = coef(j, k);
    }
    return Status();
  };
  c.coef_.resize(static_cast<std::size_t>(2 * c.terms_ + c.depth_terms_));
  if (o.depth_uv() == o.degree_uv) {
    const Status s = solve(o.degree_uv, {0, 1, 2}, c.coef_.data());
    if (!s.ok()) return s.error();
  } else {
    Status s = solve(o.degree_uv, {0, 1}, c.coef_.data());
    if (s.ok()) s = solve(o.depth_uv(), {2}, c.coef_.data() + 2 * c.terms_);
    if (!s.ok()) return s.error();
  }
  double sum2 = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const ContactEstimate& e = estimates[i];
    if (!fitted(i)) continue;
    const ContactEstimate f = c.apply(e);
    sum2 += (f.u_mm - e.u_mm) * (f.u_mm - e.u_mm) + (f.v_mm - e.v_mm) * (f.v_mm - e.v_mm);
  }
  c.rms_correction_mm_ = std::sqrt(sum2 / c.samples_);
  return c;
}

Result<CorrectionCheck> BiasCorrection::cross_validate(std::span<const ContactEstimate> estimates,
                                                       std::span<const double> true_u_mm,
                                                       std::span<const double> true_v_mm,
                                                       std::span<const double> true_depth_mm,
                                                       const BiasCorrectionOptions& options) {
  constexpr int folds = kCheckFolds;
  const std::size_t n = estimates.size();
  if (true_u_mm.size() != n || true_v_mm.size() != n || true_depth_mm.size() != n) {
    return make_error(ErrorCode::kInvalidArgument,
                      "bias correction check: estimates and truth differ in length");
  }
  // The press places and their spacing: the median distance to the nearest other place.
  std::vector<std::pair<double, double>> places;
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isfinite(true_u_mm[i]) && std::isfinite(true_v_mm[i]))
      places.emplace_back(true_u_mm[i], true_v_mm[i]);
  }
  std::sort(places.begin(), places.end());
  places.erase(std::unique(places.begin(), places.end()), places.end());
  if (places.size() < 10 * folds) {
    return make_error(ErrorCode::kDegenerate,
                      "bias correction check: " + std::to_string(places.size()) +
                          " press places, need at least " + std::to_string(10 * folds));
  }
  std::vector<double> nearest;
  for (const auto& [u, v] : places) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& [u2, v2] : places) {
      const double d = std::hypot(u - u2, v - v2);
      if (d > 0) best = std::fmin(best, d);
    }
    nearest.push_back(best);
  }
  std::nth_element(nearest.begin(),
                   nearest.begin() + static_cast<std::ptrdiff_t>(nearest.size() / 2),
                   nearest.end());
  const double pitch = nearest[nearest.size() / 2];
  // Places are sorted by u: its extent is the ends'; v's is searched.
  const double lo_u = places.front().first, hi_u = places.back().first;
  double lo_v = places.front().second, hi_v = lo_v;
  for (const auto& [u, v] : places) {
    lo_v = std::fmin(lo_v, v);
    hi_v = std::fmax(hi_v, v);
  }
  // Cells of that pitch, in five folds by (i + 2 j) mod 5: no cell shares its fold with any of
  // its 8 neighbours, so every held-out press sits among fitted ones, as a new press would. A
  // place on an edge is held out too: its neighbours along the edge are fitted, so it lies
  // between them, and the edges are where the class's misses are largest (left out, the check
  // was blind to them). Only the corner places, outermost both ways, are always fitted (fold
  // -1): held out, they would ask the polynomial to extrapolate, which the correction fitted on
  // every press never does.
  auto fold_of = [&](double u, double v) {
    const bool edge_u = !(u > lo_u + 0.5 * pitch && u < hi_u - 0.5 * pitch);
    const bool edge_v = !(v > lo_v + 0.5 * pitch && v < hi_v - 0.5 * pitch);
    if (!std::isfinite(u) || !std::isfinite(v) || (edge_u && edge_v)) return -1;
    const auto ci = static_cast<int64_t>(std::floor(u / pitch + 0.5));
    const auto cj = static_cast<int64_t>(std::floor(v / pitch + 0.5));
    const int64_t f = (ci + 2 * cj) % folds;
    return static_cast<int>(f < 0 ? f + folds : f);
  };
  std::vector<int> fold(n);
  for (std::size_t i = 0; i < n; ++i) fold[i] = fold_of(true_u_mm[i], true_v_mm[i]);
  BiasCorrectionOptions both = options;
  both.correct_position = both.correct_depth = true;
  CorrectionCheck out;
  // Sample i judged by correction c, into the held-out figures' sums or the places' (the
  // depth's and each bin's XY sums; the means follow below).
  double sum_without = 0, sum_with = 0, sq_without = 0, sq_with = 0;
  auto judge = [&](const BiasCorrection& c, std::size_t i, int* count, double* dep_without,
                   double* dep_with, int* bin_samples, double* bin_without, double* bin_with,
                   bool held_out) {
    const ContactEstimate& e = estimates[i];
    if (!e.valid() || !(true_depth_mm[i] >= options.min_depth_mm) || !std::isfinite(true_u_mm[i]) ||
        !std::isfinite(true_v_mm[i])) {
      return;
    }
    const ContactEstimate k = c.apply(e);
    const double a = std::hypot(e.u_mm - true_u_mm[i], e.v_mm - true_v_mm[i]);
    const double b = std::hypot(k.u_mm - true_u_mm[i], k.v_mm - true_v_mm[i]);
    const int bin = static_cast<int>(
        std::fmin(CorrectionCheck::kDepthBins - 1, true_depth_mm[i] - options.min_depth_mm));
    ++bin_samples[bin];
    bin_without[bin] += a;
    bin_with[bin] += b;
    *dep_without += std::fabs(e.depth_mm - true_depth_mm[i]);
    *dep_with += std::fabs(k.depth_mm - true_depth_mm[i]);
    ++*count;
    if (held_out) {
      sum_without += a;
      sum_with += b;
      sq_without += a * a;
      sq_with += b * b;
    }
  };
  // Fits the correction on the samples `use` keeps; errors as fit().
  auto fit_on = [&](auto use) -> Result<BiasCorrection> {
    std::vector<ContactEstimate> est;
    std::vector<double> tu, tv, td;
    for (std::size_t i = 0; i < n; ++i) {
      if (!use(i)) continue;
      est.push_back(estimates[i]);
      tu.push_back(true_u_mm[i]);
      tv.push_back(true_v_mm[i]);
      td.push_back(true_depth_mm[i]);
    }
    return fit(est, tu, tv, td, both);
  };
  double dep_without = 0, dep_with = 0;
  for (int f = 0; f < folds; ++f) {
    Result<BiasCorrection> c = fit_on([&](std::size_t i) { return fold[i] != f; });
    if (!c.ok()) return c.error();
    for (std::size_t i = 0; i < n; ++i) {
      if (fold[i] != f) continue;
      judge(c.value(), i, &out.samples, &dep_without, &dep_with, out.bin_samples,
            out.xy_bin_without_mm, out.xy_bin_with_mm, true);
    }
  }
  // At the places: of each place's samples, in the order given, one in kCheckFolds judged (the
  // second of each five), the others fitted: on ramps, the fit has about as many samples as a
  // fold's.
  std::vector<int> seen(places.size(), 0);
  std::vector<char> judged(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const auto at =
        std::lower_bound(places.begin(), places.end(), std::make_pair(true_u_mm[i], true_v_mm[i]));
    if (at == places.end() || at->first != true_u_mm[i] || at->second != true_v_mm[i]) continue;
    judged[i] =
        static_cast<char>(seen[static_cast<std::size_t>(at - places.begin())]++ % folds == 1);
  }
  CorrectionCheck::AtPlaces& p = out.at_places;
  if (std::find(judged.begin(), judged.end(), 1) != judged.end()) {  // a place pressed twice
    // Too few samples left for the fit (places pressed only a few times each): no check at the
    // places, the held-out one alone judges.
    Result<BiasCorrection> c = fit_on([&](std::size_t i) { return judged[i] == 0; });
    if (!c.ok() && c.error().code != ErrorCode::kDegenerate) return c.error();
    for (std::size_t i = 0; c.ok() && i < n; ++i) {
      if (judged[i] == 0) continue;
      judge(c.value(), i, &p.samples, &p.depth_mean_without_mm, &p.depth_mean_with_mm,
            p.bin_samples, p.xy_bin_without_mm, p.xy_bin_with_mm, false);
    }
  }
  // How far new presses sit: the mean distance to the nearest place of a 64 x 64 lattice over
  // the places' extent, over a held-out place's mean distance to the nearest fitted one.
  double held_out_distance = 0, new_distance = 0;
  int held_out_places = 0;
  std::vector<int> place_fold;
  for (const auto& [u, v] : places) place_fold.push_back(fold_of(u, v));
  for (std::size_t a = 0; a < places.size(); ++a) {
    if (place_fold[a] < 0) continue;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t b = 0; b < places.size(); ++b) {
      if (place_fold[b] == place_fold[a]) continue;
      best = std::fmin(
          best, std::hypot(places[a].first - places[b].first, places[a].second - places[b].second));
    }
    held_out_distance += best;
    ++held_out_places;
  }
  constexpr int kLattice = 64;
  for (int a = 0; a < kLattice; ++a) {
    for (int b = 0; b < kLattice; ++b) {
      const double u = lo_u + (hi_u - lo_u) * (a + 0.5) / kLattice;
      const double v = lo_v + (hi_v - lo_v) * (b + 0.5) / kLattice;
      double best = std::numeric_limits<double>::infinity();
      for (const auto& [u2, v2] : places) best = std::fmin(best, std::hypot(u - u2, v - v2));
      new_distance += best;
    }
  }
  held_out_distance /= std::max(held_out_places, 1);
  new_distance /= kLattice * kLattice;
  out.new_press_share =
      held_out_distance > 0 ? std::clamp(new_distance / held_out_distance, 0.0, 1.0) : 1.0;
  if (out.samples > 0) {
    out.xy_mean_without_mm = sum_without / out.samples;
    out.xy_mean_with_mm = sum_with / out.samples;
    out.explained = sq_without > 0 ? 1 - sq_with / sq_without : 0;
    out.depth_mean_without_mm = dep_without / out.samples;
    out.depth_mean_with_mm = dep_with / out.samples;
  }
  if (p.samples > 0) {
    p.depth_mean_without_mm /= p.samples;
    p.depth_mean_with_mm /= p.samples;
  }
  for (int b = 0; b < CorrectionCheck::kDepthBins; ++b) {
    if (out.bin_samples[b] > 0) {
      out.xy_bin_without_mm[b] /= out.bin_samples[b];
      out.xy_bin_with_mm[b] /= out.bin_samples[b];
    }
    if (p.bin_samples[b] > 0) {
      p.xy_bin_without_mm[b] /= p.bin_samples[b];
      p.xy_bin_with_mm[b] /= p.bin_samples[b];
    }
  }
  return out;
}

namespace {

// with / without, or nothing when there is no figure to divide.
std::optional<double> ratio_of(int samples, double without, double with) {
  if (samples == 0 || !(without > 0)) return std::nullopt;
  return with / without;
}

// The mean over depth bins of the XY ratio `share` of the way from the places' to the held-out
// places' (the held-out one alone where the places have none; share 1: it alone).
double blended_xy_ratio(const CorrectionCheck& c, double share) {
  double sum = 0;
  int bins = 0;
  for (int b = 0; b < CorrectionCheck::kDepthBins; ++b) {
    const std::optional<double> h =
        ratio_of(c.bin_samples[b], c.xy_bin_without_mm[b], c.xy_bin_with_mm[b]);
    if (!h) continue;
    const std::optional<double> p =
        ratio_of(c.at_places.bin_samples[b], c.at_places.xy_bin_without_mm[b],
                 c.at_places.xy_bin_with_mm[b]);
    sum += p ? *p + share * (*h - *p) : *h;
    ++bins;
  }
  return bins > 0 ? sum / bins : 1.0;
}

}  // namespace

double CorrectionCheck::xy_ratio() const {
  return blended_xy_ratio(*this, new_press_share);
}
double CorrectionCheck::held_out_xy_ratio() const {
  return blended_xy_ratio(*this, 1.0);
}
double CorrectionCheck::at_places_xy_ratio() const {
  return blended_xy_ratio(*this, 0.0);
}

double CorrectionCheck::depth_ratio() const {
  const std::optional<double> h = ratio_of(samples, depth_mean_without_mm, depth_mean_with_mm);
  if (!h) return 1.0;
  const std::optional<double> p =
      ratio_of(at_places.samples, at_places.depth_mean_without_mm, at_places.depth_mean_with_mm);
  return p ? *p + new_press_share * (*h - *p) : *h;
}

std::string CorrectionCheck::held_out_text(int degree) const {
  char places[96] = "no check at the places";
  if (at_places.samples > 0) {
    std::snprintf(places, sizeof places, "at the places x %.3f; new presses x %.3f",
                  at_places_xy_ratio(), xy_ratio());
  }
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "held out at degree %d: XY %.3f -> %.3f mm (x %.3f by depth bin; %s), depth %.3f "
                "-> %.3f mm (new presses x %.3f)",
                degree, xy_mean_without_mm, xy_mean_with_mm, held_out_xy_ratio(), places,
                depth_mean_without_mm, depth_mean_with_mm, depth_ratio());
  return buf;
}

Result<BiasCorrection::Choice> BiasCorrection::choose(std::span<const ContactEstimate> estimates,
                                                      std::span<const double> true_u_mm,
                                                      std::span<const double> true_v_mm,
                                                      std::span<const double> true_depth_mm,
                                                      const BiasCorrectionOptions& base,
                                                      std::span<const int> degrees_uv) {
  if (degrees_uv.empty()) {
    return make_error(ErrorCode::kInvalidArgument, "bias correction choice: no degree to try");
  }
  Choice best;
  // The degree of each part where it helps most; -1 where it helps at no degree.
  int position_at = -1, depth_at = -1;
  std::optional<Error> too_few;  // the first degree the samples could not fit
  for (std::size_t k = 0; k < degrees_uv.size(); ++k) {
    BiasCorrectionOptions o = base;
    o.degree_uv = degrees_uv[k];
    o.depth_degree_uv = -1;
    Result<CorrectionCheck> c = cross_validate(estimates, true_u_mm, true_v_mm, true_depth_mm, o);
    if (!c.ok() && c.error().code == ErrorCode::kDegenerate) {
      best.skipped.emplace_back(degrees_uv[k], c.error().message);
      if (!too_few) too_few = c.error();
      continue;
    }
    if (!c.ok()) return c.error();
    best.tried.emplace_back(degrees_uv[k], c.value());
    const auto at = static_cast<int>(best.tried.size()) - 1;
    if (c->helps_position() &&
        (position_at < 0 || c->xy_ratio() < best.tried[position_at].second.xy_ratio())) {
      position_at = at;
    }
    if (c->helps_depth() &&
        (depth_at < 0 || c->depth_ratio() < best.tried[depth_at].second.depth_ratio())) {
      depth_at = at;
    }
  }
  if (best.tried.empty()) return *too_few;
  // The position's degree leads; a depth at the same degree needs no degree of its own.
  const int lead = position_at >= 0 ? position_at : std::max(depth_at, 0);
  best.options = base;
  best.options.degree_uv = best.tried[static_cast<std::size_t>(lead)].first;
  best.options.depth_degree_uv =
      depth_at >= 0 && depth_at != lead ? best.tried[static_cast<std::size_t>(depth_at)].first : -1;
  best.options.correct_position = position_at >= 0;
  best.options.correct_depth = depth_at >= 0;
  // The parts are fitted apart: the position's held-out errors at its degree and the depth's at
  // its own are what the pair gives.
  best.check = best.tried[static_cast<std::size_t>(lead)].second;
  if (depth_at >= 0) {
    const CorrectionCheck& d = best.tried[static_cast<std::size_t>(depth_at)].second;
    best.check.depth_mean_with_mm = d.depth_mean_with_mm;
    best.check.at_places.depth_mean_with_mm = d.at_places.depth_mean_with_mm;
  }
  return best;
}

std::string BiasCorrection::Choice::degree_text() const {
  const BiasCorrectionOptions& o = options;
  if (o.depth_uv() == o.degree_uv) return "degree " + std::to_string(o.degree_uv);
  return "degree " + std::to_string(o.degree_uv) + " (position), " + std::to_string(o.depth_uv()) +
         " (depth)";
}

std::string BiasCorrection::Choice::summary_text() const {
  const CorrectionCheck& c = check;
  char buf[320];
  std::snprintf(buf, sizeof buf,
                "XY mean %.3f -> %.3f mm (explains %.0f %% of the squared error), depth mean %.3f "
                "-> %.3f mm; as new presses will meet it, XY x %.3f by depth bin, depth x %.3f: %s "
                "the position, %s the depth",
                c.xy_mean_without_mm, c.xy_mean_with_mm, 100 * c.explained, c.depth_mean_without_mm,
                c.depth_mean_with_mm, c.xy_ratio(), c.depth_ratio(),
                options.correct_position ? "corrects" : "keeps",
                options.correct_depth ? "corrects" : "keeps");
  return buf;
}

ContactEstimate BiasCorrection::apply(const ContactEstimate& e) const {
  if (!e.valid() || !(e.depth_mm >= options_.min_depth_mm)) return e;
  double phi[kMaxTerms];
  double d[3] = {0, 0, 0};
  basis(e.u_mm, e.v_mm, e.depth_mm, options_.degree_uv, phi);
  for (int k = 0; k < 2; ++k) {
    const double* c = coef_.data() + static_cast<std::ptrdiff_t>(k) * terms_;
    for (int j = 0; j < terms_; ++j) d[k] += c[j] * phi[j];
  }
  if (options_.depth_uv() != options_.degree_uv) {
    basis(e.u_mm, e.v_mm, e.depth_mm, options_.depth_uv(), phi);
  }
  const double* cd = coef_.data() + static_cast<std::ptrdiff_t>(2) * terms_;
  for (int j = 0; j < depth_terms_; ++j) d[2] += cd[j] * phi[j];
  ContactEstimate out = e;
  if (options_.correct_position) {
    out.u_mm += d[0];
    out.v_mm += d[1];
  }
  if (options_.correct_depth) out.depth_mm += d[2];
  if (!std::isfinite(out.u_mm) || !std::isfinite(out.v_mm) || !std::isfinite(out.depth_mm)) {
    return e;
  }
  return out;
}

}  // namespace skinbus::estimators
