// skinbus/estimators/creep.h: a lattice that creeps, learned from a unit's ramps and undone
// along a press.
//
// TPU is viscoelastic: under a press of depth d(t) part of the lattice's bend lags the press. The
// law (the simulator's, sim::PatchDesign::creep_fraction; a standard linear solid): the plate
// bends by b = (1 - f) d + f q, where q follows d with time constant tau, dq/dt = (d - q) / tau.
// A static model's inversion of one sample finds the bend b, not the press's depth d: pressing, b
// is less than d, releasing, more (about f x speed x tau: 0.15 mm for f = 0.25, tau = 0.3 s at
// 2 mm/s). One sample cannot tell the two apart; the press's history can. A static press
// (q = d) bends by its depth.
//
// Steps are taken at the samples, the depth linear between a press's samples (exact for a ramp,
// at any sampling: a recording thinned to every 20th sample is undone as well as a whole one;
// the simulator steps its lag with the depth held over each step, which the fitted tau takes up
// as a shift of half a period). Within a press, over the h seconds since its previous sample,
// with e = exp(-h / tau) and g = (tau / h)(1 - e): q_k = e q_{k-1} + (g - e) d_{k-1} + (1 - g) d_k
// and b_k = (1 - f) d_k + f q_k. Between presses (the indenter off the patch, depth 0) q relaxes
// by exp(-gap / tau), and a press's first sample takes q_k = q_{k-1}.
//
// A lattice relaxes over more than one time: the law may have a second, slower lag of the same
// kind (f_s, tau_s, its own q_s): b = (1 - f - f_s) d + f q + f_s q_s. The fit takes it only when
// presses held out of the fit say it explains what one lag leaves.
#pragma once

#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/estimate.h"
#include "skinbus/estimators/lookup_estimator.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::estimators {

struct CreepLaw {
  double fraction = 0;  // f in [0, 1): 0, no first lag
  double time_s = 0.3;  // tau > 0
  // The second, slower lag (f_s >= 0, f + f_s < 1; tau_s > 0): 0, none.
  double slow_fraction = 0;
  double slow_time_s = 3;
  bool none() const { return !(fraction > 0) && !(slow_fraction > 0); }
  // The law of a model's design (sim::PatchDesign::creep_fraction, creep_time_s,
  // creep_slow_fraction, creep_slow_time_s): a unit file's identified creep
  // (sim::PatchModel::of_unit_file), or a simulated unit's.
  static CreepLaw of(const sim::PatchDesign& design) {
    return {design.creep_fraction, design.creep_time_s, design.creep_slow_fraction,
            design.creep_slow_time_s};
  }
  // The law of a unit's parameters (sim::UnitParameters::creep_fraction, ...).
  static CreepLaw of(const sim::UnitParameters& unit) {
    return {unit.creep_fraction, unit.creep_time_s, unit.creep_slow_fraction,
            unit.creep_slow_time_s};
  }
  // Writes the law into a unit's parameters (sim::UnitParameters::creep_fraction, ...).
  void write_to(sim::UnitParameters* unit) const {
    unit->creep_fraction = fraction;
    unit->creep_time_s = time_s;
    unit->creep_slow_fraction = slow_fraction;
    unit->creep_slow_time_s = slow_time_s;
  }
};

// Undoes a law along the samples of one patch, in time order: the depth of the press whose
// sample bent the plate by `bend_mm` (a static model's fit). No allocation; not thread-safe (one
// a patch).
class CreepCompensator {
 public:
  explicit CreepCompensator(const CreepLaw& law = {}) : law_(law) {}
  const CreepLaw& law() const { return law_; }
  // The press's depth (mm) at `t_s` (s, any epoch, increasing). `same_press`: the previous
  // call's sample was this press's previous sample; otherwise the press is new and the lag
  // relaxes over the time since the previous call. A non-finite bend or time is returned as it
  // is and leaves the state alone; with no law the bend is the depth. The depth is the bend
  // scaled by 1 / (1 - f (1 - a)) about the lag's share: the bend's noise grows by as much.
  double depth_mm(double t_s, double bend_mm, bool same_press);
  // Forgets every press (a patch re-tared, a unit swapped).
  void reset() {
    lag_mm_ = slow_lag_mm_ = last_depth_mm_ = 0;
    last_t_s_ = std::numeric_limits<double>::quiet_NaN();
  }

