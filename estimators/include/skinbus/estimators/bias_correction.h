// skinbus/estimators/bias_correction.h: a learned correction on top of an estimator: the systematic
// error an estimator leaves on one unit (physics its model does not contain, e.g. a lattice whose
// top crushes under the tip), learned from that unit's own presses where the truth is known.
//
// The correction is a smooth function of the estimate: for each of u, v and depth, a tensor
// product of Legendre polynomials in u/half_u, v/half_v (degree `degree_uv` for u and v,
// `depth_degree_uv` for the depth) and depth/max_depth (degree `degree_depth`), fitted by
// ridge-regularised least squares to (truth - estimate) over the presses. Applying it costs one
// basis evaluation ((degree_uv+1)^2 (degree_depth+1) terms), two when the depth's degree differs,
// per estimate and allocates nothing. Only estimates at least `min_depth_mm` deep are corrected;
// the fit uses samples whose estimate and truth are both that deep and whose error is below
// `outlier_mm` (shallow presses carry no position information to learn from, and a few gross
// misses would otherwise dominate a least-squares fit). The force is not corrected.
#pragma once

#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/estimate.h"

namespace skinbus::estimators {

struct BiasCorrectionOptions {
  int degree_uv = 12;  // up to BiasCorrection::kMaxDegreeUv (16)
  // The depth correction's degree in u and v, when it differs from the position's (-1: the
  // same). The position and the depth are fitted separately: each one's coefficients depend on
  // its own degree alone, and BiasCorrection::choose() picks each by its own held-out error.
  int depth_degree_uv = -1;
  int depth_uv() const { return depth_degree_uv < 0 ? degree_uv : depth_degree_uv; }
  int degree_depth = 3;       // up to BiasCorrection::kMaxDegreeDepth (6)
  double ridge = 1e-3;        // relative to the mean diagonal of the normal equations
  double min_depth_mm = 1.0;  // estimates shallower are neither corrected nor used (nor truths)
  double outlier_mm = 3.0;    // fitting samples whose estimate is further off are left out
  // What apply() corrects (the fit learns all three either way): a correction may pay off for
  // the depth and not the position, or the other way round (CorrectionCheck).
  bool correct_position = true, correct_depth = true;
  double half_u_mm = 70, half_v_mm = 70, max_depth_mm = 4.5;  // basis scaling
};

// A correction judged on presses it was not fitted on (BiasCorrection::cross_validate), twice:
// at press places left out of its fit (a held-out place sits one place spacing from the fitted
// ones) and at the fitted places themselves (on samples left out of its fit). A new press falls
// between the two: nearer a fitted place than a held-out one is, further than zero. How far
// between is `new_press_share`, and the figures a choice goes by (xy_ratio(), depth_ratio())
// are the two checks' ratios taken that far from the places' to the held-out one's: a check at
// held-out places alone judges a flexible correction at a distance no new press has, and prefers
// a stiffer one than the new presses do.
struct CorrectionCheck {
  int samples = 0;                // held-out estimates judged (valid, truth >= min_depth_mm)
  double xy_mean_without_mm = 0;  // their mean XY error, uncorrected
  double xy_mean_with_mm = 0;     // ... corrected by a correction fitted without their presses
  // Share of the held-out squared XY error the correction removes (1 - with / without); < 0:
  // it adds error.
  double explained = 0;
  double depth_mean_without_mm = 0, depth_mean_with_mm = 0;  // mean |depth error|, same samples
  // The same XY means per true-depth bin of 1 mm from min_depth_mm (the last open-ended):
  // deeper presses have smaller errors, so the overall mean is mostly the shallowest bin's.
  static constexpr int kDepthBins = 3;
  int bin_samples[kDepthBins] = {};
  double xy_bin_without_mm[kDepthBins] = {}, xy_bin_with_mm[kDepthBins] = {};
  // At the fitted places: a correction fitted on four in five samples of each place's presses,
  // judged on the fifth (their noise is not in its fit; their place and nearby depths are).
  // The same figures as above; no samples: the check at places was not made (no place pressed
  // twice, or too few samples left to fit), and the held-out check alone judges. It assumes
  // the noise of a place's samples independent: noise they share (a press's offset held
  // along its ramp) stays in the fit through the neighbouring samples and earns credit here.
  struct AtPlaces {
    int samples = 0;
    double depth_mean_without_mm = 0, depth_mean_with_mm = 0;
    int bin_samples[kDepthBins] = {};
    double xy_bin_without_mm[kDepthBins] = {}, xy_bin_with_mm[kDepthBins] = {};
  } at_places;
  // A new press's mean distance to the nearest press place, over a held-out place's mean
  // distance to the nearest fitted one (new presses uniform over the places' extent): 0 judges
  // by the places, 1 by the held-out places alone (about 0.38 on a square grid).
  double new_press_share = 1;
  // The position's error corrected over uncorrected as new presses will meet it: per depth bin,
  // the ratio at the places plus new_press_share x (the ratio at held-out places - it), each bin
  // with samples counting alike (as accuracy goals are per bin); 1 without samples.
  double xy_ratio() const;
  // The held-out places' ratio alone (new_press_share 1) and the places' alone (0; bins without
  // samples at the places, or no check there: the held-out ratio).
  double held_out_xy_ratio() const;
  double at_places_xy_ratio() const;
  // The depth's mean error corrected over uncorrected as new presses will meet it, likewise.
  double depth_ratio() const;
  // A part helps when it removes at least kMinGain of its error as new presses will meet it
  // (xy_ratio(), depth_ratio()): a smaller change is within what the check's own presses can
  // tell, and a correction switched on for it would only carry its risk.
  static constexpr double kMinGain = 0.01;
  bool helps_position() const { return samples > 0 && xy_ratio() < 1 - kMinGain; }
  bool helps_depth() const { return samples > 0 && depth_ratio() < 1 - kMinGain; }
  // This check, made at `degree`, as one line for a tool's log: "held out at degree D: XY W -> C
  // mm (x R by depth bin; at the places x P; new presses x N), depth W -> C mm (new presses x
  // Q)" (W without the correction, C with it, R held_out_xy_ratio(), P at_places_xy_ratio(), N
  // xy_ratio(), Q depth_ratio(); "no check at the places" for P and N without a check at the
  // places).
  std::string held_out_text(int degree) const;
};

class BiasCorrection {
 public:
  static constexpr int kMaxDegreeUv = 16, kMaxDegreeDepth = 6;  // the options' bounds

