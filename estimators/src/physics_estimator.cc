#include "skinbus/estimators/physics_estimator.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "jet_traits.h"

namespace skinbus::estimators {

namespace {

constexpr double kMinDepthMm = 1e-3;  // the fit's lower depth bound: no press moves nothing
constexpr double kMaxShearN = 100;    // the fit's shear bound, each component

// The unknowns of a fit: each contact's (u, v, depth[, shear u, v]) in turn, then the ambient
// offset (3; held at 0 unless fitted).
struct LeanLayout {
  int contacts = 1;
  bool shear = false;
  constexpr int per_contact() const { return shear ? 5 : 3; }
  constexpr int ambient_at() const { return contacts * per_contact(); }
  constexpr int size() const { return ambient_at() + 3; }
  // Whether unknown `k` is fitted (the ambient's only with `fit_ambient`), and how many are.
  constexpr bool fitted(int k, bool fit_ambient) const { return k < ambient_at() || fit_ambient; }
  constexpr int unknowns(bool fit_ambient) const { return fit_ambient ? size() : ambient_at(); }
};

// Unknowns of a single-contact fit with `options`.
int unknowns_of(const PhysicsOptions& options) {
  return LeanLayout{1, options.fit_shear}.unknowns(options.fit_ambient);
}

// Whitened residuals of one sample against N contacts and the ambient offset: parameter blocks
// (u, v, depth) of each contact, then the ambient offset (3). Masked channels give 0 with a zero
// Jacobian row, so the problem keeps one shape whatever is masked.
template <int N>
class ContactsResidual final : public ceres::CostFunction {
 public:
  ContactsResidual(const sim::PatchModel& model, const double* field, const uint8_t* ok,
                   const double* inv_sigma, const double* ambient_jac, double tip_radius_mm)
      : model_(model),
        field_(field),
        ok_(ok),
        inv_sigma_(inv_sigma),
        ambient_jac_(ambient_jac),
        tip_(tip_radius_mm),
        nc_(model.channel_count()) {
    set_num_residuals(nc_);
    for (int b = 0; b <= N; ++b) mutable_parameter_block_sizes()->push_back(3);
  }

  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    double f[kMaxChannels];
    double j[3 * N * kMaxChannels];
    const std::size_t n = static_cast<std::size_t>(nc_);
    bool want_jacobian = false;
    for (int blk = 0; jacobians != nullptr && blk < N; ++blk)
      want_jacobian |= jacobians[blk] != nullptr;
    if (want_jacobian) {
      // Forward-mode jets through the simulator's template (Ceres' jets, which compile to tighter
      // code there than sim's own dual numbers).
      using J = ceres::Jet<double, 3 * N>;
      sim::ContactT<J> c[N];
      for (int k = 0; k < N; ++k) {
        c[k] = {J(params[k][0], 3 * k), J(params[k][1], 3 * k + 1), J(params[k][2], 3 * k + 2),
                tip_};
      }
      J out[kMaxChannels];
      model_.contact_field_ut<J>(std::span<const sim::ContactT<J>>(c, N), out);
      for (std::size_t i = 0; i < n; ++i) {
        f[i] = out[i].a;
        for (std::size_t k = 0; k < 3 * N; ++k) {
          j[3 * N * i + k] = out[i].v[static_cast<Eigen::Index>(k)];
        }
      }
    } else {
      sim::Contact c[N];
      for (int k = 0; k < N; ++k) c[k] = {params[k][0], params[k][1], params[k][2], tip_};
      model_.contact_field_ut(std::span<const sim::Contact>(c, N), std::span<double>(f, n));
    }
    const double* b = params[N];
    for (int i = 0; i < nc_; ++i) {
      const double* a = ambient_jac_ + 3 * i;
      const double w = ok_[i] ? inv_sigma_[i] : 0.0;
      const double pred = f[i] + a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
      residuals[i] = ok_[i] ? (pred - field_[i]) * w : 0.0;
      if (jacobians == nullptr) continue;
      for (int blk = 0; blk < N; ++blk) {
        if (jacobians[blk] == nullptr) continue;
        for (int k = 0; k < 3; ++k) jacobians[blk][3 * i + k] = j[3 * N * i + 3 * blk + k] * w;
      }
      if (jacobians[N] != nullptr) {
        for (int k = 0; k < 3; ++k) jacobians[N][3 * i + k] = a[k] * w;
      }
    }
    for (int i = 0; i < nc_; ++i) {
      if (!std::isfinite(residuals[i])) return false;
    }
    return true;
  }

