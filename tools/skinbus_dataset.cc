// skinbus-dataset: generate an indentation dataset from the patch simulator.
//
//   skinbus-dataset --plan grid -o train.csv                 # the seed's 19 x 19 protocol
//   skinbus-dataset --plan random-test --count 2000 -o test.csv
//   skinbus-dataset --plan halton --count 361 --uid 0x5B01 --fabricated -o unit1.csv
#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "skinbus/bus/protocol.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/unit_model.h"
#include "tool_util.h"

namespace {

// What the patch's node sends: a sensor whose tared field leaves the bus's range is flagged
// saturated (docs/protocol.md) and the host fits without it, so its channels are written as nan,
// as the host reads them. Returns a note for the user ("" when none left the range).
std::string leave_out_beyond_bus(skinbus::sim::Dataset* d) {
  const std::size_t nc = static_cast<std::size_t>(d->channels());
  std::size_t hit = 0;
  double peak_ut = 0;
  int peak_channel = 0;
  for (std::size_t r = 0; r < d->rows(); ++r) {
    bool any = false;
    for (std::size_t s0 = 0; s0 < nc; s0 += 3) {
      bool sensor = false;
      for (std::size_t c = s0; c < s0 + 3; ++c) {
        const double v = d->field_ut[r * nc + c];
        bool clipped = false;
        skinbus::bus::field_ut_to_lsb(v, &clipped);
        if (!clipped || !std::isfinite(v)) continue;
        sensor = true;
        if (std::fabs(v) > peak_ut) {
          peak_ut = std::fabs(v);
          peak_channel = static_cast<int>(c);
        }
      }
      if (!sensor) continue;
      any = true;
      for (std::size_t c = s0; c < s0 + 3; ++c) d->field_ut[r * nc + c] = std::nan("");
    }
    hit += any ? 1 : 0;
  }
  if (hit == 0) return "";
  char text[400];
  std::snprintf(text, sizeof text,
                "%zu of %zu samples read a sensor beyond the bus's +-%.1f uT (%s to %.0f uT): "
                "written as nan, as its patch node flags it saturated and the host fits without "
                "it; weaker magnets, or magnets further from the sensors, keep presses within the "
                "range",
                hit, d->rows(), skinbus::bus::kFieldMaxLsb * skinbus::bus::kFieldUtPerLsb,
                skinbus::sim::field_column_name(peak_channel).c_str(), peak_ut);
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace skinbus;
  using namespace skinbus::sim;
  CLI::App app{
      "skinbus-dataset: indentation datasets from the simulated patch, in the project's CSV "
      "format\n"
      "(docs/dataset_format.md).\n\n"
      "Plans (where the simulated robot presses):\n"
      "  grid         the seed's protocol: --grid N x N points at --pitch mm (19 x 19 at 7.5 mm;\n"
      "               with --area, the points at --pitch that fill that rectangle)\n"
      "  jittered     the same grid, each point moved by up to --jitter x pitch/2\n"
      "  halton       --count points of a low-discrepancy sequence over the area (--area)\n"
      "  random       --count uniformly random points over the area\n"
      "  random-test  the test split: --count static presses at random points and depths over\n"
      "               the area\n"
      "               The area: --area (a rectangle, the design's surface, or where a --unit\n"
      "               was pressed: beyond it its fit is extrapolated); else the grid's extent\n"
      "  grid-test    --count static presses at random depths at every grid point (the split\n"
      "               at the training grid's points)\n"
      "  list         the points in --points FILE (one 'u_mm,v_mm' per line)\n"
      "Ramp plans press and release each point at --speed mm/s to --max-depth, sampled at --rate,\n"
      "keeping contact samples only.\n\n"
      "Examples:\n"
      "  skinbus-dataset --plan grid -o train.csv\n"
      "  skinbus-dataset --plan random-test --count 2000 -o test.csv\n"
      "  skinbus-dataset --plan halton --count 12000 --unit unit7.json -o unit7_train.csv\n"
      "    (training data from a unit identified by skinbus-identify; the noise seed is still\n"
      "    --uid's)\n"};
  std::string plan = "grid", out_path, points_path;
  int grid = 19, count = 361;
  double pitch = 7.5, jitter = 0.5, max_depth = 4.0, speed = 2.0, rate = 41.7, hold_s = 0;
  uint64_t uid = 0x5B00000000000001ull, seed = 1;
  bool fabricated = false, cylinder = false;
  double radius = 45, anisotropy = 0;
  app.add_option("--plan", plan, "grid | jittered | halton | random | random-test | grid-test")
      ->capture_default_str();
  app.add_option("--grid", grid, "grid points per side")
      ->capture_default_str()
      ->check(CLI::Range(1, 200));
  app.add_option("--pitch", pitch, "grid pitch, mm")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 100.0));
  app.add_option("--jitter", jitter, "jittered plan: fraction of half a pitch")
      ->capture_default_str();
  app.add_option(
         "--count", count,
         "presses for halton/random, samples for random-test, presses per point for grid-test")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000000));
  app.add_option("--max-depth", max_depth, "deepest press, mm")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 9.0));
  app.add_option("--speed", speed, "ramp speed, mm/s")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 100.0));
  app.add_option("--hold", hold_s,
                 "ramp plans: hold each press this long at --max-depth before releasing, s (a "
                 "lattice that relaxes slower than a ramp lasts shows it only there; written to "
                 "the protocol header)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 600.0));
  app.add_option("--rate", rate, "sample rate, Hz")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 1000.0));
  app.add_option("--uid", uid,
                 "hardware UID of the simulated unit (seeds its fabrication variation and noise)")
      ->capture_default_str();
  app.add_flag("--fabricated", fabricated,
               "a fabricated unit (per-UID variation) instead of the nominal design");
  std::string design_path;
  app.add_option("--design", design_path,
                 "patch design file (docs/design_file.md; default: the built-in design, "
                 "sim/designs/nominal.yaml); --cylinder, --radius, --anisotropy change it")
      ->check(CLI::ExistingFile);
  double tip_radius = 0;
  CLI::Option* tip_given =
      app.add_option("--tip-radius", tip_radius,
                     "the indenter's round tip radius, mm (0: a point; default: the design's "
                     "indenter, 5 mm on the built-in design); written to the protocol header")
          ->check(CLI::Range(0.0, kMaxIndenterTipRadiusMm));
  app.add_flag("--cylinder", cylinder, "a cylinder-section patch (forearm) instead of a flat one");
  app.add_option("--radius", radius, "cylinder skin radius, mm")->capture_default_str();
  CLI::Option* anisotropy_given =
      app.add_option("--anisotropy", anisotropy,
                     "lattice anisotropy: the spread along u is l (1 + a), along v l (1 - a); "
                     "with --unit, added to the unit's own")
          ->capture_default_str();
  app.add_option("--seed", seed, "seed of random plans")->capture_default_str();
  app.add_option("--points", points_path, "list plan: file of press points");
  bool discs = false;
  app.add_flag("--disc-magnets", discs,
               "every magnet a disc of the design's size (14 dipoles over its volume) instead of "
               "a point dipole: physics outside every estimator's model class");
  std::string unit_path;
  app.add_option("--unit", unit_path,
                 "unit file (skinbus-identify): simulate that identified unit instead of the "
                 "nominal or a --fabricated one, in the model class it was identified in (the "
                 "design's anisotropy, crushing top, in-plane drag and creep are not added; the "
                 "unit file's identified anisotropy and creep are, and an --anisotropy given on "
                 "top)")
      ->check(CLI::ExistingFile);
  std::vector<double> press_frame;
  app.add_option("--press-frame", press_frame,
                 "DU,DV,YAW: record the presses as an indentation robot whose frame is off the "
                 "patch's does: each press's u_mm, v_mm turned by YAW degrees (u toward v) and "
                 "moved by (DU, DV) mm; where the unit is pressed does not change "
                 "(skinbus-identify finds such a frame)")
      ->delimiter(',')
      ->expected(3);
  std::string area_text;
  app.add_option("--area", area_text,
                 "the rectangle pressed instead of the grid's (grid - 1) x pitch square: "
                 "'U0,U1,V0,V1' (mm, patch frame), 'surface' (the design's whole surface, "
                 "centred, widened to hold where a --unit was pressed) or 'pressed' (where the "
                 "--unit was pressed: its file's pressed_area_mm; beyond it the identified model "
                 "is extrapolated). Halton, "
                 "random and random-test sample it; grid, jittered and grid-test press the "
                 "--pitch points that fill it, centred");
  double press_depth_zero_mm = 0;
  app.add_option("--press-depth-zero", press_depth_zero_mm,
                 "MM: record the presses as an indenter whose zero is off the surface does: each "
                 "press's depth_mm read MM deeper (negative: shallower) than it pressed "
                 "(skinbus-identify finds such a zero)")
      ->check(CLI::Range(-3.0, 3.0));
  app.add_option("-o,--output", out_path, "output CSV file")->required();
  CLI11_PARSE(app, argc, argv);

  const Result<PatchDesign> base_design = read_design_or_builtin(design_path);
  if (!base_design.ok())
    return skinbus::tools::report_error("skinbus-dataset", base_design.error());
  try {
    const auto t0 = std::chrono::steady_clock::now();
    PatchDesign design = base_design.value();
    if (cylinder) {
      design.surface = SurfaceKind::kCylinder;
      design.radius_mm = radius;
    }
    if (anisotropy_given->count() > 0) design.anisotropy = anisotropy;  // else the design's
    if (fabricated && !unit_path.empty()) {
      throw std::invalid_argument("--fabricated and --unit are exclusive: one unit at a time");
    }
    std::optional<PressedArea> unit_area;  // where the --unit was pressed, when its file says
    auto make_model = [&]() -> Result<PatchModel> {
      if (unit_path.empty()) {
        return fabricated ? PatchModel::fabricated(design, uid, FabricationVariation{})
                          : PatchModel::nominal(design);
      }
      // The unit file's model class with its identified creep; an --anisotropy given is put on
      // top of it.
      Result<UnitModel> unit =
          read_unit_model(unit_path, design, anisotropy_given->count() > 0 ? anisotropy : 0);
      if (!unit.ok()) return unit.error();
      unit_area = unit->note.pressed_area;
      return std::move(unit->model);
    };
    Result<PatchModel> model = make_model();
    if (model.ok() && discs) model = PatchModel::with_disc_magnets(model.value());
    if (!model.ok()) throw std::runtime_error(model.error().message);
    SimulatedPatch patch(std::move(model).value(), unit_noise_seed(uid, 1));
    // The lattice compresses no deeper than its model's stop, which holds deeper presses there:
    // they are pressed to 10 % short of it (PatchDesign::deepest_press_mm), so that no row is
    // labelled deeper than its field shows.
    const double deepest_mm =
        patch.model().design().deepest_press_mm() + patch.model().depth_zero_mm();
    if (max_depth > deepest_mm + 0.05) {  // not for an identified depth zero's hundredths
      std::fprintf(stderr,
                   "skinbus-dataset: presses to %.2f mm, not --max-depth %g: the design's %g mm "
                   "lattice stops a press at %.2f mm (0.6 x thickness_mm), and presses keep 10 %% "
                   "short of that\n",
                   deepest_mm, max_depth, design.thickness_mm, design.max_depth_mm());
    }
    max_depth = std::fmin(max_depth, deepest_mm);
    // The rectangle pressed (see --area). Grid plans fill a given one at --pitch, centred.
    const bool area_given = !area_text.empty();
    Result<PressedArea> area_read = area_given ? parse_press_area(area_text, design, unit_area)
                                               : PressedArea::square((grid - 1) / 2.0 * pitch);
    if (!area_read.ok()) throw std::invalid_argument(area_read.error().message);
    const PressedArea area = area_read.value();
    if (area_text == "surface" || area_text == "pressed") {
      std::fprintf(stderr,
                   "skinbus-dataset: pressing u %.1f .. %.1f, v %.1f .. %.1f mm (--area %s)\n",
                   area.u_min_mm, area.u_max_mm, area.v_min_mm, area.v_max_mm, area_text.c_str());
    }
    auto grid_plan = [&](std::vector<PressPoint> points) {  // the grid's points, --area's centre
      for (PressPoint& q : points) {
        q.u_mm += (area.u_min_mm + area.u_max_mm) / 2;
        q.v_mm += (area.v_min_mm + area.v_max_mm) / 2;
      }
      return points;
    };
    const bool gridded = plan == "grid" || plan == "jittered" || plan == "grid-test";
    const auto fill = [&](double lo, double hi) {  // points a side, at most --grid's 200
      const double n = area_given ? std::floor((hi - lo) / pitch + 1e-9) + 1 : grid;
      if (gridded && n > 200) {
        throw std::invalid_argument("--area at --pitch " + tools::format_g(pitch) +
                                    " mm: " + tools::format_g(n) +
                                    " points a side (at most 200): give a larger pitch");
      }
      return static_cast<int>(std::fmin(n, 200));
    };
    const int grid_u = fill(area.u_min_mm, area.u_max_mm);
    const int grid_v = fill(area.v_min_mm, area.v_max_mm);
    Dataset d;
    RampProtocol pr;
    pr.max_depth_mm = max_depth;
    pr.speed_mm_per_s = speed;
    pr.hold_s = hold_s;
    pr.rate_hz = rate;
    pr.tip_radius_mm = tip_given->count() > 0 ? tip_radius : design.indenter_tip_radius_mm;
    if (plan == "grid") {
      d = generate_ramp_dataset(patch, grid_plan(plan_grid(grid_u, grid_v, pitch)), pr);
    } else if (plan == "jittered") {
      d = generate_ramp_dataset(
          patch, grid_plan(plan_jittered_grid(grid_u, grid_v, pitch, jitter, seed)), pr);
    } else if (plan == "halton") {
      d = generate_ramp_dataset(patch, plan_halton(count, area, seed), pr);
    } else if (plan == "random") {
      d = generate_ramp_dataset(patch, plan_random(count, area, seed), pr);
    } else if (plan == "list") {
      if (points_path.empty()) throw std::invalid_argument("--plan list needs --points FILE");
      auto pts = plan_from_file(points_path);
      if (!pts.ok()) throw std::runtime_error(pts.error().message);
      d = generate_ramp_dataset(patch, *pts, pr);
    } else if (plan == "random-test") {
      d = generate_random_test_set(patch, count, area, max_depth, seed, {}, pr.tare_samples,
                                   pr.tip_radius_mm);
    } else if (plan == "grid-test") {
      d = generate_static_test_set(patch, grid_plan(plan_grid(grid_u, grid_v, pitch)), count,
                                   max_depth, seed, {}, pr.tare_samples, pr.tip_radius_mm);
    } else {
      throw std::invalid_argument("unknown --plan '" + plan + "' (see --help)");
    }
    if (const std::string note = leave_out_beyond_bus(&d); !note.empty()) {
      std::fprintf(stderr, "skinbus-dataset: %s\n", note.c_str());
    }
    if (press_frame.size() == 3 || press_depth_zero_mm != 0) {
      PressFrame f{.depth_zero_mm = press_depth_zero_mm};
      if (press_frame.size() == 3) {
        f.du_mm = press_frame[0];
        f.dv_mm = press_frame[1];
        f.yaw_deg = press_frame[2];
      }
      record_in_press_frame(&d, f);
    }
    d.meta["plan"] = plan;
    char uid_text[32];
    std::snprintf(uid_text, sizeof uid_text, "0x%016llx", static_cast<unsigned long long>(uid));
    d.meta["unit_uid"] = uid_text;
    d.meta["unit"] = std::string(!unit_path.empty() ? "identified " + unit_path
                                 : fabricated       ? "fabricated"
                                                    : "nominal") +
                     (discs ? ", disc magnets" : "");
    const auto t1 = std::chrono::steady_clock::now();
    auto s = write_dataset_csv(d, out_path);
    if (!s.ok()) throw std::runtime_error(s.error().message);
    const auto t2 = std::chrono::steady_clock::now();
    std::fprintf(
        stderr, "skinbus-dataset: %zu rows x %d channels to %s (generate %.2f s, write %.2f s)\n",
        d.rows(), d.channels(), out_path.c_str(), std::chrono::duration<double>(t1 - t0).count(),
        std::chrono::duration<double>(t2 - t1).count());
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-dataset", e.what(), 1);
  }
  return 0;
}
