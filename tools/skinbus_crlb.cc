// skinbus-crlb: the Cramer-Rao lower bound of contact position and depth over a patch.
//
//   skinbus-crlb                         # table for 1, 2 and 4 mm at the sensor's noise
//   skinbus-crlb --csv crlb.csv --step 2.5
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "skinbus/mlx90393/measurement.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/mlx90393.h"
#include "tool_util.h"

namespace {

struct Stats {
  double mean = 0, median = 0, p95 = 0;
  int unidentifiable = 0;
};

Stats stats_of(std::vector<double> v, int unident) {
  Stats s;
  s.unidentifiable = unident;
  if (v.empty()) return s;
  s.mean = skinbus::tools::mean(v);
  s.median = skinbus::tools::quantile(v, 0.5);
  s.p95 = skinbus::tools::quantile(v, 0.95);
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace skinbus::sim;
  CLI::App app{
      "skinbus-crlb: the best position and depth error any unbiased estimator can reach at each\n"
      "point of a patch (Cramer-Rao lower bound from the forward model's Jacobian), for a noise\n"
      "level and press depth. Prints a Markdown table; --csv writes the map for plotting\n"
      "(tools/plot_crlb.py).\n\n"
      "Examples:\n"
      "  skinbus-crlb\n"
      "  skinbus-crlb --depths 1,2,4 --csv crlb.csv && tools/plot_crlb.py crlb.csv crlb.png\n"};
  std::vector<double> depths = {1, 2, 4};
  double step = 2.5, extent = 67.5, noise_xy = -1, noise_z = -1;
  bool ambient = false;
  double tip_radius = 5.0;
  std::string csv;
  app.add_option("--depths", depths, "press depths, mm")->delimiter(',')->capture_default_str();
  app.add_option("--step", step, "map grid step, mm")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 50.0));
  app.add_option("--extent", extent, "map covers +-extent mm (67.5: the seed's press grid)")
      ->capture_default_str();
  app.add_option("--noise-xy", noise_xy,
                 "noise RMS of x/y channels, uT (default: the sensor model's)");
  app.add_option("--noise-z", noise_z, "noise RMS of z channels, uT (default: the sensor model's)");
  app.add_option("--tip-radius", tip_radius, "round indenter tip radius, mm (0: a point)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 50.0));
  app.add_flag("--ambient", ambient,
               "also estimate a uniform ambient field (3 nuisance parameters)");
  app.add_option("--csv", csv, "write every map point to this CSV file");
  std::string design_path;
  app.add_option("--design", design_path,
                 "patch design file (docs/design_file.md; default: the built-in design, "
                 "sim/designs/nominal.yaml)")
      ->check(CLI::ExistingFile);
  CLI11_PARSE(app, argc, argv);

  const skinbus::Result<PatchDesign> design = read_design_or_builtin(design_path);
  if (!design.ok()) return skinbus::tools::fail("skinbus-crlb", design.error().to_string(), 2);
  auto model = PatchModel::nominal(design.value());
  if (!model.ok()) {
    return skinbus::tools::fail("skinbus-crlb", model.error().message, 1);
  }
  const skinbus::mlx90393::Config& cfg = model->design().sensor_config;
  if (noise_xy <= 0) noise_xy = mlx90393_noise_xy_ut(cfg);
  if (noise_z <= 0) noise_z = mlx90393_noise_z_ut(cfg);
  // The CSV is built in memory and written whole at the end (a temporary file, renamed).
  std::string out;
  const bool want_csv = !csv.empty();
  if (want_csv) {
    skinbus::tools::appendf(out, "# tip_radius_mm: %.3f\n", tip_radius);
    skinbus::tools::appendf(out,
                            "# noise_xy_ut: %.4f\n# noise_z_ut: %.4f\n# ambient_nuisance: %d\n",
                            noise_xy, noise_z, ambient);
    out += "depth_mm,u_mm,v_mm,sd_u_mm,sd_v_mm,sd_xy_mm,sd_depth_mm,identifiable\n";
  }
  std::printf(
      "Cramer-Rao bound, nominal flat patch, noise %.2f uT (x, y) / %.2f uT (z)%s, tip radius %.1f "
      "mm, "
      "over +-%.1f mm (step %.1f mm)\n\n",
      noise_xy, noise_z, ambient ? ", ambient field estimated too" : "", tip_radius, extent, step);
  std::printf(
      "| depth (mm) | XY mean (mm) | XY median | XY p95 | depth mean (mm) | depth median | depth "
      "p95 | points without information |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  for (double depth : depths) {
    std::vector<double> xy, dd;
    int unident = 0;
    const int n = static_cast<int>(std::floor(2 * extent / step + 1e-9)) + 1;
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const double u = -extent + i * step, v = -extent + j * step;
        const CrlbPoint p =
            crlb_at(*model, Contact{u, v, depth, tip_radius}, noise_xy, noise_z, ambient);
        if (p.identifiable) {
          xy.push_back(p.sd_xy_mm);
          dd.push_back(p.sd_depth_mm);
        } else {
          ++unident;
        }
        if (want_csv) {
          skinbus::tools::appendf(out, "%g,%g,%g,%.6g,%.6g,%.6g,%.6g,%d\n", depth, u, v, p.sd_u_mm,
                                  p.sd_v_mm, p.sd_xy_mm, p.sd_depth_mm, p.identifiable);
        }
      }
    }
    const Stats a = stats_of(xy, unident), b = stats_of(dd, unident);
    std::printf("| %.1f | %.3f | %.3f | %.3f | %.4f | %.4f | %.4f | %d |\n", depth, a.mean,
                a.median, a.p95, b.mean, b.median, b.p95, unident);
  }
  if (want_csv) {
    try {
      skinbus::tools::write_output(csv, out, "CRLB table");
    } catch (const std::exception& e) {
      return skinbus::tools::fail("skinbus-crlb", e.what(), 1);
    }
  }
  return 0;
}