 private:
  const sim::PatchModel& model_;
  const double* field_;
  const uint8_t* ok_;
  const double* inv_sigma_;
  const double* ambient_jac_;
  double tip_;
  int nc_;
};

// What a fit of one sample works on: the channels it uses (the caller's mask and
// check_sample()'s), their weights (1 / sigma) and values (0 where masked).
struct FitInput {
  uint8_t ok[kMaxChannels];
  double inv_sigma[kMaxChannels];
  double y[kMaxChannels];
  SampleCheck check;
};

// Up to `wanted` of the table rows `nb[0, n)` (nearest first), each at least `spacing_mm` in
// (u, v) from `avoid_uv` (when not null) and from the rows picked before it: rows next to each
// other lie in one basin of the field, another basin is another place. Their indices into `nb`
// go to `picked`; returns how many.
int pick_apart(const LookupEstimator& table, const LookupNeighbour* nb, int n, double spacing_mm,
               const double* avoid_uv, int wanted, int* picked) {
  int count = 0;
  for (int i = 0; i < n && count < wanted; ++i) {
    const double u = table.row_u_mm(nb[i].row), v = table.row_v_mm(nb[i].row);
    bool apart = avoid_uv == nullptr || std::hypot(u - avoid_uv[0], v - avoid_uv[1]) >= spacing_mm;
    for (int t = 0; t < count && apart; ++t) {
      apart = std::hypot(u - table.row_u_mm(nb[picked[t]].row),
                         v - table.row_v_mm(nb[picked[t]].row)) >= spacing_mm;
    }
    if (apart) picked[count++] = i;
  }
  return count;
}

// A search's fit that comes this close (mm, in u and v) to a fit the search already has (an
// earlier start's, or the one its caller holds, search_lm()'s `apart_from`) has entered that fit's
// basin, whose minimum is known: it stops there. The host's basin check counts a search 1 mm or
// more from its warm fit as a move.
constexpr double kJoinMm = 1.0;

// The places (u, v, mm) of the basins a search has: the held fit's and each start's fit.
struct KnownBasins {
  static constexpr int kMax = 9;  // the held fit and search_lm()'s 8 starts
  double uv[kMax][2];
  int count = 0;
  void add(double u, double v) {
    if (count == kMax || !std::isfinite(u) || !std::isfinite(v)) return;
    uv[count][0] = u;
    uv[count][1] = v;
    ++count;
  }
  bool near(double u, double v) const {
    for (int k = 0; k < count; ++k) {
      if (std::hypot(u - uv[k][0], v - uv[k][1]) < kJoinMm) return true;
    }
    return false;
  }
};

// refine_lm()'s fit of one contact (with its shear when N is 8) on a prepared sample; below.
template <int N>
void refine_lean(const sim::PatchModel& model, const PhysicsOptions& options, const FitInput& in,
                 const double* ambient_jac, const ContactEstimate& start, PhysicsEstimate* result,
                 WarmJacobian* warm = nullptr, const KnownBasins* known = nullptr);

void prepare_fit(std::span<const double> field_ut, std::span<const uint8_t> channel_ok, int nc,
                 const PhysicsOptions& options, FitInput* in) {
  for (int c = 0; c < nc; ++c) in->ok[c] = channel_ok.empty() ? 1 : channel_ok[c];
  in->check = check_sample(field_ut, std::span<uint8_t>(in->ok, static_cast<std::size_t>(nc)),
                           options.limits);
  for (int c = 0; c < nc; ++c) {
    in->inv_sigma[c] = 1 / options.noise.sigma(c);
    in->y[c] = in->ok[c] ? field_ut[c] : 0.0;
  }
}

// The checks every single-contact fit starts with: the sample's shape, its usable channels
// (prepare_fit) and that they outnumber the unknowns. False with `out` a rejection (the reason
// set) when the fit cannot be made.
bool begin_fit(std::span<const double> field_ut, std::span<const uint8_t> channel_ok, int nc,
               const PhysicsOptions& options, FitInput* in, PhysicsEstimate* out) {
  ContactEstimate& e = out->contact;
  if (static_cast<int>(field_ut.size()) != nc ||
      (!channel_ok.empty() && static_cast<int>(channel_ok.size()) != nc)) {
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kWrongShape;
    return false;
  }
  prepare_fit(field_ut, channel_ok, nc, options, in);
  const int unknowns = unknowns_of(options);
  if (nc - in->check.masked < std::max(options.min_channels, unknowns + 1)) {
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kTooFewChannels;
    return false;
  }
  return true;
}

// An estimate flagged against the model's patch and depth range, in the depth its contacts read
// (sim::PatchModel::depth_zero_mm() at the surface).
void flag_model_range(ContactEstimate& e, const sim::PatchModel& model) {
  const double dz = model.depth_zero_mm();
  flag_range(e, model.design().size_u_mm / 2, model.design().size_v_mm / 2,
             model.max_depth_mm() + dz, kRangeMarginMm, kRangeMarginDepthMm - dz);
}

// The end every single-contact fit shares: the contact at `x` (u, v, depth) with the ambient
// offset `b` and the shear force `shear` (N; null: not fitted), its chi-square (noise units) and
// iterations, its reduced chi-square over the unknowns fitted (the shear's only when given), and
// its flags: masked channels, not converged, a poor fit, no contact (the fitted
// contact's whitened signal `contact_field`, its field change, below options.no_contact_snr), the
// range; a non-finite fit becomes a rejection.
void finish_fit(const sim::PatchModel& model, const PhysicsOptions& options, const FitInput& in,
                const double x[3], const double b[3], const double* shear, double chi2,
                int iterations, bool converged, const double* contact_field, PhysicsEstimate* out) {
  ContactEstimate& e = out->contact;
  const int nc = model.channel_count();
  const int usable = nc - in.check.masked;
  const int unknowns = LeanLayout{1, shear != nullptr}.unknowns(options.fit_ambient);  // fitted
  e.u_mm = x[0];
  e.v_mm = x[1];
  e.depth_mm = x[2];
  e.force_n = model.force_n(x[2]);
  if (shear != nullptr) {
    e.shear_u_n = shear[0];
    e.shear_v_n = shear[1];
  }
  for (int k = 0; k < 3; ++k) out->ambient_ut[k] = b[k];
  out->iterations = iterations;
  out->chi2 = chi2;
  out->channels_used = usable;
  out->reduced_chi2 = chi2 / (usable - unknowns);
  if (in.check.masked > 0) e.flags |= kEstimateMasked;
  if (!converged) e.flags |= kEstimateNotConverged;
  if (!(out->reduced_chi2 <= options.poor_fit_ratio)) e.flags |= kEstimatePoorFit;
  // Signal of the fitted contact in noise units: at noise level, nothing was pressed.
  double energy = 0;
  for (int i = 0; i < nc; ++i) {
    if (in.ok[i]) energy += contact_field[i] * contact_field[i] * in.inv_sigma[i] * in.inv_sigma[i];
  }
  if (!(energy >= options.no_contact_snr * options.no_contact_snr)) e.flags |= kEstimateNoContact;
  flag_model_range(e, model);
  bool finite = std::isfinite(chi2);
  for (int k = 0; k < 3; ++k) finite = finite && std::isfinite(x[k]) && std::isfinite(b[k]);
  finite = finite && std::isfinite(e.shear_u_n) && std::isfinite(e.shear_v_n);
  if (!finite) {
    *out = PhysicsEstimate{};
    out->contact.flags = kEstimateRejected;
    out->contact.reason = RejectReason::kNonFinite;
  }
}

// A contact's bounds: (u, v) within the patch extent plus the margin, depth from kMinDepthMm
// into the lattice to the deepest press (in the depth its contacts read).
void contact_bounds(const sim::PatchModel& model, const PhysicsOptions& options, double lo[3],
                    double hi[3]) {
  const double half_u = model.design().size_u_mm / 2, half_v = model.design().size_v_mm / 2;
  lo[0] = -half_u - options.uv_margin_mm;
  lo[1] = -half_v - options.uv_margin_mm;
  lo[2] = model.depth_zero_mm() + kMinDepthMm;
  hi[0] = half_u + options.uv_margin_mm;
  hi[1] = half_v + options.uv_margin_mm;
  hi[2] = model.depth_zero_mm() + model.max_depth_mm();
}

// Levenberg-Marquardt as every fit here runs it: dense QR, one thread, silent.
ceres::Solver::Options solver_options(const PhysicsOptions& options) {
  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.parameter_tolerance = options.parameter_tolerance;
  so.gradient_tolerance = 1e-14;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  return so;
}

Status check_options(const PhysicsOptions& o) {
  if (!(o.tip_radius_mm >= 0) || o.max_iterations < 1 || o.min_channels < 4 ||
      !(o.poor_fit_ratio > 0) || !(o.no_contact_snr >= 0) || !(o.uv_margin_mm >= 0) ||
      !(o.noise.xy_ut >= 0) || !(o.noise.z_ut >= 0) || o.other_basins < 0 || o.other_basins > 8) {
    return make_error(ErrorCode::kInvalidArgument,
                      "physics options: tip_radius_mm >= 0, max_iterations >= 1, min_channels "
                      ">= 4, poor_fit_ratio > 0, no_contact_snr >= 0, uv_margin_mm >= 0, noise "
                      ">= 0, other_basins 0..8 required");
  }
  return Status::Ok();
}

}  // namespace

double start_pitch_mm(const sim::PatchDesign& design) {
  constexpr double kMaxPitchMm = 5.0;
  double spacing_mm = design.magnet_pitch_mm;
  if (!design.magnet_list.empty()) {
    std::vector<double> nearest;
    for (const auto& a : design.magnet_list) {
      double best = std::numeric_limits<double>::infinity();
      for (const auto& b : design.magnet_list) {
        const double d = std::hypot(a.u_mm - b.u_mm, a.v_mm - b.v_mm);
        if (&a != &b && d > 0) best = std::min(best, d);
      }
      if (std::isfinite(best)) nearest.push_back(best);
    }
    if (nearest.empty()) return kMaxPitchMm;
    std::nth_element(nearest.begin(), nearest.begin() + nearest.size() / 2, nearest.end());
    spacing_mm = nearest[nearest.size() / 2];
  }
  if (!(spacing_mm > 0)) return kMaxPitchMm;
  return std::min(kMaxPitchMm, spacing_mm / kStartPitchPerMagnetSpacing);
}

