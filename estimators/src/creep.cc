#include "skinbus/estimators/creep.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <utility>

namespace skinbus::estimators {

namespace {

// One step of a lag of time constant `time_s` to a sample `h` seconds after the previous one
// (NaN before the first), the depth taken linear between the press's previous sample (depth d0)
// and this one (d1), exact for a ramp: q1 = e q0 + (g - e) d0 + (1 - g) d1, e = exp(-h / tau),
// g = (tau / h)(1 - e). A press's first sample: q0 relaxed over the time since the previous
// call (the indenter off the patch), e = g = 1 (q1 = q0).
struct Step {
  double e = 1, g = 1;
  double lag(double q0, double d0, double d1) const { return e * q0 + (g - e) * d0 + (1 - g) * d1; }
};
Step advance(double time_s, double h, bool same_press, double* lag_mm) {
  Step s;
  if (h > 0) {
    const double x = h / time_s;
    if (same_press) {
      s.e = std::exp(-x);
      s.g = -std::expm1(-x) / x;
    } else {
      *lag_mm *= std::exp(-x);
    }
  }
  return s;
}

bool new_press(const sim::Dataset& d, std::size_t r) {
  return r == 0 || d.press.empty() || d.press[r] < 0 || d.press[r] != d.press[r - 1];
}

// The press that starts at row r: its rows [r, end), and whether it is a ramp (3 or more rows
// at increasing times), as fit_creep and held_presses read a recording.
struct PressRows {
  std::size_t end;
  bool ramp;
};
PressRows press_rows(const sim::Dataset& d, std::size_t r) {
  std::size_t end = r + 1;
  bool increasing = std::isfinite(d.t_s[r]);
  while (end < d.rows() && !new_press(d, end)) {
    increasing = increasing && d.t_s[end] > d.t_s[end - 1];
    ++end;
  }
  return {end, increasing && end - r >= 3};
}

// A press of one row: a static press, held till the lag caught up (bent by its depth).
bool static_press(const sim::Dataset& d, std::size_t r) {
  return new_press(d, r) && (r + 1 == d.rows() || new_press(d, r + 1));
}

// Solves the n x n system a x = b (row-major a, n <= N) by Gaussian elimination with partial
// pivoting; false when singular.
template <int N>
bool solve(int n, double (&a)[N][N], double (&b)[N], double (&x)[N]) {
  for (int c = 0; c < n; ++c) {
    int p = c;
    for (int r = c + 1; r < n; ++r) {
      if (std::fabs(a[r][c]) > std::fabs(a[p][c])) p = r;
    }
    if (!(std::fabs(a[p][c]) > 1e-12)) return false;
    std::swap(a[p], a[c]);
    std::swap(b[p], b[c]);
    for (int r = c + 1; r < n; ++r) {
      const double k = a[r][c] / a[c][c];
      for (int j = c; j < n; ++j) a[r][j] -= k * a[c][j];
      b[r] -= k * b[c];
    }
  }
  for (int r = n - 1; r >= 0; --r) {
    double v = b[r];
    for (int j = r + 1; j < n; ++j) v -= a[r][j] * x[j];
    x[r] = v / a[r][r];
  }
  return true;
}

// The Gram matrix of (z, e) over rows, for a regression of e on the N - 1 terms z (z[0] = 1:
// its first entry counts the rows), and the squared residual of e - w . z.
template <int N>
struct Gram {
  double g[N][N] = {};
  double n() const { return g[0][0]; }
  void add(const double (&z)[N]) {
    for (int i = 0; i < N; ++i) {
      for (int j = 0; j < N; ++j) g[i][j] += z[i] * z[j];
    }
  }
  Gram& operator+=(const Gram& o) {
    for (int i = 0; i < N; ++i) {
      for (int j = 0; j < N; ++j) g[i][j] += o.g[i][j];
    }
    return *this;
  }
  double sse(const double (&w)[N - 1]) const {
    double s = g[N - 1][N - 1];
    for (int i = 0; i < N - 1; ++i) {
      s -= 2 * w[i] * g[i][N - 1];
      for (int j = 0; j < N - 1; ++j) s += w[i] * w[j] * g[i][j];
    }
    return std::max(0.0, s);
  }
};

// The regression of e = bend - depth on z = (1, d, d^2, x) over one fold: a static model's own
// depth bias (a quadratic in the depth: the first fit took part of the lag for static physics)
// and f times the law's lag term x.
struct Sums : Gram<5> {
  void add(double d, double x, double e) { Gram<5>::add({1, d, d * d, x, e}); }
  // The coefficients (bias c0..c2, fraction f in [0, 0.95]; f = 0 without the lag).
  struct Coefficients {
    double w[4] = {0, 0, 0, 0};
    double fraction() const { return w[3]; }
  };
  Coefficients fit(bool with_lag) const {
    Coefficients out;
    double a[4][4], b[4], x[4] = {0, 0, 0, 0};
    if (with_lag) {
      for (int i = 0; i < 4; ++i) {
        for (int j = 0; j < 4; ++j) a[i][j] = g[i][j];
        b[i] = g[i][4];
      }
      if (solve(4, a, b, x)) out.w[3] = std::clamp(x[3], 0.0, 0.95);
    }
    for (int i = 0; i < 3; ++i) {  // the bias, given the fraction
      for (int j = 0; j < 3; ++j) a[i][j] = g[i][j];
      b[i] = g[i][4] - out.w[3] * g[i][3];
    }
    if (solve(3, a, b, x)) {
      for (int i = 0; i < 3; ++i) out.w[i] = x[i];
    }
    return out;
  }
  double sse(const Coefficients& c) const { return Gram<5>::sse(c.w); }
};

// The time constants searched: this many log-spaced steps over the options' range.
constexpr int kTauGrid = 40;

// The minimum of `cost` over [a, b] by golden section (`iterations` steps): the interval's middle.
template <typename Cost>
double golden_min(const Cost& cost, double a, double b, int iterations) {
  const double g = (std::sqrt(5.0) - 1) / 2;
  for (int it = 0; it < iterations; ++it) {
    const double x1 = b - g * (b - a), x2 = a + g * (b - a);
    if (cost(x1) < cost(x2)) {
      b = x2;
    } else {
      a = x1;
    }
  }
  return (a + b) / 2;
}

// The same regression with two lags: e on z = (1, d, d^2, x, x_s), the fast lag's term and the
// slow one's.
struct Sums2 : Gram<6> {
  // (c0, c1, c2, f, f_s); false unless both fractions are positive and sum to at most 0.95.
  bool fit(double (&w)[5]) const {
    double a[5][5], b[5], x[5] = {0, 0, 0, 0, 0};
    for (int i = 0; i < 5; ++i) {
      for (int j = 0; j < 5; ++j) a[i][j] = g[i][j];
      b[i] = g[i][5];
    }
    if (!solve(5, a, b, x) || !(x[3] > 0) || !(x[4] > 0) || !(x[3] + x[4] <= 0.95)) return false;
    for (int i = 0; i < 5; ++i) w[i] = x[i];
    return true;
  }
  double cost() const {  // the least squared residual; infinite without a valid fit
    double w[5];
    return fit(w) ? sse(w) : std::numeric_limits<double>::infinity();
  }
};

}  // namespace

double CreepCompensator::depth_mm(double t_s, double bend_mm, bool same_press) {
  if (law_.none() || !std::isfinite(t_s) || !std::isfinite(bend_mm)) return bend_mm;
  const double h = t_s - last_t_s_;  // NaN before the first sample
  const Step st = advance(law_.time_s, h, same_press, &lag_mm_);
  const Step ss = advance(law_.slow_time_s, h, same_press, &slow_lag_mm_);
  last_t_s_ = t_s;
  if (!same_press) last_depth_mm_ = 0;
  // b1 = (1 - f g - f_s g_s) d1 + f (e q0 + (g - e) d0) + f_s (e_s q_s0 + (g_s - e_s) d0), solved
  // for d1.
  const double f = law_.fraction, fs = law_.slow_fraction, d0 = last_depth_mm_;
  const double depth = (bend_mm - f * (st.e * lag_mm_ + (st.g - st.e) * d0) -
                        fs * (ss.e * slow_lag_mm_ + (ss.g - ss.e) * d0)) /
                       (1 - f * st.g - fs * ss.g);
  lag_mm_ = st.lag(lag_mm_, d0, depth);
  slow_lag_mm_ = ss.lag(slow_lag_mm_, d0, depth);
  last_depth_mm_ = depth;
  return depth;
}

sim::Dataset bent_dataset(const CreepLaw& law, const sim::Dataset& d) {
  sim::Dataset bent = d;
  if (!law.none()) bent.depth_mm = creep_bend_mm(law, d);
  return bent;
}

void undo_creep(const CreepLaw& law, const sim::Dataset& d, std::span<ContactEstimate> estimates) {
  if (law.none()) return;
  CreepCompensator comp(law);
  const std::size_t n = std::min(d.rows(), estimates.size());
  for (std::size_t r = 0; r < n; ++r) {
    ContactEstimate& e = estimates[r];
    if (!e.valid() || static_press(d, r)) continue;
    e.depth_mm = comp.depth_mm(d.t_s[r], e.depth_mm, !new_press(d, r));
  }
}

std::vector<double> creep_bend_mm(const CreepLaw& law, const sim::Dataset& d) {
  std::vector<double> bend(d.rows(), std::numeric_limits<double>::quiet_NaN());
  double lag = 0, slow_lag = 0, last_depth = 0, last_t = std::numeric_limits<double>::quiet_NaN();
  const double f = law.fraction, fs = law.slow_fraction;
  for (std::size_t r = 0; r < d.rows(); ++r) {
    const double t = d.t_s[r], depth = d.depth_mm[r];
    if (!std::isfinite(depth)) continue;
    if (law.none() || static_press(d, r)) {
      bend[r] = depth;
      continue;
    }
    if (!std::isfinite(t)) continue;
    const bool same = !new_press(d, r);
    const double h = t - last_t;
    last_t = t;
    const double d0 = same ? last_depth : 0.0;
    const Step st = advance(law.time_s, h, same, &lag);  // relaxes `lag` between presses
    lag = st.lag(lag, d0, depth);
    bend[r] = (1 - f) * depth + f * lag;
    if (fs > 0) {
      const Step ss = advance(law.slow_time_s, h, same, &slow_lag);
      slow_lag = ss.lag(slow_lag, d0, depth);
      bend[r] += fs * (slow_lag - depth);
    }
    last_depth = depth;
  }
  return bend;
}

int held_presses(const sim::Dataset& d, double min_hold_s, double tolerance_mm) {
  int held = 0;
  for (std::size_t r = 0; r < d.rows();) {
    const PressRows p = press_rows(d, r);
    if (p.ramp) {
      double deepest = d.depth_mm[r];
      for (std::size_t k = r + 1; k < p.end; ++k) deepest = std::fmax(deepest, d.depth_mm[k]);
      double first = std::numeric_limits<double>::quiet_NaN(), last = first;
      for (std::size_t k = r; k < p.end; ++k) {
        if (!(d.depth_mm[k] >= deepest - tolerance_mm)) continue;
        if (std::isnan(first)) first = d.t_s[k];
        last = d.t_s[k];
      }
      held += last - first >= min_hold_s ? 1 : 0;
    }
    r = p.end;
  }
  return held;
}

std::string CreepFit::summary_text() const {
  char buf[320];
  if (!kept) {
    std::snprintf(buf, sizeof buf, "creep: none kept (%s)", why.c_str());
  } else if (law.slow_fraction > 0) {
    std::snprintf(buf, sizeof buf,
                  "creep: %.3f of the bend lags the press by %.3f s and %.3f by %.3f s; depth "
                  "residual on held-out presses %.4f -> %.4f mm RMS (one lag: %.4f; %d ramps, %d "
                  "samples)",
                  law.fraction, law.time_s, law.slow_fraction, law.slow_time_s,
                  held_out_rms_before_mm, held_out_rms_after_mm, held_out_rms_one_lag_mm, presses,
                  rows);
  } else {
    std::snprintf(buf, sizeof buf,
                  "creep: %.3f of the bend lags the press by %.3f s; depth residual on held-out "
                  "presses %.4f -> %.4f mm RMS (%d ramps, %d samples)",
                  law.fraction, law.time_s, held_out_rms_before_mm, held_out_rms_after_mm, presses,
                  rows);
  }
  return buf;
}

Result<CreepFit> fit_creep(const sim::PatchModel& model, const sim::Dataset& d,
                           const CreepFitOptions& opt) {
  const int nc = model.channel_count();
  if (d.channels() != nc) {
    return make_error(ErrorCode::kInvalidArgument,
                      "creep fit: the dataset's channel count differs from the model's (" +
                          std::to_string(nc) + ")");
  }
  CreepFit out;
  const ChannelNoise noise =
      opt.noise.xy_ut > 0 && opt.noise.z_ut > 0 ? opt.noise : ChannelNoise::of(model.design());

  // Ramps: presses of at least 3 samples at increasing times. Each row's fold is its press's
  // parity among them; -1: not in a ramp.
  std::vector<int> fold(d.rows(), -1);
  std::size_t candidates = 0;
  for (std::size_t r = 0; r < d.rows();) {
    const PressRows p = press_rows(d, r);
    if (p.ramp) {
      for (std::size_t k = r; k < p.end; ++k) fold[k] = out.presses % 2;
      ++out.presses;
    }
    r = p.end;
  }
  auto usable = [&](std::size_t r) {
    if (fold[r] < 0 || !(d.depth_mm[r] >= opt.min_depth_mm) || !std::isfinite(d.depth_mm[r]) ||
        !std::isfinite(d.u_mm[r]) || !std::isfinite(d.v_mm[r])) {
      return false;
    }
    int known = 0;
    for (int c = 0; c < nc; ++c) known += std::isfinite(d.field(r)[c]) ? 1 : 0;
    return 2 * known >= nc;
  };
  for (std::size_t r = 0; r < d.rows(); ++r) candidates += usable(r) ? 1 : 0;
  if (out.presses < 4 || candidates < 40) {
    out.why = "no ramps: fewer than 4 presses of 3 or more samples in time order";
    return out;
  }

  // Each inverted sample's bend: depth alone fitted by Gauss-Newton at the recorded place.
  const std::size_t stride =
      std::max<std::size_t>(1, (candidates + static_cast<std::size_t>(opt.max_rows) - 1) /
                                   static_cast<std::size_t>(std::max(1, opt.max_rows)));
  std::vector<double> bend(d.rows(), std::numeric_limits<double>::quiet_NaN());
  std::vector<double> jac(static_cast<std::size_t>(nc) * 3), field(static_cast<std::size_t>(nc));
  std::size_t seen = 0;
  for (std::size_t r = 0; r < d.rows(); ++r) {
    if (!usable(r) || seen++ % stride != 0) continue;
    const double* y = d.field(r);
    double b = d.depth_mm[r];
    bool converged = false;
    for (int it = 0; it < 10 && !converged; ++it) {
      model.contact_jacobian({d.u_mm[r], d.v_mm[r], b, opt.tip_radius_mm}, jac, field);
      double jj = 0, jr = 0;
      for (int c = 0; c < nc; ++c) {
        if (!std::isfinite(y[c])) continue;
        const double w = 1 / (noise.sigma(c) * noise.sigma(c));
        const double j = jac[static_cast<std::size_t>(c) * 3 + 2];
        jj += w * j * j;
        jr += w * j * (y[c] - field[static_cast<std::size_t>(c)]);
      }
      if (!(jj > 0)) break;
      const double step = std::clamp(jr / jj, -1.0, 1.0);
      b = std::max(0.0, b + step);
      converged = std::fabs(step) < 1e-5;
    }
    if (converged && std::isfinite(b)) {
      bend[r] = b;
      ++out.rows;
    }
  }
  if (out.rows < 40) {
    out.why = "too few samples whose depth alone could be fitted";
    return out;
  }

  // The regression's sums per fold at one time constant: the law's lag from the recorded depths
  // (the bend of a law whose whole bend lags, creep_bend_mm; bend - depth = f x).
  auto sums_at = [&](double tau) {
    std::array<Sums, 2> s;
    const std::vector<double> lag = creep_bend_mm({1, tau}, d);
    for (std::size_t r = 0; r < d.rows(); ++r) {
      if (!std::isfinite(bend[r]) || !std::isfinite(lag[r])) continue;
      const double depth = d.depth_mm[r];
      s[static_cast<std::size_t>(fold[r])].add(depth, lag[r] - depth, bend[r] - depth);
    }
    return s;
  };
  auto pooled = [](const auto& s) {  // both folds' sums (Sums, or the two lags' Sums2)
    auto p = s[0];
    p += s[1];
    return p;
  };
  const double lo = std::log(opt.min_time_s), hi = std::log(opt.max_time_s);
  // The time constant of least squared residual for the rows `pick` selects (a fold, or both):
  // a log grid, then golden section between the best point's neighbours.
  auto best_tau = [&](auto pick) {
    auto cost = [&](double log_tau) {
      const Sums s = pick(sums_at(std::exp(log_tau)));
      return s.sse(s.fit(true));
    };
    int best = 0;
    double best_cost = std::numeric_limits<double>::infinity();
    for (int i = 0; i <= kTauGrid; ++i) {
      const double c = cost(lo + (hi - lo) * i / kTauGrid);
      if (c < best_cost) {
        best_cost = c;
        best = i;
      }
    }
    return std::exp(golden_min(cost, lo + (hi - lo) * std::max(0, best - 1) / kTauGrid,
                               lo + (hi - lo) * std::min(kTauGrid, best + 1) / kTauGrid, 30));
  };

  // Held out: each fold's law (its own tau, fraction and bias) on the other fold's rows; before:
  // the fold's bias alone.
  double before = 0, after = 0, n = 0;
  for (std::size_t k = 0; k < 2; ++k) {
    const double tau = best_tau([k](const std::array<Sums, 2>& s) { return s[k]; });
    const std::array<Sums, 2> s = sums_at(tau);
    const Sums& fit = s[k];
    const Sums& held = s[1 - k];
    before += held.sse(fit.fit(false));
    after += held.sse(fit.fit(true));
    n += held.n();
  }
  out.held_out_rms_before_mm = std::sqrt(before / n);
  out.held_out_rms_after_mm = out.held_out_rms_one_lag_mm = std::sqrt(after / n);
  const double tau = best_tau(pooled);
  const double f = pooled(sums_at(tau)).fit(true).fraction();
  if (!(after <= (1 - opt.min_gain) * before) || !(f > 0)) {
    out.why = "it does not lower the depth residual of held-out presses by " +
              std::to_string(static_cast<int>(std::lround(100 * opt.min_gain))) + " %";
    return out;
  }
  out.law = {f, tau};
  out.kept = true;
  if (!opt.slow_lag) return out;

  // Two lags: the rows with a bend, and each grid time constant's lag term at them.
  std::vector<std::size_t> rows;
  for (std::size_t r = 0; r < d.rows(); ++r) {
    if (std::isfinite(bend[r])) rows.push_back(r);
  }
  auto lag_terms = [&](double tau_s) {  // the lag's term x = q - d at `rows`; NaN: none
    const std::vector<double> q = creep_bend_mm({1, tau_s}, d);
    std::vector<double> x(rows.size());
    for (std::size_t i = 0; i < rows.size(); ++i) x[i] = q[rows[i]] - d.depth_mm[rows[i]];
    return x;
  };
  std::vector<std::vector<double>> grid_terms(kTauGrid + 1);
  for (int i = 0; i <= kTauGrid; ++i) {
    grid_terms[static_cast<std::size_t>(i)] = lag_terms(std::exp(lo + (hi - lo) * i / kTauGrid));
  }
  auto sums2 = [&](const std::vector<double>& x, const std::vector<double>& xs) {
    std::array<Sums2, 2> s;
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const std::size_t r = rows[i];
      if (!std::isfinite(x[i]) || !std::isfinite(xs[i])) continue;
      const double depth = d.depth_mm[r];
      const double z[6] = {1, depth, depth * depth, x[i], xs[i], bend[r] - depth};
      s[static_cast<std::size_t>(fold[r])].add(z);
    }
    return s;
  };
  // The grid's pairs' sums, once for the three searches (each fold's, and both folds').
  struct GridPair {
    int i, j;
    std::array<Sums2, 2> sums;
  };
  std::vector<GridPair> grid_pairs;
  for (int i = 0; i < kTauGrid; ++i) {
    for (int j = i + 1; j <= kTauGrid; ++j) {
      grid_pairs.push_back({i, j,
                            sums2(grid_terms[static_cast<std::size_t>(i)],
                                  grid_terms[static_cast<std::size_t>(j)])});
    }
  }
  // The pair of times of least squared residual for the rows `pick` selects: the grid's pairs
  // (the slow time longer), then each time refined by golden section with the other held (and
  // still the shorter, or longer); with their lag terms. Times {0, 0}: no pair fits.
  struct Pair {
    std::array<double, 2> taus = {0, 0};
    std::array<std::vector<double>, 2> terms;
  };
  auto best_pair = [&](auto pick) {
    int bi = -1, bj = -1;
    double best_cost = std::numeric_limits<double>::infinity();
    for (const GridPair& gp : grid_pairs) {
      const double c = pick(gp.sums).cost();
      if (c < best_cost) {
        best_cost = c;
        bi = gp.i;
        bj = gp.j;
      }
    }
    if (bi < 0) return Pair{};
    std::array<double, 2> log_tau = {lo + (hi - lo) * bi / kTauGrid,
                                     lo + (hi - lo) * bj / kTauGrid};
    std::array<std::vector<double>, 2> terms = {grid_terms[static_cast<std::size_t>(bi)],
                                                grid_terms[static_cast<std::size_t>(bj)]};
    for (std::size_t which = 0; which < 2; ++which) {
      auto cost = [&](double lt) {
        if (which == 0 ? !(lt < log_tau[1]) : !(lt > log_tau[0])) {
          return std::numeric_limits<double>::infinity();
        }
        std::array<std::vector<double>, 2> t = terms;
        t[which] = lag_terms(std::exp(lt));
        return pick(sums2(t[0], t[1])).cost();
      };
      const double step = (hi - lo) / kTauGrid;
      const double mid = golden_min(cost, log_tau[which] - step, log_tau[which] + step, 20);
      if (cost(mid) <= cost(log_tau[which])) {
        log_tau[which] = mid;
        terms[which] = lag_terms(std::exp(mid));
      }
    }
    return Pair{{std::exp(log_tau[0]), std::exp(log_tau[1])}, std::move(terms)};
  };
  // Held out as one lag was: each fold's pair on the other fold's rows.
  double after2 = 0;
  for (std::size_t k = 0; k < 2; ++k) {
    const Pair pair = best_pair([k](const std::array<Sums2, 2>& s) { return s[k]; });
    if (!(pair.taus[0] > 0)) return out;  // no pair explains this fold: one lag
    const std::array<Sums2, 2> s = sums2(pair.terms[0], pair.terms[1]);
    double w[5];
    if (!s[k].fit(w)) return out;
    after2 += s[1 - k].sse(w);
  }
  if (!(after2 <= (1 - opt.min_gain) * after)) return out;
  const Pair pair = best_pair(pooled);
  double w[5];
  if (!(pair.taus[0] > 0) || !pooled(sums2(pair.terms[0], pair.terms[1])).fit(w)) return out;
  out.law = {w[3], pair.taus[0], w[4], pair.taus[1]};
  out.held_out_rms_after_mm = std::sqrt(after2 / n);
  return out;
}

}  // namespace skinbus::estimators
