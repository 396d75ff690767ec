#include "skinbus/estimators/lookup_estimator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "skinbus/sim/mlx90393.h"

namespace skinbus::estimators {

namespace {

constexpr int kMaxNeighbours = 8;
constexpr int kFirstPassStride = 16;  // rows visited first to set a good bound
constexpr int kChannelBlock = 6;      // channels summed between early-exit checks

// Keeps `out` sorted by distance; inserts (row, d2) if it beats the last entry.
void insert_neighbour(std::span<LookupNeighbour> out, int& found, int row, double d2) {
  const int k = static_cast<int>(out.size());
  int pos = found < k ? found : k - 1;
  if (found == k && !(d2 < out[k - 1].distance2)) return;
  while (pos > 0 && out[pos - 1].distance2 > d2) {
    out[pos] = out[pos - 1];
    --pos;
  }
  out[pos] = {row, d2};
  if (found < k) ++found;
}

}  // namespace

void LookupEstimator::set_ambient_basis(const sim::PatchModel& model) {
  // Whitened response of every channel to a unit ambient field along x, y, z; Gram-Schmidt.
  const std::size_t nc = static_cast<std::size_t>(channels_);
  ambient_basis_.assign(nc * 3, 0.0);
  const auto& sensors = model.sensors();
  for (std::size_t s = 0; s < sensors.size(); ++s) {
    const double g[3] = {sensors[s].gain.x, sensors[s].gain.y, sensors[s].gain.z};
    for (int axis = 0; axis < 3; ++axis) {
      const std::size_t c = 3 * s + static_cast<std::size_t>(axis);
      const double w = g[axis] / noise_.sigma(static_cast<int>(c));
      ambient_basis_[3 * c + 0] = sensors[s].frame.r[axis].x * w;
      ambient_basis_[3 * c + 1] = sensors[s].frame.r[axis].y * w;
      ambient_basis_[3 * c + 2] = sensors[s].frame.r[axis].z * w;
    }
  }
  for (int k = 0; k < 3; ++k) {
    for (int j = 0; j < k; ++j) {
      double d = 0;
      for (std::size_t c = 0; c < nc; ++c)
        d += ambient_basis_[3 * c + k] * ambient_basis_[3 * c + j];
      for (std::size_t c = 0; c < nc; ++c)
        ambient_basis_[3 * c + k] -= d * ambient_basis_[3 * c + j];
    }
    double n = 0;
    for (std::size_t c = 0; c < nc; ++c) n += ambient_basis_[3 * c + k] * ambient_basis_[3 * c + k];
    n = n > 0 ? 1 / std::sqrt(n) : 0.0;
    for (std::size_t c = 0; c < nc; ++c) ambient_basis_[3 * c + k] *= n;
  }
}

void LookupEstimator::project(double* w) const {
  if (ambient_basis_.empty()) return;
  double a[3] = {0, 0, 0};
  for (int c = 0; c < channels_; ++c) {
    for (int k = 0; k < 3; ++k) a[k] += ambient_basis_[3 * c + k] * w[c];
  }
  for (int c = 0; c < channels_; ++c) {
    for (int k = 0; k < 3; ++k) w[c] -= ambient_basis_[3 * c + k] * a[k];
  }
}

ChannelNoise ChannelNoise::of(const sim::PatchDesign& design) {
  return {sim::mlx90393_noise_xy_ut(design.sensor_config),
          sim::mlx90393_noise_z_ut(design.sensor_config)};
}

std::vector<double> noisy_field(const sim::PatchModel& truth,
                                std::span<const sim::Contact> contacts, sim::Rng& rng) {
  std::vector<double> f(static_cast<std::size_t>(truth.channel_count()));
  truth.contact_field_ut(contacts, f);
  const ChannelNoise noise = ChannelNoise::of(truth.design());
  for (std::size_t k = 0; k < f.size(); ++k)
    f[k] += noise.sigma(static_cast<int>(k)) * rng.normal();
  return f;
}

Result<LookupEstimator> LookupEstimator::from_model(const sim::PatchModel& model,
                                                    const LookupGrid& grid,
                                                    const LookupOptions& options) {
  const sim::PatchDesign& d = model.design();
  if (!(grid.pitch_mm > 0.1) || grid.depths_mm.empty()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "lookup grid: pitch_mm must be > 0.1 and depths_mm not empty");
  }
  if (options.neighbours < 1 || options.neighbours > kMaxNeighbours) {
    return make_error(ErrorCode::kInvalidArgument, "lookup: neighbours must be 1..8");
  }
  LookupEstimator e;
  e.channels_ = model.channel_count();
  e.noise_ = ChannelNoise::of(d);
  e.options_ = options;
  e.half_u_mm_ = d.size_u_mm / 2;
  e.half_v_mm_ = d.size_v_mm / 2;
  e.max_depth_mm_ = model.max_depth_mm();
  if (options.ambient_invariant) e.set_ambient_basis(model);
  const int nu = static_cast<int>(std::floor(d.size_u_mm / grid.pitch_mm)) + 1;
  const int nv = static_cast<int>(std::floor(d.size_v_mm / grid.pitch_mm)) + 1;
  const double u0 = -(nu - 1) * grid.pitch_mm / 2, v0 = -(nv - 1) * grid.pitch_mm / 2;
  const std::size_t nc = static_cast<std::size_t>(e.channels_);
  std::vector<double> field(nc), inv_sigma(nc);
  for (std::size_t c = 0; c < nc; ++c) inv_sigma[c] = 1 / e.noise_.sigma(static_cast<int>(c));
  e.table_.reserve(static_cast<std::size_t>(nu) * nv * grid.depths_mm.size() * nc);
  for (double depth : grid.depths_mm) {
    if (!(depth > 0) || !std::isfinite(depth)) {
      return make_error(ErrorCode::kInvalidArgument, "lookup grid: depths must be > 0");
    }
    for (int j = 0; j < nv; ++j) {
      for (int i = 0; i < nu; ++i) {
        const sim::Contact c{u0 + i * grid.pitch_mm, v0 + j * grid.pitch_mm, depth,
                             grid.tip_radius_mm};
        model.contact_field_ut(std::span<const sim::Contact>(&c, 1), field);
        for (std::size_t k = 0; k < nc; ++k) field[k] *= inv_sigma[k];
        e.project(field.data());
        for (std::size_t k = 0; k < nc; ++k) e.table_.push_back(static_cast<float>(field[k]));
        e.u_.push_back(c.u_mm);
        e.v_.push_back(c.v_mm);
        e.depth_.push_back(depth);
        e.force_.push_back(model.force_n(depth));
      }
    }
  }
  return e;
}

