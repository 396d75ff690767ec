// skinbus-identify: fit one patch unit's physical parameters from its own presses and write them
// as a unit file, for skinbus-dataset --unit (training data from the unit's own physics) and the
// physics estimator.
//
//   skinbus-identify unit7_presses.csv -o unit7.json --held-out unit7_check.csv
#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "skinbus/estimators/creep.h"
#include "skinbus/estimators/field_correction_fit.h"
#include "skinbus/estimators/unit_identification.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/unit_parameters.h"
#include "tool_util.h"

namespace {

using namespace skinbus;

constexpr int kExitOk = 0, kExitFailed = 1, kExitUsage = 2;

void print_quality(const char* what, const estimators::FitQuality& nominal,
                   const estimators::FitQuality& fitted) {
  std::printf("%s (%d samples): residual RMS %.3f noise units identified, %.3f nominal\n", what,
              fitted.rows, fitted.rms, nominal.rms);
  for (std::size_t b = 0; b < fitted.bins.size(); ++b) {
    const estimators::DepthBinResidual& f = fitted.bins[b];
    if (f.rows == 0) continue;
    const double nom = b < nominal.bins.size() ? nominal.bins[b].rms : 0.0;
    std::printf("  depth %.0f-%.0f mm  n=%-5d identified %.3f  nominal %.3f\n", f.depth_lo_mm,
                f.depth_hi_mm, f.rows, f.rms, nom);
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-identify: fit one patch unit's physical parameters (magnet positions, moments and\n"
      "tilts, sensor positions, mountings and gains, the lattice's spread along u and v and its\n"
      "lateral coupling; 441 numbers for the standard patch, placed in the frame the presses\n"
      "were made in) from that unit's own presses with Ceres, and write them as a unit file\n"
      "(docs/physics_estimator.md, \"Unit files\").\n\n"
      "Input: a dataset in the project's CSV format (docs/dataset_format.md) of presses at known\n"
      "positions and depths, e.g. an indentation robot's ramp protocol: 361 presses on the\n"
      "seed's 19 x 19 grid take ~5-15 s to fit (about a minute for a unit the model class\n"
      "cannot explain); at least ~20 presses spread over the patch.\n"
      "The fit reports its residual in sensor-noise units, overall and per depth bin: about 1\n"
      "means the model explains the unit down to the noise; clearly above 1 (> 1.1) means the\n"
      "unit has physics the model class does not contain (e.g. a top that crushes): learn\n"
      "its field correction too (--field-correction: a smooth correction of the modelled\n"
      "field, from the same presses; a few seconds) and the learned correction on top\n"
      "(docs/physics_estimator.md, docs/models.md).\n\n"
      "Examples:\n"
      "  skinbus-dataset --plan grid --fabricated --uid 0x5B07 -o unit7.csv\n"
      "  skinbus-identify unit7.csv -o unit7.json\n"
      "  skinbus-identify lab.csv -o unit.json --design my_patch.yaml --field-correction\n"
      "  skinbus-dataset --plan halton --count 12000 --unit unit7.json -o unit7_train.csv\n"};
  std::string presses_path, out_path, held_out_path;
  bool cylinder = false;
  double radius = 45;
  estimators::IdentificationOptions opt;
  app.add_option("presses", presses_path, "the unit's presses (dataset CSV)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("-o,--output", out_path, "unit file to write (JSON)")->required();
  app.add_option("--held-out", held_out_path,
                 "other presses of the same unit (dataset CSV): residual on data not fitted")
      ->check(CLI::ExistingFile);
  std::string design_path;
  app.add_option("--design", design_path,
                 "the unit's patch design file (docs/design_file.md; default: the built-in "
                 "design, sim/designs/nominal.yaml): the model class the fit starts from")
      ->check(CLI::ExistingFile);
  app.add_flag("--cylinder", cylinder, "the patch is wrapped on a cylinder (skin on a limb)");
  app.add_option("--radius", radius, "cylinder skin radius, mm")->capture_default_str();
  CLI::Option* tip_given =
      app.add_option("--tip-radius", opt.tip_radius_mm,
                     "the indenter's round tip radius, mm (default: the recording's, its "
                     "protocol header's tip_radius_mm=, else the design's indenter)")
          ->check(CLI::Range(0.0, sim::kMaxIndenterTipRadiusMm));
  app.add_option("--depths-per-press", opt.depths_per_press, "samples kept per press")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  app.add_option("--min-depth", opt.min_depth_mm, "shallower samples are not used, mm")
      ->capture_default_str();
  bool keep_globals = false;
  app.add_flag("--keep-globals", keep_globals,
               "start every part from the design file as it is, without first fitting the "
               "design's global physics (spread, lateral coupling, magnet and sensor heights, "
               "moment scale, anisotropy, the presses' frame and depth zero)");
  bool hold_depth_zero = false;
  app.add_flag("--hold-depth-zero", hold_depth_zero,
               "the presses read depth 0 where the tip met the surface (an indenter whose zero "
               "was measured): hold the depth zero there rather than fit it. Fitted, a lattice "
               "whose physics the model lacks near the surface (a top that crushes) may move it "
               "a few tenths of a millimetre");
  app.add_option("--max-residual", opt.max_residual,
                 "refuse a fit leaving more than this residual (RMS, noise units)")
      ->capture_default_str();
  std::string refused_path;
  app.add_option("--refused-out", refused_path,
                 "when the fit is refused for its residual, write it here anyway (exit status "
                 "still 1): the model class's nearest model of the unit, to simulate training "
                 "presses from (scripts/calibrate_unit.sh's network route), never to refine on");
  bool field_correction = false;
  app.add_flag("--field-correction", field_correction,
               "then learn what the unit's field does beyond the fitted class from the same "
               "presses (a smooth correction of the modelled field, chosen on press places held "
               "out of its fit; docs/physics_estimator.md, \"The field correction\") and put it "
               "in the unit file when it lowers the held-out residual. A fit refused for its "
               "residual is kept when the correction brings the held-out residual within "
               "--max-residual. When the class leaves physics and the depth zero was fitted "
               "off the surface, the fit is made again with the zero held there, and the one "
               "whose correction explains held-out places better is kept (a crushing top can "
               "pass for an indenter's zero). When the class leaves physics, the creep is "
               "chosen with the correction too (the identified law, none, or one fitted on the "
               "corrected model: the one whose correction explains held-out places best; a "
               "crushing top can pass for a slow lag)");
  CLI11_PARSE(app, argc, argv);
  opt.fit_globals = !keep_globals;
  if (hold_depth_zero) opt.global_priors.depth_zero_sd_mm = 0;
  opt.progress = [](const std::string& line) {
    std::fprintf(stderr, "skinbus-identify: %s\n", line.c_str());
  };

  Result<sim::PatchDesign> read = sim::read_design_or_builtin(design_path);
  if (!read.ok())
    return skinbus::tools::fail("skinbus-identify", read.error().to_string(), kExitUsage);
  sim::PatchDesign design = read.value();
  if (cylinder) {
    design.surface = sim::SurfaceKind::kCylinder;
    design.radius_mm = radius;
  }
  Result<sim::Dataset> presses = sim::read_dataset_csv(presses_path);
  if (!presses.ok()) {
    return skinbus::tools::fail("skinbus-identify", presses.error().to_string(), kExitFailed);
  }
  if (const std::string note = sim::leave_out_stuck_channels(&*presses); !note.empty()) {
    std::fprintf(stderr, "skinbus-identify: %s: %s\n", presses_path.c_str(), note.c_str());
  }
  // The model's lattice compresses no deeper than the design says: deeper presses it cannot
  // explain (it holds them at that depth) are left out, and the user told why.
  const auto leave_out_deeper = [&](sim::Dataset* d, const std::string& path) {
    const std::string note = sim::leave_out_presses_past_the_lattice(d, design);
    if (note.empty()) return;
    std::fprintf(stderr, "skinbus-identify: %s: %s: is thickness_mm the patch's?\n", path.c_str(),
                 note.c_str());
  };
  leave_out_deeper(&*presses, presses_path);
  std::string tip_from = "--tip-radius";
  if (tip_given->count() == 0) {
    Result<double> tip = sim::presses_tip_radius_mm(*presses, design, &tip_from);
    if (!tip.ok()) {
      return skinbus::tools::fail("skinbus-identify", presses_path + ": " + tip.error().message,
                                  kExitFailed);
    }
    opt.tip_radius_mm = *tip;
  }
  std::fprintf(stderr, "skinbus-identify: indenter tip radius %g mm (%s)\n", opt.tip_radius_mm,
               tip_from.c_str());
  if (opt.tip_radius_mm != design.indenter_tip_radius_mm) {
    std::fprintf(stderr,
                 "skinbus-identify: note: the design's indenter is %g mm: the host refines, and "
                 "skinbus-dataset presses, with the design's\n",
                 design.indenter_tip_radius_mm);
  }
  std::optional<sim::Dataset> held_out;
  if (!held_out_path.empty()) {
    Result<sim::Dataset> h = sim::read_dataset_csv(held_out_path);
    if (!h.ok()) {
      return skinbus::tools::fail("skinbus-identify", h.error().to_string(), kExitFailed);
    }
    held_out = std::move(h).value();
    if (const std::string note = sim::leave_out_stuck_channels(&*held_out); !note.empty()) {
      std::fprintf(stderr, "skinbus-identify: %s: %s\n", held_out_path.c_str(), note.c_str());
    }
    leave_out_deeper(&*held_out, held_out_path);
    // One tip for both: held-out presses made with another indenter would be judged wrongly.
    Result<std::optional<double>> held_tip = sim::recorded_tip_radius_mm(*held_out);
    if (!held_tip.ok()) {
      return skinbus::tools::fail("skinbus-identify",
                                  held_out_path + ": " + held_tip.error().message, kExitFailed);
    }
    if (held_tip->has_value() && **held_tip != opt.tip_radius_mm) {
      char text[160];
      std::snprintf(text, sizeof text,
                    ": pressed with a %g mm tip, the fit with %g mm: give presses of one "
                    "indenter (or --tip-radius)",
                    **held_tip, opt.tip_radius_mm);
      return skinbus::tools::fail("skinbus-identify", held_out_path + text, kExitUsage);
    }
  }
  // A recording of another layout or order than the design's fits nothing: say so first.
  if (Result<sim::PatchModel> nominal = sim::PatchModel::nominal(design); nominal.ok()) {
    Status layout = sim::check_sensor_layout(*presses, *nominal);
    std::string path = presses_path;
    if (layout.ok() && held_out) {
      layout = sim::check_sensor_layout(*held_out, *nominal);
      path = held_out_path;
    }
    if (!layout.ok()) {
      return skinbus::tools::fail("skinbus-identify", path + ": " + layout.error().message,
                                  kExitUsage);
    }
  }
  std::fprintf(stderr, "skinbus-identify: fitting %zu samples of %s (seconds to a minute) ...\n",
               presses->rows(), presses_path.c_str());
  const auto t0 = std::chrono::steady_clock::now();
  sim::UnitParameters refused;
  Result<estimators::IdentifiedUnit> id =
      estimators::identify_unit(design, *presses, opt, held_out ? &*held_out : nullptr, &refused);
  // The class leaves physics in the unit (the fit's residual, or the fit was refused for it).
  const bool outside =
      id.ok() ? (held_out ? id->held_out.rms : id->fit.rms) > estimators::kModelMissesResidual
              : !refused.magnets.empty();
  // What the fit leaves, learned from the same presses (--field-correction), at the bends the
  // unit's creep gives when it has one; its check and how long it took. On a unit the class
  // leaves physics in, the creep is chosen with it (estimators::fit_creep_and_correction: the
  // creep fitted on the class alone may hold some of that physics).
  struct Learned {
    std::shared_ptr<const sim::FieldCorrection> fc;
    estimators::FieldCorrectionReport report;
    std::optional<estimators::CreepLaw> law;  // the creep chosen with it
    std::string creep_text;
    double seconds = 0;
  };
  auto fit_correction = [&](const sim::UnitParameters& unit) {
    Learned out;
    estimators::FieldCorrectionOptions fo;
    fo.noise = opt.noise;
    fo.min_depth_mm = opt.min_depth_mm;
    fo.depth_bin_edges_mm = opt.depth_bin_edges_mm;
    std::fprintf(stderr, "skinbus-identify: learning the field correction%s (seconds) ...\n",
                 outside ? ", and the creep with it" : "");
    const auto t_fit = std::chrono::steady_clock::now();
    Result<estimators::CreepAndCorrection> both = estimators::fit_creep_and_correction(
        design, unit, *presses, opt.tip_radius_mm, fo, estimators::creep_fit_options(opt), outside);
    out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_fit).count();
    if (!both.ok()) {
      std::printf("field correction not learned: %s\n", both.error().message.c_str());
      return out;
    }
    out.fc = both->correction;
    out.report = std::move(both->report);
    if (outside) {
      out.law = both->law;
      out.creep_text = both->summary_text();
    }
    return out;
  };
  std::optional<Learned> chosen;  // the kept fit's, when the depth zero's comparison learned it
  // A unit the class leaves physics in, its depth zero fitted off the surface: a crushing top or
  // another law near the surface can pass for an indenter's zero, and the field correction may
  // take it up the better. Both fits are corrected; the lower residual at held-out places wins.
  const double zero_mm = id.ok() ? id->parameters.depth_zero_mm : refused.depth_zero_mm;
  if (field_correction && outside && std::fabs(zero_mm) > 0.05) {
    Learned fitted = fit_correction(id.ok() ? id->parameters : refused), held;
    const bool fitted_ok = (fitted.fc != nullptr);
    std::fprintf(stderr,
                 "skinbus-identify: the class leaves physics and the depth zero is %+.2f mm: "
                 "fitting again with it held at the surface, to compare the two corrected\n",
                 zero_mm);
    estimators::IdentificationOptions held_opt = opt;
    held_opt.global_priors.depth_zero_sd_mm = 0;
    held_opt.start_from_spread(design, (id.ok() ? id->parameters : refused).spread_mm);
    sim::UnitParameters held_refused;
    Result<estimators::IdentifiedUnit> held_id = estimators::identify_unit(
        design, *presses, held_opt, held_out ? &*held_out : nullptr, &held_refused);
    if (held_id.ok() || !held_refused.magnets.empty())
      held = fit_correction(held_id.ok() ? held_id->parameters : held_refused);
    const bool held_ok = (held.fc != nullptr);
    const bool take_held =
        held_ok && (!fitted_ok || held.report.rms_held_out < fitted.report.rms_held_out);
    std::printf(
        "depth zero: corrected residual at held-out places %.3f with it fitted (%+.2f mm), %.3f "
        "with it held at the surface: %s\n",
        fitted_ok ? fitted.report.rms_held_out : NAN, zero_mm,
        held_ok ? held.report.rms_held_out : NAN,
        take_held ? "held (the class's misfit near the surface, not the indenter's zero)"
                  : "fitted");
    if (take_held) {
      id = std::move(held_id);
      refused = std::move(held_refused);
    }
    chosen = take_held ? std::move(held) : std::move(fitted);
  }
  // `unit` with its correction when it helps (the comparison's, for the fit it kept).
  auto learn = [&](const sim::UnitParameters& unit) -> std::optional<sim::UnitParameters> {
    Learned l = chosen ? std::move(*chosen) : fit_correction(unit);
    chosen.reset();
    if (!l.fc) return std::nullopt;
    if (!l.creep_text.empty()) std::printf("%s\n", l.creep_text.c_str());
    // A lag chosen on ramps alone, on a unit the class leaves physics in: a crushing top bends a
    // ramp as a slower lag does, and ramps fit several laws alike (estimators::held_presses).
    if (l.law && !l.law->none() && estimators::held_presses(*presses) == 0) {
      std::printf(
          "note: the lag (%.2f s) was chosen on ramps alone, on a unit with physics the class "
          "lacks: a top that crushes bends a ramp as a slower lag does, and the ramps cannot "
          "tell them apart, so a press held still may read too deep or too shallow. Record the "
          "presses held 3 s at their deepest (skinbus-dataset --hold 3; "
          "docs/guides/training.md)\n",
          l.law->time_s);
    }
    std::printf("%s\nfield correction learned and checked in %.1f s\n",
                l.report.summary_text().c_str(), l.seconds);
    if (!l.report.helps || l.report.rms_held_out > opt.max_residual) return std::nullopt;
    sim::UnitParameters corrected = unit;
    corrected.field_correction = std::move(l.fc);
    if (l.law) l.law->write_to(&corrected);
    return corrected;
  };
  if (!id.ok()) std::fprintf(stderr, "skinbus-identify: %s\n", id.error().to_string().c_str());
  std::optional<sim::UnitParameters> rescued;
  if (!id.ok() && field_correction && !refused.magnets.empty()) {
    rescued = learn(refused);
    if (rescued) {
      std::printf(
          "the refused fit is kept with the field correction: its residual at held-out places "
          "is within %.1f noise units\n",
          opt.max_residual);
    }
  }
  if (!id.ok() && !rescued) {
    if (!refused_path.empty() && !refused.magnets.empty()) {
      const sim::UnitFileNote note{"skinbus-identify " + presses_path +
                                       std::string(sim::kRefusedInSource) + id.error().message,
                                   id.error().message, sim::pressed_area(*presses)};
      if (Status st = sim::write_unit_parameters(refused, refused_path, note); !st.ok()) {
        return skinbus::tools::fail("skinbus-identify", st.error().to_string(), kExitFailed);
      }
      std::fprintf(stderr, "skinbus-identify: wrote the refused fit to %s\n", refused_path.c_str());
    }
    return id.error().code == ErrorCode::kInvalidArgument ? kExitUsage : kExitFailed;
  }
  sim::UnitParameters unit;
  std::string source = "skinbus-identify " + presses_path + ": ";
  if (rescued) {
    unit = *rescued;
    source +=
        "the class alone refused (" + id.error().message + "); kept with the field correction";
  } else {
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("identified from %d presses (%d samples) in %.1f s, %d iterations\n", id->presses,
                id->rows_used, seconds, id->iterations);
    if (opt.fit_globals) {
      const estimators::GlobalPhysics& g = id->globals;
      std::printf(
          "globals: spread %.2f mm (design %.2f), anisotropy %.3f (design %.3f: along u %.2f mm, "
          "along v %.2f mm), lateral %.2f mm (design %.2f), magnet heights %+.2f mm, sensor "
          "heights %+.2f mm, moments x%.3f, the presses' frame (%+.2f, %+.2f) mm and %+.2f deg "
          "from the design's, their depth zero %+.3f mm; residual %.3f noise units with these "
          "alone (%d starts)\n",
          g.spread_mm, design.spread_mm, g.anisotropy, design.anisotropy,
          g.spread_mm * (1 + g.anisotropy), g.spread_mm * (1 - g.anisotropy), g.lateral_mm,
          design.lateral_mm, g.magnet_height_offset_mm, g.sensor_height_offset_mm, g.moment_scale,
          g.frame_du_mm, g.frame_dv_mm, g.frame_yaw_deg, g.depth_zero_mm, g.rms, g.starts);
      if (std::hypot(g.frame_du_mm, g.frame_dv_mm) > 0.5 || std::fabs(g.frame_yaw_deg) > 0.5) {
        std::printf(
            "the presses were made in a frame off the design's (the indenter's origin or axes "
            "off the patch's): the unit file's parts, and the contacts refined on it, are in the "
            "presses' frame; a patch pose calibrated from touches (skinbus-calibrate) takes the "
            "difference up\n");
      }
      if (std::fabs(g.depth_zero_mm) > 0.05) {
        std::printf(
            "the presses read %+.2f mm where the tip met the surface (the indenter's zero off "
            "the surface): the unit, and the contacts refined on it, read depth as they did "
            "(depth_zero_mm in the unit file)\n",
            g.depth_zero_mm);
      }
    }
    if (id->creep.presses > 0) std::printf("%s\n", id->creep.summary_text().c_str());
    if (!id->chip_turns.empty()) {
      // One line for all: the design file is the likelier culprit than the unit.
      std::string turns;
      for (const estimators::ChipTurn& t : id->chip_turns) {
        char buf[64];
        std::snprintf(buf, sizeof buf, "%s%d (%g deg%s)", turns.empty() ? "" : ", ", t.sensor,
                      t.yaw_deg, t.upside_down ? ", upside down" : "");
        turns += buf;
      }
      std::printf(
          "chips turned from the design file, fitted so: sensors %s; check the design file's "
          "sensor yaw_deg (docs/design_file.md)\n",
          turns.c_str());
    }
    if (!id->uncovered_magnets.empty()) {
      std::string list;
      for (int m : id->uncovered_magnets) {
        const sim::MagnetParameters& mp = id->parameters.magnets[static_cast<std::size_t>(m)];
        char buf[64];
        std::snprintf(buf, sizeof buf, "%s%d (%.1f, %.1f mm)", list.empty() ? "" : ", ", m, mp.u_mm,
                      mp.v_mm);
        list += buf;
      }
      std::printf(
          "magnets too few presses reach (fewer than %d within %g mm), held at the design with "
          "the globals found: %s; contacts near them rest on the design file, not on this unit: "
          "press there too for a full fit\n",
          opt.min_presses_per_magnet, opt.coverage_radius_mm, list.c_str());
    }
    if (id->masked_values > 0) {
      std::printf("%d field value(s) not finite (dead channels): left out of the fit\n",
                  id->masked_values);
    }
    print_quality("fit", id->nominal_fit, id->fit);
    if (held_out) print_quality("held out", id->nominal_held_out, id->held_out);
    // The chips' noise as the ramps show it: a residual above the design's noise can be chips
    // noisier than their settings say rather than physics the model lacks.
    const estimators::ChannelNoise chip = estimators::ChannelNoise::of(design);
    const estimators::RecordedNoise recorded = estimators::recorded_noise(*presses);
    double noise_alone = 1;  // the residual the recorded noise alone leaves, design noise units
    if (recorded.windows > 0) {
      noise_alone = std::fmax(1.0, recorded.residual(chip));
      std::printf(
          "noise along the ramps (%lld sixth differences of consecutive samples): %.3f uT (x, "
          "y), %.3f uT (z), %.2fx and %.2fx the design's chips (%.2f, %.2f uT)\n",
          static_cast<long long>(recorded.windows), recorded.noise.xy_ut, recorded.noise.z_ut,
          recorded.xy_ratio(chip), recorded.z_ratio(chip), chip.xy_ut, chip.z_ut);
    }
    const double judged = held_out ? id->held_out.rms : id->fit.rms;
    if (judged > estimators::kModelMissesResidual * noise_alone) {
      std::printf(
          "warning: residual %.2f > %.1f noise units: this unit has physics the model does not "
          "contain; learn its field correction (--field-correction) and the learned correction "
          "on top (docs/physics_estimator.md, docs/models.md)\n",
          judged, estimators::kModelMissesResidual * noise_alone);
    } else if (judged > estimators::kModelMissesResidual) {
      std::printf(
          "note: residual %.2f noise units is %.2f in the noise the ramps show: the chips are "
          "noisier than the design file's settings say (interference, supply, other chip "
          "settings), and the model explains the unit to that noise\n",
          judged, judged / noise_alone);
    }
    char residuals[96];
    std::snprintf(residuals, sizeof residuals, "residual %.3f noise units (fit)", id->fit.rms);
    source += std::to_string(id->presses) + " presses, " + residuals;
    if (held_out) {
      std::snprintf(residuals, sizeof residuals, ", %.3f (held out)", id->held_out.rms);
      source += residuals;
    }
    unit = id->parameters;
    if (field_correction) {
      if (std::optional<sim::UnitParameters> corrected = learn(unit)) {
        unit = std::move(*corrected);
        source += "; with the field correction";
      } else {
        std::printf("the unit file has no field correction\n");
      }
    }
  }
  if (held_out && unit.field_correction != nullptr) {
    Result<sim::PatchModel> corrected = sim::PatchModel::of_unit_file(design, unit);
    if (corrected.ok()) {
      const estimators::FitQuality q = estimators::fit_quality(
          *corrected,
          estimators::bent_dataset(estimators::CreepLaw::of(corrected->design()), *held_out),
          opt.tip_radius_mm, estimators::ChannelNoise::of(design), opt.depth_bin_edges_mm);
      std::printf(
          "held out, with the field correction (%d samples): residual RMS %.3f noise units\n",
          q.rows, q.rms);
      for (const estimators::DepthBinResidual& b : q.bins) {
        if (b.rows > 0) {
          std::printf("  depth %.0f-%.0f mm  n=%-5d corrected %.3f\n", b.depth_lo_mm, b.depth_hi_mm,
                      b.rows, b.rms);
        }
      }
    }
  }
  if (Status st =
          sim::write_unit_parameters(unit, out_path, {source, {}, sim::pressed_area(*presses)});
      !st.ok()) {
    return skinbus::tools::fail("skinbus-identify", st.error().to_string(), kExitFailed);
  }
  std::fprintf(stderr, "skinbus-identify: wrote %s\n", out_path.c_str());
  return kExitOk;
}