PhysicsEstimator::PhysicsEstimator(const sim::PatchModel& model, const PhysicsOptions& options,
                                   LookupEstimator start)
    : model_(model),
      options_(options),
      start_(std::move(start)),
      other_basin_mm_(2 * start_pitch_mm(model.design())) {
  if (!(options_.noise.xy_ut > 0) || !(options_.noise.z_ut > 0))
    options_.noise = ChannelNoise::of(model_.design());
  const auto& sensors = model_.sensors();
  ambient_jac_.resize(3 * static_cast<std::size_t>(model_.channel_count()));
  for (std::size_t s = 0; s < sensors.size(); ++s) {
    const double g[3] = {sensors[s].gain.x, sensors[s].gain.y, sensors[s].gain.z};
    for (int axis = 0; axis < 3; ++axis) {
      double* row = &ambient_jac_[3 * (3 * s + static_cast<std::size_t>(axis))];
      row[0] = sensors[s].frame.r[axis].x * g[axis];
      row[1] = sensors[s].frame.r[axis].y * g[axis];
      row[2] = sensors[s].frame.r[axis].z * g[axis];
    }
  }
}

Result<PhysicsEstimator> PhysicsEstimator::create(const sim::PatchModel& model,
                                                  const PhysicsOptions& options) {
  if (Status s = check_options(options); !s.ok()) return s.error();
  LookupOptions lo;
  lo.ambient_invariant = options.fit_ambient;
  LookupGrid grid = options.start_grid;
  if (grid.pitch_mm == 0) grid.pitch_mm = start_pitch_mm(model.design());
  grid.tip_radius_mm = options.tip_radius_mm;  // the rows are presses of the fit's indenter
  Result<LookupEstimator> start = LookupEstimator::from_model(model, grid, lo);
  if (!start.ok()) return start.error();
  return PhysicsEstimator(model, options, std::move(start).value());
}

Result<PhysicsEstimator> PhysicsEstimator::create(const sim::PatchModel& model,
                                                  const PhysicsOptions& options,
                                                  LookupEstimator start) {
  if (Status s = check_options(options); !s.ok()) return s.error();
  if (start.channels() != model.channel_count()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "physics estimator: the start table's channel count differs from the "
                      "model's");
  }
  return PhysicsEstimator(model, options, std::move(start));
}

PhysicsEstimate PhysicsEstimator::estimate(std::span<const double> field_ut,
                                           std::span<const uint8_t> channel_ok) const {
  return solve(field_ut, channel_ok, nullptr);
}

PhysicsEstimate PhysicsEstimator::refine(std::span<const double> field_ut,
                                         std::span<const uint8_t> channel_ok,
                                         const ContactEstimate& guess) const {
  return solve(field_ut, channel_ok, &guess);
}

PhysicsEstimate PhysicsEstimator::solve(std::span<const double> field_ut,
                                        std::span<const uint8_t> channel_ok,
                                        const ContactEstimate* guess) const {
  PhysicsEstimate out;
  const int nc = model_.channel_count();
  FitInput in;
  if (!begin_fit(field_ut, channel_ok, nc, options_, &in, &out)) return out;
  const uint8_t* ok = in.ok;
  const double* inv_sigma = in.inv_sigma;
  const double* y = in.y;
  const int usable = nc - in.check.masked;
  // The Ceres fit has no shear: with fit_shear the lean fit takes over from its answer (below).
  const int unknowns = LeanLayout{1, false}.unknowns(options_.fit_ambient);
  double whitened[kMaxChannels];
  for (int c = 0; c < nc; ++c) whitened[c] = y[c] * inv_sigma[c];

  // Starts: the guess, or the nearest rows of the start table. The first is tried; the others
  // only when it ends in a poor fit (a local minimum), and the best fit is kept.
  double lo[3], hi[3];
  contact_bounds(model_, options_, lo, hi);
  constexpr int kStarts = 3;
  double starts[kStarts][3];
  int n_starts = 0;
  if (guess != nullptr && std::isfinite(guess->u_mm) && std::isfinite(guess->v_mm) &&
      std::isfinite(guess->depth_mm)) {
    starts[n_starts][0] = guess->u_mm;
    starts[n_starts][1] = guess->v_mm;
    starts[n_starts][2] = guess->depth_mm;
    ++n_starts;
  }
  // Nearest rows of the start table, fetched once when first needed (a good guess may not need
  // them): the starts, and with other_basins the candidates for other basins (below).
  constexpr int kCandidates = 32;
  LookupNeighbour nb[kCandidates];
  int n_nb = 0;
  bool looked_up = false;
  auto look_up = [&]() {
    looked_up = true;
    n_nb = start_.nearest(
        std::span<const double>(whitened, static_cast<std::size_t>(nc)),
        std::span<const uint8_t>(ok, static_cast<std::size_t>(nc)),
        std::span<LookupNeighbour>(
            nb, static_cast<std::size_t>(options_.other_basins > 0 ? kCandidates : kStarts)));
  };
  auto add_table_starts = [&]() {
    if (!looked_up) look_up();
    const int found = std::min(n_nb, kStarts - n_starts);
    for (int i = 0; i < found; ++i, ++n_starts) {
      starts[n_starts][0] = start_.row_u_mm(nb[i].row);
      starts[n_starts][1] = start_.row_v_mm(nb[i].row);
      starts[n_starts][2] = start_.row_depth_mm(nb[i].row);
    }
  };
  if (n_starts == 0) add_table_starts();
  if (n_starts == 0) {
    starts[0][0] = starts[0][1] = 0;
    starts[0][2] = 1;
    n_starts = 1;
  }

  ContactsResidual<1> residual(model_, y, ok, inv_sigma, ambient_jac_.data(),
                               options_.tip_radius_mm);
  const ceres::Solver::Options so = solver_options(options_);
  double best_x[3] = {0, 0, 0}, best_b[3] = {0, 0, 0};
  double best_cost = std::numeric_limits<double>::infinity();
  bool best_converged = false;
  int iterations = 0;
  // One Levenberg-Marquardt fit from a start; the best kept.
  auto fit_from = [&](const double start[3]) {
    double x[3], b[3] = {0, 0, 0};
    for (int k = 0; k < 3; ++k) x[k] = std::clamp(start[k], lo[k], hi[k]);
    ceres::Problem::Options po;
    po.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(po);
    problem.AddResidualBlock(&residual, nullptr, x, b);
    for (int k = 0; k < 3; ++k) {
      problem.SetParameterLowerBound(x, k, lo[k]);
      problem.SetParameterUpperBound(x, k, hi[k]);
    }
    if (!options_.fit_ambient) problem.SetParameterBlockConstant(b);
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    iterations += static_cast<int>(summary.iterations.size()) - 1;
    if (summary.final_cost < best_cost) {
      best_cost = summary.final_cost;
      std::copy(x, x + 3, best_x);
      std::copy(b, b + 3, best_b);
      best_converged = summary.termination_type == ceres::CONVERGENCE;
    }
  };
  for (int s = 0; s < n_starts; ++s) {
    fit_from(starts[s]);
    if (2 * best_cost / (usable - unknowns) <= options_.poor_fit_ratio) break;
    if (s + 1 == n_starts && !looked_up) add_table_starts();
  }
  // Other basins: where the field is ambiguous (a press beyond the magnets, a design whose field
  // repeats) two places some magnet spacing apart explain a sample to nearly the same
  // chi-square, and the fit from the nearest start can land in the wrong one even though it fits
  // well. The table rows nearest the sample that lie at least other_basin_mm from the fit, and
  // from each other, are fitted too (by the lean fit); the lowest chi-square is kept.
  if (options_.other_basins > 0 && std::isfinite(best_cost)) {
    if (!looked_up) look_up();
    const double first_uv[2] = {best_x[0], best_x[1]};
    int picked[kCandidates];
    const int n_picked =
        pick_apart(start_, nb, n_nb, other_basin_mm_, first_uv, options_.other_basins, picked);
    for (int k = 0; k < n_picked; ++k) {
      const LookupNeighbour& row = nb[picked[k]];
      // The lean fit (refine_lm()'s): a tenth of the Ceres fit's cost, the same minimum to a few
      // percent of its uncertainty.
      ContactEstimate from;
      from.u_mm = start_.row_u_mm(row.row);
      from.v_mm = start_.row_v_mm(row.row);
      from.depth_mm = start_.row_depth_mm(row.row);
      PhysicsEstimate e;
      refine_lean<6>(model_, options_, in, ambient_jac_.data(), from, &e);
      iterations += e.iterations;
      if (e.contact.valid() && e.chi2 < 2 * best_cost) {
        best_cost = e.chi2 / 2;
        best_x[0] = e.contact.u_mm;
        best_x[1] = e.contact.v_mm;
        best_x[2] = e.contact.depth_mm;
        std::copy(e.ambient_ut, e.ambient_ut + 3, best_b);
        best_converged = (e.contact.flags & kEstimateNotConverged) == 0;
      }
    }
  }

  double f[kMaxChannels];
  const sim::Contact c{best_x[0], best_x[1], best_x[2], options_.tip_radius_mm};
  model_.contact_field_ut(std::span<const sim::Contact>(&c, 1),
                          std::span<double>(f, static_cast<std::size_t>(nc)));
  if (options_.fit_shear) {
    // The shear by the lean fit, which knows it, from this fit's contact without shear; a strong
    // shear misleads that fit, so when the joint fit ends poor it is tried again from the other
    // starts, and from this contact with a shear of 0.3 of its normal force along 8 directions;
    // the lowest chi-square is kept.
    auto joint_from = [&](const double x[3], double shear_u_n, double shear_v_n) {
      ContactEstimate start;
      start.u_mm = x[0];
      start.v_mm = x[1];
      start.depth_mm = x[2];
      start.shear_u_n = shear_u_n;
      start.shear_v_n = shear_v_n;
      PhysicsEstimate e;  // on the sample already prepared (refine_lm() would check it again)
      refine_lean<8>(model_, options_, in, ambient_jac_.data(), start, &e);
      iterations += e.iterations;
      return e;
    };
    auto poor = [&](const PhysicsEstimate& e) {
      return !e.contact.valid() || (e.contact.flags & kEstimatePoorFit) != 0;
    };
    PhysicsEstimate joint = joint_from(best_x, 0, 0);
    if (poor(joint) && !looked_up) add_table_starts();
    for (int k = 0; k < n_starts + 8 && poor(joint); ++k) {
      PhysicsEstimate e;
      if (k < n_starts) {
        e = joint_from(starts[k], 0, 0);
      } else {
        const double angle = (k - n_starts) * M_PI / 4, mag = 0.3 * model_.force_n(best_x[2]);
        e = joint_from(best_x, mag * std::cos(angle), mag * std::sin(angle));
      }
      if (e.contact.valid() && (!joint.contact.valid() || e.chi2 < joint.chi2)) joint = e;
    }
    joint.iterations = iterations;
    return joint;
  }
  finish_fit(model_, options_, in, best_x, best_b, nullptr, 2 * best_cost, iterations,
             best_converged, f, &out);
  if (options_.covariance && out.contact.valid()) covariance(c, ok, inv_sigma, &out);
  return out;
}