Result<LookupEstimator> LookupEstimator::from_dataset(const sim::PatchDesign& design,
                                                      const sim::Dataset& data, int row_stride,
                                                      const LookupOptions& options,
                                                      const ChannelNoise* noise) {
  if (Status s = sim::validate(design); !s.ok()) return s.error();
  if (data.channels() != design.channel_count()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "lookup: the dataset has " + std::to_string(data.channels()) +
                          " channels, the design " + std::to_string(design.channel_count()));
  }
  if (row_stride < 1) return make_error(ErrorCode::kInvalidArgument, "lookup: row_stride < 1");
  if (options.neighbours < 1 || options.neighbours > kMaxNeighbours) {
    return make_error(ErrorCode::kInvalidArgument, "lookup: neighbours must be 1..8");
  }
  LookupEstimator e;
  e.channels_ = design.channel_count();
  e.noise_ = noise ? *noise : ChannelNoise::of(design);
  e.options_ = options;
  e.half_u_mm_ = design.size_u_mm / 2;
  e.half_v_mm_ = design.size_v_mm / 2;
  Result<sim::PatchModel> nominal = sim::PatchModel::nominal(design);
  if (!nominal.ok()) return nominal.error();
  e.max_depth_mm_ = nominal->max_depth_mm();
  if (options.ambient_invariant) e.set_ambient_basis(*nominal);
  const std::size_t nc = static_cast<std::size_t>(e.channels_);
  std::vector<double> w(nc);
  for (std::size_t r = 0; r < data.rows(); r += static_cast<std::size_t>(row_stride)) {
    if (!(data.depth_mm[r] > 0)) continue;
    const double* f = data.field(r);
    bool finite = std::isfinite(data.u_mm[r]) && std::isfinite(data.v_mm[r]) &&
                  std::isfinite(data.depth_mm[r]) && std::isfinite(data.force_n[r]);
    for (std::size_t k = 0; k < nc && finite; ++k) finite = std::isfinite(f[k]);
    if (!finite) continue;
    for (std::size_t k = 0; k < nc; ++k) w[k] = f[k] / e.noise_.sigma(static_cast<int>(k));
    e.project(w.data());
    for (std::size_t k = 0; k < nc; ++k) e.table_.push_back(static_cast<float>(w[k]));
    e.u_.push_back(data.u_mm[r]);
    e.v_.push_back(data.v_mm[r]);
    e.depth_.push_back(data.depth_mm[r]);
    e.force_.push_back(data.force_n[r]);
  }
  if (e.u_.empty()) {
    return make_error(ErrorCode::kDegenerate, "lookup: the dataset has no usable contact rows");
  }
  return e;
}

