// skinbus/estimators/lookup_estimator.h: nearest-neighbour lookup of a contact in a table of
// fields: the "grid lookup" baseline estimator and the start of the physics inversion
// (skinbus/estimators/physics_estimator.h).
//
// A table holds rows (field at every channel, u, v, depth, force). A sample is matched to the
// row nearest to it in noise-whitened field space: distance^2 = sum over usable channels of
// ((sample - row) / sigma)^2, sigma the sensor noise of the channel's axis (xy or z). The
// table is built either from a forward model on a (u, v, depth) grid or from a dataset's rows
// (a unit's own training presses).
//
// Search cost: exact nearest neighbours by partial distances with early exit. Channels are
// visited in order of the sample's own whitened magnitude (the strongest first), so a row far
// from the sample exceeds the best distance so far after a few channels; a first pass over
// every 16th row sets a good bound, so most rows cost a few channels' distance instead of 48
// (times per table size: docs/physics_estimator.md). Memory: rows x channels floats
// (7.5 MB for the default grid).
// Thread safety: a built table is immutable; estimate() and nearest() are const and safe to call
// from several threads.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/estimate.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators {

// Largest channel count any estimator here takes (256 sensors x 3 axes).
inline constexpr int kMaxChannels = 3 * sim::kMaxSensors;

// Sensor noise per axis (1 sd, uT): whitens residuals and distances.
struct ChannelNoise {
  double xy_ut = 0.7, z_ut = 1.15;
  // The noise of a design's sensor configuration (sim/mlx90393.h).
  static ChannelNoise of(const sim::PatchDesign& design);
  double sigma(int channel) const { return channel % 3 == 2 ? z_ut : xy_ut; }
};

// A tared sample of `contacts` on `truth` with its design's sensor noise (independent Gaussian
// per channel, drawn from `rng`): the simulated sample the tests and benchmarks feed the
// estimators. Allocates the result.
std::vector<double> noisy_field(const sim::PatchModel& truth,
                                std::span<const sim::Contact> contacts, sim::Rng& rng);

// A (u, v, depth) grid of presses for a table built from a model.
struct LookupGrid {
  double pitch_mm = 2.5;  // u and v pitch, centred on the patch, covering its full extent
  std::vector<double> depths_mm = {0.25, 0.5, 0.75, 1, 1.5, 2, 2.5, 3, 3.5, 4, 5, 6};
  double tip_radius_mm = 5.0;  // the indenter (sim::RampProtocol's default)
};

struct LookupOptions {
  int neighbours = 1;     // k: the estimate is the inverse-distance weighted mean of the k nearest
                          // rows (1..8; 1: the nearest row itself)
  int min_channels = 12;  // fewer usable channels: rejected with kTooFewChannels
  // kEstimateNoContact when the sample's whitened energy exceeds what noise alone gives by less
  // than this many standard deviations: (sum q^2 - n) / sqrt(2 n) < no_contact_sigmas.
  double no_contact_sigmas = 5.0;
  InputLimits limits;  // saturation threshold for check_sample()
  // Compare fields with their uniform-ambient component removed: rows and sample are projected
  // (in whitened space, all channels) onto the complement of the 3 directions a uniform ambient
  // field takes (each sensor's rotation and gain). A sample carrying an ambient offset since the
  // tare then finds the same rows; the physics inversion starts from such a table. Costs one
  // 3 x channels projection per sample. With masked channels the projection is approximate.
  bool ambient_invariant = false;
};

struct LookupNeighbour {
  int row = -1;
  double distance2 = 0;  // whitened squared distance over the usable channels
};

class LookupEstimator {
 public:
  // Rows of `model`'s contact field on `grid` (u, v over the patch extent at grid.pitch_mm).
  // Cost: rows x one forward evaluation (about 40k rows, ~0.5 s, for the default grid).
  static Result<LookupEstimator> from_model(const sim::PatchModel& model,
                                            const LookupGrid& grid = {},
                                            const LookupOptions& options = {});
  // Rows of a dataset (tared fields with their u, v, depth, force), every `row_stride`-th row
  // with depth > 0. The design gives the noise (unless `noise` is set), patch extent and depth
  // range; its channel count must match the dataset's.
  static Result<LookupEstimator> from_dataset(const sim::PatchDesign& design,
                                              const sim::Dataset& data, int row_stride = 1,
                                              const LookupOptions& options = {},
                                              const ChannelNoise* noise = nullptr);

  int rows() const { return static_cast<int>(u_.size()); }
  int channels() const { return channels_; }
  const ChannelNoise& noise() const { return noise_; }
  const LookupOptions& options() const { return options_; }
  double row_u_mm(int r) const { return u_[r]; }
  double row_v_mm(int r) const { return v_[r]; }
  double row_depth_mm(int r) const { return depth_[r]; }
  double row_force_n(int r) const { return force_[r]; }

  // One tared sample (channels() values, uT) to a contact. `channel_ok` (empty: all alive) marks
  // channels the caller knows are dead with 0; NaN/Inf and saturated channels are masked too
  // (check_sample()). Masked channels are left out of the distance and kEstimateMasked is set;
  // too few usable channels reject with kTooFewChannels. The result is range-flagged
  // (flag_range()). No allocation.
  ContactEstimate estimate(std::span<const double> field_ut,
                           std::span<const uint8_t> channel_ok = {}) const;

  // The out.size() nearest rows (sorted, nearest first) to a sample whose channels are given
  // already whitened (field / sigma) in `whitened`, using only channels with usable[c] != 0
  // (projected first when the table is ambient_invariant).
  // Returns how many were found (min(out.size(), rows())). No allocation for out.size() <= 8.
  int nearest(std::span<const double> whitened, std::span<const uint8_t> usable,
              std::span<LookupNeighbour> out) const;

 private:
  LookupEstimator() = default;

  int channels_ = 0;
  ChannelNoise noise_;
  LookupOptions options_;
  double half_u_mm_ = 70, half_v_mm_ = 70, max_depth_mm_ = 9;
  void set_ambient_basis(const sim::PatchModel& model);
  void project(double* whitened) const;  // removes the ambient component (ambient_invariant)

  std::vector<double> ambient_basis_;  // channels x 3, orthonormal columns (ambient_invariant)
  std::vector<float> table_;           // rows x channels, whitened
  std::vector<double> u_, v_, depth_, force_;
};

}  // namespace skinbus::estimators