namespace {

// The lean fit's unknowns (LeanLayout), sized at compile time (N unknowns: 6 for one contact, 8
// with its shear, 9 for two, 12 for three, 18 for three with their shear): no allocation,
// fixed-size algebra.
constexpr int kLeanMax = kMaxContacts * 5 + 3;

template <int N>
struct LeanFit {
  using LeanVec = Eigen::Matrix<double, N, 1>;
  using LeanMat = Eigen::Matrix<double, N, N>;
  LeanVec x;
  double cost = std::numeric_limits<double>::infinity();  // chi-square, noise units
  int iterations = 0;
  int field_evaluations = 0, jacobians = 0;  // computed by this fit
  bool converged = false;
  bool joined = false;         // stopped within kJoinMm of a basin its caller knows
  LeanMat jtj;                 // J^T J (whitened) at the start of the last iteration, every unknown
  double field[kMaxChannels];  // the contacts' field change at x
};

// The contacts of `x` (layout `l`) with the indenter's tip.
template <typename LeanVec>
void lean_contacts(const LeanLayout& l, const LeanVec& x, double tip_radius_mm, sim::Contact* c) {
  for (int j = 0; j < l.contacts; ++j) {
    const int o = j * l.per_contact();
    c[j] = sim::Contact{x(o), x(o + 1), x(o + 2), tip_radius_mm};
    if (l.shear) {
      c[j].shear_u_n = x(o + 3);
      c[j].shear_v_n = x(o + 4);
    }
  }
}

// `m` with the rows and columns of the unknowns not fitted replaced by the identity's.
template <typename LeanMat>
LeanMat hold_unfitted(LeanMat m, const bool* fitted) {
  for (int k = 0; k < m.rows(); ++k) {
    if (fitted[k]) continue;
    m.row(k).setZero();
    m.col(k).setZero();
    m(k, k) = 1;
  }
  return m;
}

// Levenberg-Marquardt over the layout's unknowns from `x` (non-finite entries start mid-range,
// the rest clamped to the bounds: each contact within contact_bounds(), each shear component
// within +-kMaxShearN): the Jacobian exact (PatchModel::contact_field_jacobian_ut, about three
// field evaluations' time for one contact) or updated along short steps, the ambient's columns
// constant. Ends when a step gains, or with the exact Jacobian is predicted to gain, less than
// 1e-3 in chi-square. No allocation.
template <int N>
LeanFit<N> lean_fit(const sim::PatchModel& model, const PhysicsOptions& options, const FitInput& in,
                    const double* ambient_jac, const LeanLayout& l, typename LeanFit<N>::LeanVec x,
                    WarmJacobian* warm = nullptr, const KnownBasins* known = nullptr) {
  using LeanVec = typename LeanFit<N>::LeanVec;
  using LeanMat = typename LeanFit<N>::LeanMat;
  const int nc = model.channel_count();
  const int n = N, pc = l.per_contact(), amb = l.ambient_at();
  double lo[kLeanMax], hi[kLeanMax];
  bool fitted[kLeanMax];
  double clo[3], chi[3];
  contact_bounds(model, options, clo, chi);
  for (int k = 0; k < n; ++k) {
    const int within = k % pc;
    if (k >= amb) {
      lo[k] = -std::numeric_limits<double>::infinity();
      hi[k] = std::numeric_limits<double>::infinity();
    } else if (within < 3) {
      lo[k] = clo[within];
      hi[k] = chi[within];
    } else {
      lo[k] = -kMaxShearN;
      hi[k] = kMaxShearN;
    }
    fitted[k] = l.fitted(k, options.fit_ambient);
    const bool bounded = std::isfinite(lo[k]) && std::isfinite(hi[k]);
    if (!std::isfinite(x(k))) {
      x(k) = bounded && within < 3 && k < amb ? (lo[k] + hi[k]) / 2 : 0.0;
    } else {
      x(k) = std::clamp(x(k), lo[k], hi[k]);
    }
  }
  LeanFit<N> fit;
  const double tip = options.tip_radius_mm;
  sim::Contact contacts[kMaxContacts];
  auto field = [&](const LeanVec& p, double* into) {
    ++fit.field_evaluations;
    lean_contacts(l, p, tip, contacts);
    model.contact_field_ut(std::span<const sim::Contact>(contacts, l.contacts),
                           std::span<double>(into, static_cast<std::size_t>(nc)));
  };
  // Whitened residuals of the contacts' field `fc` with the ambient of `p`; their squared sum.
  auto residuals = [&](const double* fc, const LeanVec& p, double* into) {
    double cost = 0;
    for (int i = 0; i < nc; ++i) {
      if (!in.ok[i]) {
        into[i] = 0;
        continue;
      }
      const double* a = ambient_jac + 3 * static_cast<std::size_t>(i);
      into[i] = (fc[i] + a[0] * p(amb) + a[1] * p(amb + 1) + a[2] * p(amb + 2) - in.y[i]) *
                in.inv_sigma[i];
      cost += into[i] * into[i];
    }
    return cost;
  };
  static_assert(kMaxContacts <= sim::PatchModel::kMaxJetContacts);
  // The contacts' Jacobian, row-major, nc x amb (contact_field_jacobian_ut's layout).
  double ft[kMaxChannels], r[kMaxChannels], jac[kMaxChannels * (N - 3)];
  fit.jtj = LeanMat::Zero();
  constexpr double kConvergedMm = 1e-5;  // a step this small ends the fit (bounds: ~0.1 mm)
  // A step that lowers the chi-square by less than this ends the fit: what is left to gain moves
  // the contact by a few percent of its uncertainty (a chi-square change of d^2 is a move of d
  // standard deviations).
  constexpr double kConvergedChi2 = 1e-3;
  // After an accepted step shorter than this (mm; a shear change in N counts as the surface shift
  // it makes at 1 N/mm) the Jacobian is not computed again but corrected along the step
  // (Broyden's rank-one update, from the field change the step made, no field evaluation): the
  // field's gradients change over millimetres, and along the step just taken the update is exact
  // to first order. Measured (docs/benchmarks/refinement.md): a fifth less time a warm
  // refinement when the Jacobian was differenced (three field evaluations), the same errors;
  // differencing again only past 5 mm let one more fit end poor.
  constexpr double kReuseMm = 0.5;
  // The last accepted step's contact unknowns; zero before the first iteration, which therefore
  // computes the Jacobian.
  double last_step[kLeanMax] = {};
  double last_field[kMaxChannels];
  // A Jacobian the same press's last fit left near this start: this fit begins from it, updated
  // along the move (the first iteration's, below).
  const bool kept = warm != nullptr && warm->valid && warm->unknowns == amb && l.contacts == 1;
  bool from_warm = false, at_warm = kept;
  for (int k = 0; at_warm && k < amb; ++k) at_warm = x(k) == warm->at[k];
  if (kept && warm->uses < WarmJacobian::kMaxUses) {
    double d2 = 0;
    for (int k = 0; k < amb; ++k) d2 += (x(k) - warm->at[k]) * (x(k) - warm->at[k]);
    if (d2 <= kReuseMm * kReuseMm) {
      from_warm = true;
      for (int k = 0; k < amb; ++k) last_step[k] = x(k) - warm->at[k];
      std::copy(warm->field_ut, warm->field_ut + nc, last_field);
      std::copy(warm->jacobian, warm->jacobian + nc * amb, jac);
    }
  }
  // The contacts' field at the start: the last fit's own when it begins where that one ended
  // (the model's field depends on the contacts alone, not on the sample), else evaluated.
  if (at_warm) {
    std::copy(warm->field_ut, warm->field_ut + nc, fit.field);
  } else {
    field(x, fit.field);
  }
  double cost = residuals(fit.field, x, r);
  double lambda = 1e-3;
  auto broyden = [&](double dd) {  // the Jacobian along last_step (squared length dd > 0)
    for (int i = 0; i < nc; ++i) {
      double* row = jac + i * amb;
      double miss = fit.field[i] - last_field[i];
      for (int k = 0; k < amb; ++k) miss -= row[k] * last_step[k];
      for (int k = 0; k < amb; ++k) row[k] += miss * last_step[k] / dd;
    }
  };
  auto step2 = [&] {  // the squared length of last_step over the contact's unknowns
    double dd = 0;
    for (int k = 0; k < amb; ++k) dd += last_step[k] * last_step[k];
    return dd;
  };
  bool computed = false;  // whether this fit computed the Jacobian
  while (fit.iterations < options.max_iterations && std::isfinite(cost) && !fit.converged) {
    ++fit.iterations;
    const double dd = step2();
    const bool updated =
        (dd > 0 && dd <= kReuseMm * kReuseMm) || (from_warm && fit.iterations == 1);
    if (updated) {
      if (dd > 0) broyden(dd);
    } else {
      lean_contacts(l, x, tip, contacts);
      if (!model.contact_field_jacobian_ut(
              std::span<const sim::Contact>(contacts, l.contacts), l.shear,
              std::span<double>(ft, static_cast<std::size_t>(nc)),
              std::span<double>(jac, static_cast<std::size_t>(nc * amb)))) {
        break;  // not reached: the layouts are within the jets' (static_assert above)
      }
      computed = true;
      ++fit.jacobians;
    }
    std::fill(last_step, last_step + amb, 0.0);
    LeanMat jtj = LeanMat::Zero();
    LeanVec jtr = LeanVec::Zero();
    for (int i = 0; i < nc; ++i) {
      if (!in.ok[i]) continue;
      const double w = in.inv_sigma[i];
      const double* a = ambient_jac + 3 * static_cast<std::size_t>(i);
      LeanVec row;
      for (int k = 0; k < amb; ++k) row(k) = jac[i * amb + k] * w;
      for (int k = 0; k < 3; ++k) row(amb + k) = a[k] * w;
      jtj.noalias() += row * row.transpose();
      jtr.noalias() += row * r[i];
    }
    fit.jtj = jtj;
    jtj = hold_unfitted(jtj, fitted);
    for (int k = 0; k < n; ++k) {
      if (!fitted[k]) jtr(k) = 0;
    }
    // Damped steps until one lowers the cost; the damping relaxes after a success.
    bool accepted = false, last_try = false;
    for (int tries = 0; tries < 12 && !accepted; ++tries) {
      LeanMat a = jtj;
      for (int p = 0; p < n; ++p) a(p, p) += lambda * std::max(jtj(p, p), 1e-9);
      const LeanVec step = a.ldlt().solve(-jtr);
      LeanVec xt = x + step;
      bool clamped = false;
      for (int k = 0; k < n; ++k) {
        xt(k) = std::clamp(xt(k), lo[k], hi[k]);
        clamped = clamped || xt(k) != x(k) + step(k);
      }
      // The chi-square the step would gain by the linear model, |r|^2 - |r + J h|^2. Below what
      // ends a fit (a more damped step only gains less, unless a bound clamped it): with the
      // exact Jacobian the fit ends here, unevaluated; with one updated along the last step only
      // (Broyden's, approximate elsewhere) this step is evaluated, and the fit ends if it fails.
      const double predicted = -(2 * step.dot(jtr) + step.dot(jtj * step));
      if (!clamped && !(predicted > kConvergedChi2)) {
        if (!updated) {
          fit.converged = true;
          break;
        }
        last_try = true;
      }
      field(xt, ft);
      double rt[kMaxChannels];
      const double cost_t = residuals(ft, xt, rt);
      if (std::isfinite(cost_t) && cost_t <= cost) {
        // How far the step moved the unknowns of the contacts (mm; a shear change in N counts as
        // the surface shift it makes at 1 N/mm).
        double moved2 = 0;
        for (int k = 0; k < amb; ++k) {
          last_step[k] = xt(k) - x(k);
          moved2 += last_step[k] * last_step[k];
        }
        const double moved = std::sqrt(moved2);
        const double drop = cost - cost_t;
        std::copy(fit.field, fit.field + nc, last_field);
        x = xt;
        std::copy(ft, ft + nc, fit.field);
        std::copy(rt, rt + nc, r);
        fit.converged = drop <= kConvergedChi2 || moved <= kConvergedMm;
        cost = cost_t;
        lambda = std::max(lambda / 3, 1e-9);
        accepted = true;
        fit.joined = l.contacts == 1 && known != nullptr && known->near(x(0), x(1));
      } else if (last_try) {
        fit.converged = true;  // the gain left is below what ends a fit, and this step failed
        break;
      } else {
        lambda *= 4;
      }
    }
    if (!accepted) {
      fit.converged = true;  // no step lowers the cost: a minimum to the damping's resolution
    }
    if (fit.joined) break;
  }
  // What the next sample of the press begins from: the Jacobian at this fit's end (updated
  // along its last step), unless that step was long or nothing was computed.
  if (warm != nullptr) {
    const double dd = step2();
    warm->valid = l.contacts == 1 && (computed || from_warm) && dd <= kReuseMm * kReuseMm &&
                  std::isfinite(cost);
    if (warm->valid) {
      if (dd > 0) broyden(dd);
      warm->unknowns = amb;
      warm->uses = computed ? 0 : warm->uses + 1;
      for (int k = 0; k < amb; ++k) warm->at[k] = x(k);
      std::copy(fit.field, fit.field + nc, warm->field_ut);
      std::copy(jac, jac + nc * amb, warm->jacobian);
    }
  }
  fit.x = x;
  fit.cost = cost;
  return fit;
}

// 1-sigma uncertainties of contact `j` of layout `l` from J^T J of the whitened residuals over
// the fitted unknowns (the ambient held unless `fit_ambient`), scaled by the reduced chi-square
// above 1: its radial position, depth and shear (when the layout has it). False, the outputs
// untouched, when J^T J is singular.
template <typename LeanMat>
bool lean_sigmas(const LeanMat& jtj, const LeanLayout& l, bool fit_ambient, double reduced_chi2,
                 int j, double* sigma_uv_mm, double* sigma_depth_mm, double* sigma_shear_n) {
  bool fitted[kLeanMax];
  for (int k = 0; k < l.size(); ++k) fitted[k] = l.fitted(k, fit_ambient);
  const LeanMat m = hold_unfitted(jtj, fitted);
  const Eigen::LDLT<LeanMat> ldlt(m);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() ||
      ldlt.vectorD().minCoeff() <= 1e-12 * std::max(1.0, ldlt.vectorD().maxCoeff())) {
    return false;
  }
  const LeanMat cov = ldlt.solve(LeanMat::Identity());
  const double scale = std::max(1.0, reduced_chi2);
  const int o = j * l.per_contact();
  const double var_uv = (cov(o, o) + cov(o + 1, o + 1)) * scale, var_d = cov(o + 2, o + 2) * scale;
  if (!(std::isfinite(var_uv) && var_uv >= 0 && std::isfinite(var_d) && var_d >= 0)) return false;
  *sigma_uv_mm = std::sqrt(var_uv);
  *sigma_depth_mm = std::sqrt(var_d);
  if (l.shear && sigma_shear_n != nullptr) {
    const double var_s = (cov(o + 3, o + 3) + cov(o + 4, o + 4)) * scale;
    if (std::isfinite(var_s) && var_s >= 0) *sigma_shear_n = std::sqrt(var_s);
  }
  return true;
}

