#include "skinbus/estimators/bias_correction.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

namespace skinbus::estimators {
namespace {

constexpr int kMaxDegree = 16;
constexpr int kMaxDepthDegree = 6;
constexpr int kMaxTerms = (kMaxDegree + 1) * (kMaxDegree + 1) * (kMaxDepthDegree + 1);

// Legendre polynomials P0..Pn at x (clamped to [-1, 1]).
void legendre(double x, int n, double* p) {
  x = std::clamp(x, -1.0, 1.0);
  p[0] = 1;
  if (n >= 1) p[1] = x;
  for (int k = 2; k <= n; ++k) p[k] = ((2 * k - 1) * x * p[k - 1] - (k - 1) * p[k - 2]) / k;
}

}  // namespace

void BiasCorrection::basis(double u, double v, double d, double* out) const {
  double pu[kMaxDegree + 1], pv[kMaxDegree + 1], pd[kMaxDepthDegree + 1];
  const BiasCorrectionOptions& o = options_;
  legendre(u / o.half_u_mm, o.degree_uv, pu);
  legendre(v / o.half_v_mm, o.degree_uv, pv);
  legendre(2 * d / o.max_depth_mm - 1, o.degree_depth, pd);
  int k = 0;
  for (int i = 0; i <= o.degree_uv; ++i) {
    for (int j = 0; j <= o.degree_uv; ++j) {
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
  if (o.degree_uv < 0 || o.degree_uv > kMaxDegree || o.degree_depth < 0 ||
      o.degree_depth > kMaxDepthDegree || !(o.half_u_mm > 0) || !(o.half_v_mm > 0) ||
      !(o.max_depth_mm > 0) || !(o.ridge >= 0)) {
    return make_error(ErrorCode::kInvalidArgument, "bias correction: bad options");
  }
  const std::size_t n = estimates.size();
  if (true_u_mm.size() != n || true_v_mm.size() != n || true_depth_mm.size() != n) {
    return make_error(ErrorCode::kInvalidArgument,
                      "bias correction: estimates and truth differ in length");
  }
  BiasCorrection c;
  c.options_ = o;
  c.terms_ = (o.degree_uv + 1) * (o.degree_uv + 1) * (o.degree_depth + 1);
  const int t = c.terms_;
  Eigen::MatrixXd ata = Eigen::MatrixXd::Zero(t, t);
  Eigen::MatrixXd atb = Eigen::MatrixXd::Zero(t, 3);
  std::vector<double> phi(static_cast<std::size_t>(t));
  // The samples the fit learns from: deep enough (estimate and truth), finite, not a gross miss.
  auto fitted = [&](std::size_t i) {
    const ContactEstimate& e = estimates[i];
    return e.valid() && e.depth_mm >= o.min_depth_mm && true_depth_mm[i] >= o.min_depth_mm &&
           std::isfinite(true_u_mm[i]) && std::isfinite(true_v_mm[i]) &&
           std::hypot(true_u_mm[i] - e.u_mm, true_v_mm[i] - e.v_mm) < o.outlier_mm;
  };
  for (std::size_t i = 0; i < n; ++i) {
    const ContactEstimate& e = estimates[i];
    if (!fitted(i)) continue;
    c.basis(e.u_mm, e.v_mm, e.depth_mm, phi.data());
    const Eigen::Map<const Eigen::VectorXd> p(phi.data(), t);
    ata.selfadjointView<Eigen::Lower>().rankUpdate(p);
    const Eigen::Vector3d r(true_u_mm[i] - e.u_mm, true_v_mm[i] - e.v_mm,
                            true_depth_mm[i] - e.depth_mm);
    atb += p * r.transpose();
    ++c.samples_;
  }
  if (c.samples_ < 4 * t) {
    return make_error(ErrorCode::kDegenerate, "bias correction: " + std::to_string(c.samples_) +
                                                  " usable samples (deep enough, valid) for " +
                                                  std::to_string(t) + " terms; need at least " +
                                                  std::to_string(4 * t));
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
  c.coef_.resize(static_cast<std::size_t>(3 * t));
  for (int k = 0; k < 3; ++k) {
    for (int j = 0; j < t; ++j) c.coef_[static_cast<std::size_t>(k * t + j)] = coef(j, k);
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

ContactEstimate BiasCorrection::apply(const ContactEstimate& e) const {
  if (!e.valid() || !(e.depth_mm >= options_.min_depth_mm)) return e;
  double phi[kMaxTerms];
  basis(e.u_mm, e.v_mm, e.depth_mm, phi);
  double d[3] = {0, 0, 0};
  for (int k = 0; k < 3; ++k) {
    const double* c = coef_.data() + static_cast<std::ptrdiff_t>(k) * terms_;
    for (int j = 0; j < terms_; ++j) d[k] += c[j] * phi[j];
  }
  ContactEstimate out = e;
  out.u_mm += d[0];
  out.v_mm += d[1];
  out.depth_mm += d[2];
  if (!std::isfinite(out.u_mm) || !std::isfinite(out.v_mm) || !std::isfinite(out.depth_mm)) {
    return e;
  }
  return out;
}

}  // namespace skinbus::estimators