 private:
  CreepLaw law_;
  double lag_mm_ = 0;         // q
  double slow_lag_mm_ = 0;    // q_s
  double last_depth_mm_ = 0;  // the press's previous depth (0 before its first sample)
  double last_t_s_ = std::numeric_limits<double>::quiet_NaN();
};

// The bend of every row of `d` under `law` (mm; NaN where the row has no finite depth, or no
// finite time in a press of several rows): the law run forward over each press's rows in the
// dataset's order (rows of one press consecutive; a row with press -1 is a press of its own),
// from the recorded depths. A press of one row is a static press, relaxed: bent by its depth.
// What a static model should be fitted to on a unit that creeps. Allocates the result.
std::vector<double> creep_bend_mm(const CreepLaw& law, const sim::Dataset& d);

// `d` with each row's depth replaced by its bend under `law` (creep_bend_mm): what a static model
// of a creeping unit (its field correction too) is fitted to and judged on. Allocates the copy.
sim::Dataset bent_dataset(const CreepLaw& law, const sim::Dataset& d);

// A static inversion's estimates of `d`'s rows (estimates[r] of row r) with `law` undone along
// each press of several rows (a ramp: CreepCompensator, from the rows' times); a press of one
// row is a static press and keeps its depth, as do rejected estimates. No law: nothing changes.
void undo_creep(const CreepLaw& law, const sim::Dataset& d, std::span<ContactEstimate> estimates);

// How many presses of `d` were held still at their deepest for at least `min_hold_s` (a press:
// consecutive rows of one press number, times increasing; held: its rows within `tolerance_mm`
// of its deepest depth span that long, as skinbus-dataset --hold's and a lab robot's holds do).
// A lag slower than a ramp, or one a unit that also crushes shows on its ramps, is told apart
// only by such holds: the bends along a ramp fit several laws alike. No allocation.
int held_presses(const sim::Dataset& d, double min_hold_s = 1.0, double tolerance_mm = 0.02);

// What fit_creep() found.
struct CreepFit {
  CreepLaw law;       // none() when none kept; slow_fraction 0 when one lag was kept
  bool kept = false;  // the law lowers the depth residual of presses held out of its fit
  // The depth residual (RMS, mm) of the static inversions about the recorded depths, without the
  // law and with it, on presses held out of the fit (two folds: odd and even presses); with one
  // lag alone (the law's when it has one).
  double held_out_rms_before_mm = 0, held_out_rms_after_mm = 0, held_out_rms_one_lag_mm = 0;
  int presses = 0, rows = 0;  // ramps used, samples inverted
  std::string why;            // when not kept: why (no ramps, no gain on held-out presses, ...)
  std::string summary_text() const;
};

struct CreepFitOptions {
  double tip_radius_mm = 5.0;
  ChannelNoise noise{0, 0};                   // 0: the design's
  double min_depth_mm = 0.3;                  // shallower samples are not inverted
  int max_rows = 6000;                        // samples inverted at most (evenly over the presses)
  double min_time_s = 0.01, max_time_s = 30;  // tau searched over this range
  double min_gain = 0.01;                     // held-out mean square must fall by this share
  bool slow_lag = true;  // try a second, slower lag (kept when it gains min_gain over one)
};

// Fits a creep law to a unit's ramps: each sample's bend by a one-unknown fit of `model` (the
// unit's static model, e.g. identified) at the recorded place, then f and tau by least squares
// of bend - depth against the law's lag (linear in f; tau over a log grid, then refined). Kept
// when it lowers the held-out depth residual by options.min_gain (each fold's law judged on the
// other's presses). Then, with options.slow_lag, two lags (f, tau, f_s, tau_s > tau: the pair of
// times over the grid's pairs, then refined one at a time), kept instead when they lower the
// held-out residual one lag leaves by min_gain again. A recording without ramps (static presses,
// no times) keeps none, saying so.
// Errors: kInvalidArgument (channel count differs from the model's). Single-threaded; cost: a
// few field evaluations per inverted sample (about a second for 6000) and the pairs' search
// (about as long again), allocates.
Result<CreepFit> fit_creep(const sim::PatchModel& model, const sim::Dataset& presses,
                           const CreepFitOptions& options = {});

}  // namespace skinbus::estimators