// refine_lm()'s fit: one contact, with its shear when N is 8.
template <int N>
void refine_lean(const sim::PatchModel& model, const PhysicsOptions& options, const FitInput& in,
                 const double* ambient_jac, const ContactEstimate& start, PhysicsEstimate* result,
                 WarmJacobian* warm, const KnownBasins* known) {
  PhysicsEstimate& out = *result;
  const LeanLayout l{1, N == 8};
  typename LeanFit<N>::LeanVec x0 = LeanFit<N>::LeanVec::Zero();
  x0(0) = start.u_mm;
  x0(1) = start.v_mm;
  x0(2) = start.depth_mm;
  if (l.shear) {
    x0(3) = start.shear_u_n;
    x0(4) = start.shear_v_n;
  }
  const LeanFit<N> fit = lean_fit<N>(model, options, in, ambient_jac, l, x0, warm, known);
  if (fit.joined) {  // in a basin the caller has: no fit of its own
    out = PhysicsEstimate{};
    out.contact.flags = kEstimateRejected;
    out.iterations = fit.iterations;
    out.field_evaluations = fit.field_evaluations;
    out.jacobians = fit.jacobians;
    return;
  }
  const int amb = l.ambient_at();
  const double xc[3] = {fit.x(0), fit.x(1), fit.x(2)};
  const double xb[3] = {fit.x(amb), fit.x(amb + 1), fit.x(amb + 2)};
  const double xs[2] = {l.shear ? fit.x(3) : 0.0, l.shear ? fit.x(4) : 0.0};
  finish_fit(model, options, in, xc, xb, l.shear ? xs : nullptr, fit.cost, fit.iterations,
             fit.converged, fit.field, &out);
  out.field_evaluations = fit.field_evaluations;
  out.jacobians = fit.jacobians;
  // From the last iteration's J^T J (at the point before its step: within the tolerance of the
  // minimum).
  if (options.covariance && fit.iterations > 0 && out.contact.valid()) {
    lean_sigmas(fit.jtj, l, options.fit_ambient, out.reduced_chi2, 0, &out.sigma_uv_mm,
                &out.sigma_depth_mm, &out.sigma_shear_n);
  }
}

}  // namespace