  // Fits the correction from `estimates` and the true (u, v, depth) of the same samples.
  // kDegenerate when fewer usable samples than 4x the basis size remain.
  static Result<BiasCorrection> fit(std::span<const ContactEstimate> estimates,
                                    std::span<const double> true_u_mm,
                                    std::span<const double> true_v_mm,
                                    std::span<const double> true_depth_mm,
                                    const BiasCorrectionOptions& options = {});

  // Whether a correction pays off on this unit, for the position and for the depth, judged on
  // presses it was not fitted on (the correction fitted with both on, whatever `options` says):
  // the press places (the distinct true (u, v)) fall into cells of their spacing (the median
  // distance to the nearest other place) and the cells into kCheckFolds folds by
  // (i + 2 j) mod 5, so that no held-out press has a held-out neighbour; places on an edge are
  // held out like the others (they lie between fitted edge places), the corner places are always
  // fitted (the correction interpolates, it is not asked to extrapolate); each fold's
  // estimates are corrected by a correction fitted on the others. Then once more at the places
  // (CorrectionCheck::at_places): of each place's samples, in the order given, one in kCheckFolds
  // judged (the second of each five) by a correction fitted on the others (not made when no
  // place is pressed twice or that fit is kDegenerate); and
  // CorrectionCheck::new_press_share from the places' layout (new presses on a 64 x 64 lattice over
  // their extent). Errors: as fit() for any fit; kDegenerate for fewer than 10 x kCheckFolds
  // places; kInvalidArgument for lengths that differ. Cost: kCheckFolds + 1 fits, 2 places^2 +
  // 4096 places distances.
  static constexpr int kCheckFolds = 5;
  static Result<CorrectionCheck> cross_validate(std::span<const ContactEstimate> estimates,
                                                std::span<const double> true_u_mm,
                                                std::span<const double> true_v_mm,
                                                std::span<const double> true_depth_mm,
                                                const BiasCorrectionOptions& options = {});

