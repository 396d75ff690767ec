// skinbus/estimators/estimate.h: what every per-patch estimator takes and gives, and the input
// checks they share.
//
// An estimator turns one tared sample of a patch (the field change at every channel, uT, each
// sensor's own frame, channel order s0 x y z, s1 x y z, ...) into one contact in the patch frame
// (u, v along the sensor grid, mm, origin at the patch centre; depth positive into the skin, mm;
// normal force, N). Bad input never becomes a silent wrong contact:
//   - check_sample() marks channels that cannot be trusted (NaN/Inf, at or beyond the sensor's
//     range, or marked dead by the caller, e.g. from the node's status flags);
//   - an estimator that can drop channels (the physics inversion) masks them and says so in the
//     flags; one that cannot (a CNN) rejects the sample with kEstimateRejected and a reason;
//   - a contact outside the patch, or a depth outside [0, max], is flagged, never clipped
//     silently.
// Nothing here allocates.
#pragma once

#include <cstdint>
#include <span>

namespace skinbus::estimators {

// Bits of ContactEstimate::flags.
enum EstimateFlag : uint32_t {
  kEstimateOk = 0,
  kEstimateMasked = 1u << 0,        // some channels were left out (see SampleCheck)
  kEstimateRejected = 1u << 1,      // no estimate: the fields other than flags are not valid
  kEstimateOutsidePatch = 1u << 2,  // (u, v) beyond the patch edge (+ margin)
  kEstimateDepthRange = 1u << 3,    // depth below 0 or beyond the deepest press the model knows
  kEstimateNotConverged = 1u << 4,  // an iterative estimator stopped without converging
  kEstimatePoorFit = 1u << 5,       // the residual is large for the sensor noise
  kEstimateNoContact = 1u << 6,     // the signal is at noise level: nothing pressed
  // (u, v) outside the area the unit's model was fitted on (its unit file's pressed_area_mm,
  // widened by sim::kPressedAreaMarginMm): the model, and so the uncertainty, are extrapolated.
  kEstimateExtrapolated = 1u << 7,
};

// Why a sample was rejected (when kEstimateRejected is set).
enum class RejectReason : uint8_t {
  kNone = 0,
  kNonFinite,       // NaN or Inf in a channel the estimator needs
  kSaturated,       // a needed channel at or beyond the sensor's range
  kDead,            // a needed channel marked dead by the caller
  kTooFewChannels,  // too many channels masked to estimate anything
  kWrongShape,      // the sample has a different number of channels than the model
};

constexpr const char* reject_reason_name(RejectReason r) {
  switch (r) {
    case RejectReason::kNone:
      return "none";
    case RejectReason::kNonFinite:
      return "non_finite";
    case RejectReason::kSaturated:
      return "saturated";
    case RejectReason::kDead:
      return "dead";
    case RejectReason::kTooFewChannels:
      return "too_few_channels";
    case RejectReason::kWrongShape:
      return "wrong_shape";
  }
  return "unknown";
}

// The most contacts one sample of one patch is resolved into (PhysicsEstimator::count_contacts).
inline constexpr int kMaxContacts = 3;

struct ContactEstimate {
  double u_mm = 0, v_mm = 0, depth_mm = 0, force_n = 0;
  uint32_t flags = kEstimateOk;
  RejectReason reason = RejectReason::kNone;
  // Tangential force on the skin along u and v, N: 0 from estimators that do not estimate it
  // (PhysicsOptions::fit_shear).
  double shear_u_n = 0, shear_v_n = 0;

  bool valid() const { return (flags & kEstimateRejected) == 0; }
};

// Limits of the input, from the sensor configuration.
struct InputLimits {
  // A tared channel whose magnitude reaches this is treated as saturated (uT). The default suits
  // the MLX90393 at the simulator's configuration: set it from mlx90393 sensitivity * 32767
  // minus the rest field for another gain.
  double saturation_ut = 1.0e4;
};

// Result of check_sample().
struct SampleCheck {
  int masked = 0;  // channels marked bad in channel_ok
  int non_finite = 0, saturated = 0, dead = 0;
  RejectReason first_reason = RejectReason::kNone;  // of the first bad channel
};

// Checks one sample. `channel_ok` has one entry per channel: on entry, 0 marks a channel the
// caller knows is dead (any other value: alive); on return, 1 for a usable channel, 0 otherwise.
// `field_ut` and `channel_ok` must have the same size; if they do not, every channel is marked
// unusable and first_reason is kWrongShape.
SampleCheck check_sample(std::span<const double> field_ut, std::span<uint8_t> channel_ok,
                         const InputLimits& limits = {});

// Flags an estimate against the patch extent (half sizes, mm, plus `margin_mm`) and the depth
// range [0, max_depth_mm] (a small negative depth within `margin_depth_mm` is not flagged).
// Non-finite outputs are turned into a rejection (kNonFinite): no NaN leaves an estimator.
constexpr double kRangeMarginMm = 2.0, kRangeMarginDepthMm = 0.2;
void flag_range(ContactEstimate& e, double half_u_mm, double half_v_mm, double max_depth_mm,
                double margin_mm = kRangeMarginMm, double margin_depth_mm = kRangeMarginDepthMm);

}  // namespace skinbus::estimators