PhysicsEstimate PhysicsEstimator::refine_lm(std::span<const double> field_ut,
                                            std::span<const uint8_t> channel_ok,
                                            const ContactEstimate& start,
                                            WarmJacobian* warm) const {
  PhysicsEstimate out;
  const int nc = model_.channel_count();
  FitInput in;
  if (!begin_fit(field_ut, channel_ok, nc, options_, &in, &out)) return out;
  if (options_.fit_shear) {
    refine_lean<8>(model_, options_, in, ambient_jac_.data(), start, &out, warm);
  } else {
    refine_lean<6>(model_, options_, in, ambient_jac_.data(), start, &out, warm);
  }
  return out;
}

PhysicsEstimate PhysicsEstimator::search_lm(std::span<const double> field_ut,
                                            std::span<const uint8_t> channel_ok, int starts,
                                            const ContactEstimate* apart_from) const {
  PhysicsEstimate best;
  const int nc = model_.channel_count();
  FitInput in;
  if (!begin_fit(field_ut, channel_ok, nc, options_, &in, &best)) return best;
  double whitened[kMaxChannels];
  for (int c = 0; c < nc; ++c) whitened[c] = in.y[c] * in.inv_sigma[c];
  // The nearest row, then the next nearest ones at least 2 table pitches from those taken.
  constexpr int kCandidates = 32;
  LookupNeighbour nb[kCandidates];
  const int n = start_.nearest(std::span<const double>(whitened, static_cast<std::size_t>(nc)),
                               std::span<const uint8_t>(in.ok, static_cast<std::size_t>(nc)),
                               std::span<LookupNeighbour>(nb, kCandidates));
  const double pitch = options_.start_grid.pitch_mm > 0 ? options_.start_grid.pitch_mm
                                                        : start_pitch_mm(model_.design());
  int picked[8];
  const double held_uv[2] = {apart_from != nullptr ? apart_from->u_mm : 0.0,
                             apart_from != nullptr ? apart_from->v_mm : 0.0};
  const bool avoid =
      apart_from != nullptr && std::isfinite(held_uv[0]) && std::isfinite(held_uv[1]);
  const int n_picked = pick_apart(start_, nb, n, 2 * pitch, avoid ? held_uv : nullptr,
                                  std::clamp(starts, 1, 8), picked);
  bool found = false;
  int evaluations = 0, jacobians = 0;
  KnownBasins known;
  if (avoid) known.add(held_uv[0], held_uv[1]);
  for (int t = 0; t < n_picked; ++t) {
    const LookupNeighbour& row = nb[picked[t]];
    ContactEstimate start;
    start.u_mm = start_.row_u_mm(row.row);
    start.v_mm = start_.row_v_mm(row.row);
    start.depth_mm = start_.row_depth_mm(row.row);
    PhysicsEstimate e;
    // A fit that enters the held fit's basin or an earlier start's stops there, rejected
    // (kJoinMm).
    if (options_.fit_shear) {
      refine_lean<8>(model_, options_, in, ambient_jac_.data(), start, &e, nullptr, &known);
    } else {
      refine_lean<6>(model_, options_, in, ambient_jac_.data(), start, &e, nullptr, &known);
    }
    if (e.contact.valid() &&
        (e.contact.flags & (kEstimateNoContact | kEstimateNotConverged)) == 0) {
      known.add(e.contact.u_mm, e.contact.v_mm);  // a minimum: its basin is known
    }
    evaluations += e.field_evaluations;
    jacobians += e.jacobians;
    if (e.contact.valid() && (!found || e.chi2 < best.chi2)) {
      best = e;
      found = true;
    }
  }
  if (!found) best.contact.flags = kEstimateRejected;  // no start, or no fit from any
  best.field_evaluations = evaluations;
  best.jacobians = jacobians;
  return best;
}