int LookupEstimator::nearest(std::span<const double> whitened, std::span<const uint8_t> usable,
                             std::span<LookupNeighbour> out) const {
  if (out.empty() || rows() == 0 || whitened.size() < static_cast<std::size_t>(channels_) ||
      usable.size() < static_cast<std::size_t>(channels_)) {
    return 0;
  }
  // The sample, masked channels zeroed, ambient component removed for an invariant table.
  double q[kMaxChannels];
  for (int c = 0; c < channels_; ++c) q[c] = usable[c] != 0 ? whitened[c] : 0.0;
  project(q);
  // Usable channels, strongest first: a far row exceeds the bound after a few of them.
  int order[kMaxChannels];
  float query[kMaxChannels];
  int n = 0;
  for (int c = 0; c < channels_; ++c) {
    if (usable[c] != 0) order[n++] = c;
  }
  std::sort(order, order + n, [&](int a, int b) { return std::fabs(q[a]) > std::fabs(q[b]); });
  for (int t = 0; t < n; ++t) query[t] = static_cast<float>(q[order[t]]);

  int found = 0;
  const int k = static_cast<int>(out.size());
  const std::size_t stride = static_cast<std::size_t>(channels_);
  auto visit = [&](int r) {
    const float* row = table_.data() + static_cast<std::size_t>(r) * stride;
    const double bound = found < k ? std::numeric_limits<double>::infinity() : out[k - 1].distance2;
    double d2 = 0;
    for (int t0 = 0; t0 < n; t0 += kChannelBlock) {
      const int t1 = std::min(n, t0 + kChannelBlock);
      float part = 0;
      for (int t = t0; t < t1; ++t) {
        const float diff = row[order[t]] - query[t];
        part += diff * diff;
      }
      d2 += part;
      if (d2 >= bound) return;
    }
    insert_neighbour(out, found, r, d2);
  };
  const int nr = rows();
  for (int r = 0; r < nr; r += kFirstPassStride) visit(r);
  for (int r = 0; r < nr; ++r) {
    if (r % kFirstPassStride != 0) visit(r);
  }
  return found;
}

ContactEstimate LookupEstimator::estimate(std::span<const double> field_ut,
                                          std::span<const uint8_t> channel_ok) const {
  ContactEstimate e;
  if (static_cast<int>(field_ut.size()) != channels_ ||
      (!channel_ok.empty() && channel_ok.size() != field_ut.size())) {
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kWrongShape;
    return e;
  }
  uint8_t ok[kMaxChannels];
  for (int c = 0; c < channels_; ++c) ok[c] = channel_ok.empty() ? 1 : channel_ok[c];
  const SampleCheck check = check_sample(
      field_ut, std::span<uint8_t>(ok, static_cast<std::size_t>(channels_)), options_.limits);
  const int usable = channels_ - check.masked;
  if (usable < options_.min_channels) {
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kTooFewChannels;
    return e;
  }
  double whitened[kMaxChannels];
  double energy = 0;
  for (int c = 0; c < channels_; ++c) {
    whitened[c] = ok[c] ? field_ut[c] / noise_.sigma(c) : 0.0;
    energy += whitened[c] * whitened[c];
  }
  LookupNeighbour nb[kMaxNeighbours];
  const int found =
      nearest(std::span<const double>(whitened, static_cast<std::size_t>(channels_)),
              std::span<const uint8_t>(ok, static_cast<std::size_t>(channels_)),
              std::span<LookupNeighbour>(nb, static_cast<std::size_t>(options_.neighbours)));
  if (found == 0) {
    e.flags = kEstimateRejected;
    e.reason = RejectReason::kTooFewChannels;
    return e;
  }
  // Inverse-distance weights; an exact match takes all the weight.
  double wsum = 0, u = 0, v = 0, depth = 0, force = 0;
  for (int i = 0; i < found; ++i) {
    const double w = 1 / (std::sqrt(nb[i].distance2) + 1e-9);
    wsum += w;
    u += w * u_[nb[i].row];
    v += w * v_[nb[i].row];
    depth += w * depth_[nb[i].row];
    force += w * force_[nb[i].row];
  }
  e.u_mm = u / wsum;
  e.v_mm = v / wsum;
  e.depth_mm = depth / wsum;
  e.force_n = force / wsum;
  if (check.masked > 0) e.flags |= kEstimateMasked;
  if ((energy - usable) / std::sqrt(2.0 * usable) < options_.no_contact_sigmas)
    e.flags |= kEstimateNoContact;
  flag_range(e, half_u_mm_, half_v_mm_, max_depth_mm_);
  return e;
}

}  // namespace skinbus::estimators