  // The correction to use on this unit, chosen by its error as new presses will meet it
  // (CorrectionCheck::xy_ratio(), depth_ratio()): cross_validate() at each
  // degree in `degrees_uv` (the others as `base`); the position corrected at the degree where it
  // helps new presses most (the lowest CorrectionCheck::xy_ratio(), by depth bin), the depth at
  // the degree where it helps them most (the lowest depth_ratio()), each only if it helps at all
  // (CorrectionCheck::helps_position(), helps_depth()); neither: use no correction. The two are
  // fitted apart, so each one's held-out error at its degree is what it will have together.
  // A degree with more terms than the samples can fit (cross_validate()'s kDegenerate) is left
  // out and listed in `skipped`; the others are chosen from. Errors: as cross_validate(), and its
  // kDegenerate when no degree can be fitted. Cost: that, per degree.
  struct Choice {
    BiasCorrectionOptions options;  // the degrees chosen (degree_uv: the position's, unless only
                                    // the depth is corrected) and what to correct
    // The check of the choice: the XY part at the position's degree, the depth part (held out
    // and at the places) at the depth's.
    CorrectionCheck check;
    std::vector<std::pair<int, CorrectionCheck>> tried;  // every degree's check, in order
    std::vector<std::pair<int, std::string>> skipped;    // degrees too many terms for, and why
    bool any() const { return options.correct_position || options.correct_depth; }
    // "degree D", or "degree P (position), D (depth)" when the depth has its own, for a log.
    std::string degree_text() const;
    // The check and the choice, for a log: "XY mean W -> C mm (explains E % of the squared
    // error), depth mean W -> C mm; as new presses will meet it, XY x R by depth bin, depth x Q:
    // corrects|keeps the position, corrects|keeps the depth".
    std::string summary_text() const;
  };
  static Result<Choice> choose(std::span<const ContactEstimate> estimates,
                               std::span<const double> true_u_mm, std::span<const double> true_v_mm,
                               std::span<const double> true_depth_mm,
                               const BiasCorrectionOptions& base, std::span<const int> degrees_uv);

  // The corrected estimate (unchanged when rejected or shallower than min_depth_mm). Flags are
  // kept as they were: run flag_range() with the patch's extent again if the range matters.
  ContactEstimate apply(const ContactEstimate& e) const;

  // Correction files ("skinbus-correction 1", JSON; docs/physics_estimator.md, "The learned
  // correction"): the options (degrees, scaling, what is corrected) and the coefficients, with
  // the held-out check the choice was made by (`check`, may be null; kept for the record, not
  // read back) and a free-text note of where it came from (`source`). Doubles are written with
  // 17 significant digits: a read-back correction applies bit for bit the same.
  std::string to_json(const CorrectionCheck* check = nullptr, std::string_view source = {}) const;
  // Writes to_json() to `path` (a temporary file renamed: never a torn one). Errors: kIo, naming
  // the path.
  Status write(const std::string& path, const CorrectionCheck* check = nullptr,
               std::string_view source = {}) const;
  // Parses a correction file's text. Errors: kParse naming the field (or the JSON's line and
  // column) for a malformed file, degrees out of range, scales not positive, coefficients not
  // finite or not (degree+1)^2 (degree_depth+1) each (the depth's: its own degree in u and v,
  // `depth_degree_uv` when the file has it).
  static Result<BiasCorrection> parse(std::string_view text, std::string* source = nullptr);
  // Reads and parses `path`: errors as parse() with the path in front; kNotFound for no file.
  static Result<BiasCorrection> read(const std::string& path, std::string* source = nullptr);

  const BiasCorrectionOptions& options() const { return options_; }
  int terms() const { return terms_; }              // of the position's u and v, each
  int depth_terms() const { return depth_terms_; }  // of the depth
  int samples_used() const { return samples_; }
  // RMS of the correction over the fitting samples (mm): how large the learned bias is.
  double rms_correction_mm() const { return rms_correction_mm_; }

 private:
  BiasCorrection() = default;
  // The basis size of one part: (degree_uv + 1)^2 (degree_depth + 1).
  static int terms_of(int degree_uv, int degree_depth) {
    return (degree_uv + 1) * (degree_uv + 1) * (degree_depth + 1);
  }
  // terms_ and depth_terms_ from options_.
  void size_terms() {
    terms_ = terms_of(options_.degree_uv, options_.degree_depth);
    depth_terms_ = terms_of(options_.depth_uv(), options_.degree_depth);
  }
  void basis(double u, double v, double d, int degree_uv, double* out) const;

  BiasCorrectionOptions options_;
  int terms_ = 0, depth_terms_ = 0, samples_ = 0;
  double rms_correction_mm_ = 0;
  std::vector<double> coef_;  // u and v (terms_ each), then depth (depth_terms_)
};

}  // namespace skinbus::estimators