void PhysicsEstimator::covariance(const sim::Contact& c, const uint8_t* ok, const double* inv_sigma,
                                  PhysicsEstimate* out) const {
  const int nc = model_.channel_count();
  double jac[3 * kMaxChannels];
  model_.contact_jacobian(c, std::span<double>(jac, 3 * static_cast<std::size_t>(nc)));
  const LeanLayout l{1, false};
  using LeanMat = LeanFit<6>::LeanMat;
  using LeanVec = LeanFit<6>::LeanVec;
  LeanMat jtj = LeanMat::Zero();
  for (int i = 0; i < nc; ++i) {
    if (!ok[i]) continue;
    const double w = inv_sigma[i];
    const double* a = &ambient_jac_[3 * static_cast<std::size_t>(i)];
    const double* j = &jac[3 * i];
    LeanVec row;
    row << j[0] * w, j[1] * w, j[2] * w, a[0] * w, a[1] * w, a[2] * w;
    jtj.noalias() += row * row.transpose();
  }
  lean_sigmas(jtj, l, options_.fit_ambient, out->reduced_chi2, 0, &out->sigma_uv_mm,
              &out->sigma_depth_mm, nullptr);
}

ContactCountEstimate PhysicsEstimator::estimate_contacts(std::span<const double> field_ut,
                                                         std::span<const uint8_t> channel_ok,
                                                         const ContactCountOptions& count) const {
  return count_contacts(field_ut, channel_ok, estimate(field_ut, channel_ok), count, {});
}

ContactCountEstimate PhysicsEstimator::count_contacts(
    std::span<const double> field_ut, std::span<const uint8_t> channel_ok,
    const PhysicsEstimate& single, const ContactCountOptions& count,
    std::span<const ContactEstimate> previous) const {
  ContactCountEstimate out;
  out.single = single;
  std::copy(single.ambient_ut, single.ambient_ut + 3, out.ambient_ut);
  const ContactEstimate& one = out.single.contact;
  if (previous.size() < 2 || previous.size() > static_cast<std::size_t>(kMaxContacts)) {
    previous = {};  // one contact, or none, is no start for several
  }
  // Rejected, or nothing found: done, unless contacts are given (a single fit started between
  // two presses can run off the patch while the pair still explains the sample).
  const bool nothing = (one.flags & kEstimateNoContact) != 0;
  if (!one.valid() || (nothing && previous.empty())) return out;
  if (!nothing) {
    out.count = 1;
    out.contacts[0] = one;
    out.sigma_uv_mm[0] = single.sigma_uv_mm;
  }
  if (count.max_contacts < 2 || !(out.single.reduced_chi2 > count.try_ratio)) return out;

  // The pair's fit: both contacts' (u, v, depth), with fit_shear each one's shear too (9 or 13
  // unknowns with the ambient), as one code path over the fixed-size lean fit; then, with
  // max_contacts 3, when the best pair (kept or not: three presses are not explained by two)
  // still leaves more than noise, three the same way.
  CountFit single_fit;
  single_fit.count = out.count;
  single_fit.contacts[0] = one;
  std::copy(single.ambient_ut, single.ambient_ut + 3, single_fit.ambient_ut);
  single_fit.chi2 = single.chi2;
  single_fit.reduced_chi2 = single.reduced_chi2;
  CountFit pair_fit;
  out =
      options_.fit_shear
          ? count_more<2, true>(field_ut, channel_ok, count, previous, single_fit, &pair_fit, out)
          : count_more<2, false>(field_ut, channel_ok, count, previous, single_fit, &pair_fit, out);
  if (count.max_contacts < 3 || pair_fit.count != 2 || !(pair_fit.reduced_chi2 > count.try_ratio)) {
    return out;
  }
  CountFit triple_fit;
  return options_.fit_shear ? count_more<3, true>(field_ut, channel_ok, count, previous, pair_fit,
                                                  &triple_fit, out)
                            : count_more<3, false>(field_ut, channel_ok, count, previous, pair_fit,
                                                   &triple_fit, out);
}

template <int K, bool Shear>
ContactCountEstimate PhysicsEstimator::count_more(std::span<const double> field_ut,
                                                  std::span<const uint8_t> channel_ok,
                                                  const ContactCountOptions& count,
                                                  std::span<const ContactEstimate> previous,
                                                  const CountFit& base, CountFit* fitted,
                                                  ContactCountEstimate out) const {
  static_assert(K >= 2 && K <= kMaxContacts);
  constexpr LeanLayout l{K, Shear};
  constexpr int N = l.size();
  constexpr int pc = l.per_contact();
  // `base` has K - 1 contacts, or none when the single fit found nothing (then only the given
  // contacts are tried).
  const int nc = model_.channel_count();
  const int usable = out.single.channels_used;
  const int unknowns = l.unknowns(options_.fit_ambient);
  if (usable <= unknowns || static_cast<int>(field_ut.size()) != nc) return out;
  FitInput in;
  prepare_fit(field_ut, channel_ok, nc, options_, &in);
  const uint8_t* ok = in.ok;
  const double* y = in.y;
  bool& tried = K == 2 ? out.pair_tried : out.triple_tried;
  int& iterations = K == 2 ? out.pair_iterations : out.triple_iterations;
  tried = true;
  // Starts, in turn, until a fit explains the sample to the noise: the given contacts; the kept
  // ones and a single fit of what they leave (greedy); each kept one split along 4 directions.
  // The best fit is kept. Each start: (u, v, depth, shear u, shear v) a contact.
  using Start = std::array<std::array<double, 5>, K>;
  auto row_of = [](const ContactEstimate& e) {
    return std::array<double, 5>{e.u_mm, e.v_mm, e.depth_mm, e.shear_u_n, e.shear_v_n};
  };
  LeanFit<N> best;
  auto try_start = [&](const Start& x, const double* ambient) {
    typename LeanFit<N>::LeanVec x0;
    for (int j = 0; j < K; ++j) {
      for (int k = 0; k < pc; ++k) x0(j * pc + k) = x[static_cast<std::size_t>(j)][k];
    }
    for (int k = 0; k < 3; ++k) x0(l.ambient_at() + k) = ambient[k];
    LeanFit<N> fit = lean_fit<N>(model_, options_, in, ambient_jac_.data(), l, x0);
    iterations += fit.iterations;
    if (std::isfinite(fit.cost) && fit.cost < best.cost) best = fit;
    return best.cost / (usable - unknowns) <= count.max_reduced_chi2;
  };
  bool done = false;
  bool only_given = false;
  if (previous.size() >= static_cast<std::size_t>(K)) {
    // The given contacts, the deepest K of them; with more given than K, the next count follows
    // from them and this one is fitted from them alone.
    int order[kMaxContacts];
    const int given = static_cast<int>(previous.size());
    for (int j = 0; j < given; ++j) {  // by depth, deepest first (at most 3: insertion)
      int at = j;
      for (; at > 0 && previous[order[at - 1]].depth_mm < previous[j].depth_mm; --at) {
        order[at] = order[at - 1];
      }
      order[at] = j;
    }
    Start x;
    for (int j = 0; j < K; ++j) x[static_cast<std::size_t>(j)] = row_of(previous[order[j]]);
    done = try_start(x, base.ambient_ut);
    only_given = given > K;
  }
  // From kept contacts and their ambient: the greedy start (them and a single fit of what they
  // leave), then each split along 4 directions.
  auto starts_from = [&](const ContactEstimate* kept_in, const double(&ambient)[3]) {
    sim::Contact kept[kMaxContacts];
    for (int j = 0; j < K - 1; ++j) {
      kept[j] = sim::Contact{kept_in[j].u_mm, kept_in[j].v_mm, kept_in[j].depth_mm,
                             options_.tip_radius_mm};
      kept[j].shear_u_n = kept_in[j].shear_u_n;  // 0 unless the fit had the shear
      kept[j].shear_v_n = kept_in[j].shear_v_n;
    }
    double f1[kMaxChannels];
    model_.contact_field_ut(std::span<const sim::Contact>(kept, K - 1),
                            std::span<double>(f1, static_cast<std::size_t>(nc)));
    double rest[kMaxChannels];
    for (int i = 0; i < nc; ++i) {
      const double* a = ambient_jac_.data() + 3 * i;
      rest[i] = y[i] - f1[i] - (a[0] * ambient[0] + a[1] * ambient[1] + a[2] * ambient[2]);
    }
    const PhysicsEstimate next =
        estimate(std::span<const double>(rest, static_cast<std::size_t>(nc)),
                 std::span<const uint8_t>(ok, static_cast<std::size_t>(nc)));
    Start x;
    for (int j = 0; j < K - 1; ++j) x[static_cast<std::size_t>(j)] = row_of(kept_in[j]);
    if (next.contact.valid()) {
      x[K - 1] = row_of(next.contact);
      if (try_start(x, ambient)) return true;
    }
    for (int split = 0; split < K - 1; ++split) {
      for (double deg : {0.0, 45.0, 90.0, 135.0}) {
        const double du = count.start_offset_mm * std::cos(deg * M_PI / 180);
        const double dv = count.start_offset_mm * std::sin(deg * M_PI / 180);
        const ContactEstimate& b = kept_in[split];
        Start xs;
        for (int j = 0, o = 0; j < K - 1; ++j) {
          if (j != split) xs[static_cast<std::size_t>(o++)] = row_of(kept_in[j]);
        }
        xs[K - 2] = {b.u_mm + du, b.v_mm + dv, b.depth_mm, 0, 0};
        xs[K - 1] = {b.u_mm - du, b.v_mm - dv, b.depth_mm, 0, 0};
        if (try_start(xs, ambient)) return true;
      }
    }
    return false;
  };
  if (!done && !only_given && base.count == K - 1)
    done = starts_from(base.contacts, base.ambient_ut);
  if constexpr (Shear && K == 2) {
    // A single fit with the shear can sit between two presses (the shear absorbing the
    // difference); the same starts from the single fit without it.
    if (!done && !only_given && base.count == 1) {
      ContactEstimate from = base.contacts[0];
      from.shear_u_n = from.shear_v_n = 0;
      PhysicsEstimate e;
      refine_lean<6>(model_, options_, in, ambient_jac_.data(), from, &e);
      if (e.contact.valid() && !(e.contact.flags & kEstimateNoContact)) {
        done = starts_from(&e.contact, e.ambient_ut);
      }
    }
  }
  if (!std::isfinite(best.cost)) return out;
  if (!best.converged) {
    // Still moving after max_iterations (more unknowns take longer): once more from there.
    LeanFit<N> more = lean_fit<N>(model_, options_, in, ambient_jac_.data(), l, best.x);
    iterations += more.iterations;
    if (std::isfinite(more.cost) && more.cost <= best.cost) best = more;
  }
  const double chi2 = best.cost;
  const double reduced = chi2 / (usable - unknowns);
  (K == 2 ? out.pair_chi2 : out.triple_chi2) = chi2;
  (K == 2 ? out.pair_reduced_chi2 : out.triple_reduced_chi2) = reduced;
  fitted->count = K;
  fitted->chi2 = chi2;
  fitted->reduced_chi2 = reduced;
  for (int k = 0; k < 3; ++k) fitted->ambient_ut[k] = best.x(l.ambient_at() + k);
  for (int k = 0; k < K; ++k) {
    ContactEstimate& e = fitted->contacts[k];
    e = ContactEstimate{};
    const int o = k * pc;
    e.u_mm = best.x(o);
    e.v_mm = best.x(o + 1);
    e.depth_mm = best.x(o + 2);
    if (l.shear) {
      e.shear_u_n = best.x(o + 3);
      e.shear_v_n = best.x(o + 4);
    }
    e.force_n = model_.force_n(e.depth_mm);
    e.flags = out.single.contact.flags & kEstimateMasked;
    if (!best.converged) e.flags |= kEstimateNotConverged;
    flag_model_range(e, model_);
  }
  // Kept only when better than both the fit of one fewer (kept or not) and the single fit by the
  // information criterion's price (min_chi2_drop for the 3 unknowns a contact adds, 5 with its
  // shear) and min_improvement.
  const double drop = count.min_chi2_drop * (pc / 3.0);
  bool split = reduced <= count.max_reduced_chi2 &&
               base.reduced_chi2 >= count.min_improvement * reduced && base.chi2 - chi2 >= drop &&
               out.single.reduced_chi2 >= count.min_improvement * reduced &&
               out.single.chi2 - chi2 >= drop * (K - 1);
  for (int j = 0; j < K && split; ++j) {
    split = best.x(j * pc + 2) >= count.min_depth_mm;
    for (int i = 0; i < j && split; ++i) {
      split = std::hypot(best.x(j * pc) - best.x(i * pc),
                         best.x(j * pc + 1) - best.x(i * pc + 1)) >= count.min_separation_mm;
    }
  }
  if (!split) return out;
  out.count = K;
  std::copy(fitted->ambient_ut, fitted->ambient_ut + 3, out.ambient_ut);
  for (int k = 0; k < K; ++k) {
    out.contacts[k] = fitted->contacts[k];
    out.sigma_uv_mm[k] = std::numeric_limits<double>::quiet_NaN();
    out.sigma_shear_n[k] = std::numeric_limits<double>::quiet_NaN();
    double sigma_depth = 0;
    if (options_.covariance) {
      lean_sigmas(best.jtj, l, options_.fit_ambient, reduced, k, &out.sigma_uv_mm[k], &sigma_depth,
                  l.shear ? &out.sigma_shear_n[k] : nullptr);
    }
  }
  return out;
}

}  // namespace skinbus::estimators
