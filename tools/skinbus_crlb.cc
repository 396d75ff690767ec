// skinbus-crlb: the Cramer-Rao lower bound of contact position and depth over a patch.
//
//   skinbus-crlb                         # table for 1, 2 and 4 mm at the sensor's noise
//   skinbus-crlb --csv crlb.csv --step 2.5
//   skinbus-crlb --pair --csv pair.csv     # two contacts: the bound against their separation
//   skinbus-crlb --shear --csv shear.csv   # a shear force: its bound and what it costs the
//   position
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "skinbus/mlx90393/measurement.h"
#include "skinbus/sim/crlb.h"
#include "skinbus/sim/dataset.h"
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

// --pair: prints the table, returns the CSV.
std::string pair_report(const skinbus::sim::PatchModel& model, const std::vector<double>& depths,
                        const std::vector<double>& separations, double tip_radius, double noise_xy,
                        double noise_z, bool ambient) {
  using namespace skinbus::sim;
  std::string out;
  skinbus::tools::appendf(out, "# noise_xy_ut: %.4f\n# noise_z_ut: %.4f\n# ambient_nuisance: %d\n",
                          noise_xy, noise_z, ambient);
  out +=
      "separation_mm,depth_mm,mid_u_mm,mid_v_mm,along,sd_xy_first_mm,sd_xy_second_mm,"
      "sd_depth_first_mm,sd_depth_second_mm,alone_xy_first_mm,alone_xy_second_mm,identifiable,"
      "non_additive\n";
  std::printf(
      "Cramer-Rao bound of two simultaneous contacts, nominal patch, noise %.2f / %.2f uT%s, "
      "tip %.1f mm: mean per contact over midpoints within +-30 mm, pairs along u and v\n\n",
      noise_xy, noise_z, ambient ? ", ambient estimated" : "", tip_radius);
  std::printf(
      "| separation (mm) | depth (mm) | XY bound (mm) | alone (mm) | x alone | depth bound (mm) | "
      "pairs not told apart | non-additive (noise units) |\n"
      "|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (double sep : separations) {
    for (double depth : depths) {
      std::vector<double> xy, alone, dd, nonadd;
      int total = 0, lost = 0;
      const int nc = model.channel_count();
      std::vector<double> fab(nc), fa(nc), fb(nc);
      for (double mu = -30; mu <= 30; mu += 10) {
        for (double mv = -30; mv <= 30; mv += 10) {
          for (int along = 0; along < 2; ++along) {
            const double du = along == 0 ? sep / 2 : 0, dv = along == 0 ? 0 : sep / 2;
            const Contact a{mu - du, mv - dv, depth, tip_radius};
            const Contact b{mu + du, mv + dv, depth, tip_radius};
            const CrlbPair p = crlb_pair_at(model, a, b, noise_xy, noise_z, ambient);
            const CrlbPoint one = crlb_at(model, a, noise_xy, noise_z, ambient);
            const CrlbPoint two = crlb_at(model, b, noise_xy, noise_z, ambient);
            // How far the pair's field is from the sum of each press's alone (RMS over the
            // channels, in noise units): the model's response is not additive where the presses
            // move the same magnets (the dipole field is not linear in their displacement).
            const Contact ab[2] = {a, b};
            model.contact_field_ut(std::span<const Contact>(ab, 2), fab);
            model.contact_field_ut(std::span<const Contact>(&a, 1), fa);
            model.contact_field_ut(std::span<const Contact>(&b, 1), fb);
            double na = 0;
            for (int i = 0; i < nc; ++i) {
              const double d = (fab[i] - fa[i] - fb[i]) / (i % 3 == 2 ? noise_z : noise_xy);
              na += d * d;
            }
            na = std::sqrt(na / nc);
            nonadd.push_back(na);
            ++total;
            const bool ok = p.first.identifiable && one.identifiable && two.identifiable;
            if (ok) {
              xy.insert(xy.end(), {p.first.sd_xy_mm, p.second.sd_xy_mm});
              alone.insert(alone.end(), {one.sd_xy_mm, two.sd_xy_mm});
              dd.insert(dd.end(), {p.first.sd_depth_mm, p.second.sd_depth_mm});
            } else {
              ++lost;
            }
            skinbus::tools::appendf(out, "%g,%g,%g,%g,%c,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%d,%.6g\n",
                                    sep, depth, mu, mv, along == 0 ? 'u' : 'v', p.first.sd_xy_mm,
                                    p.second.sd_xy_mm, p.first.sd_depth_mm, p.second.sd_depth_mm,
                                    one.sd_xy_mm, two.sd_xy_mm, ok, na);
          }
        }
      }
      const double m_xy = xy.empty() ? 0 : skinbus::tools::mean(xy);
      const double m_alone = alone.empty() ? 0 : skinbus::tools::mean(alone);
      std::printf("| %.0f | %.1f | %.3f | %.3f | %.2f | %.4f | %d of %d | %.2f |\n", sep, depth,
                  m_xy, m_alone, m_alone > 0 ? m_xy / m_alone : 0.0,
                  dd.empty() ? 0 : skinbus::tools::mean(dd), lost, total,
                  nonadd.empty() ? 0 : skinbus::tools::mean(nonadd));
    }
  }
  return out;
}

// The map's points: `step` apart from the area's low corner, as many as fit in it.
struct MapGrid {
  MapGrid(const skinbus::sim::PressedArea& a, double step_mm)
      : area(a),
        step(step_mm),
        nu(static_cast<int>(std::floor((a.u_max_mm - a.u_min_mm) / step_mm + 1e-9)) + 1),
        nv(static_cast<int>(std::floor((a.v_max_mm - a.v_min_mm) / step_mm + 1e-9)) + 1) {}
  skinbus::sim::PressedArea area;
  double step;
  int nu, nv;
  double u(int i) const { return area.u_min_mm + i * step; }
  double v(int j) const { return area.v_min_mm + j * step; }
  std::string text() const {  // "+-67.5 mm (step 2.5 mm)" or "u -80 .. 80, v -20 .. 20 mm (...)"
    char t[128];
    if (area == skinbus::sim::PressedArea::square(area.u_max_mm)) {
      std::snprintf(t, sizeof t, "+-%.1f mm (step %.1f mm)", area.u_max_mm, step);
    } else {
      std::snprintf(t, sizeof t, "u %.1f .. %.1f, v %.1f .. %.1f mm (step %.1f mm)", area.u_min_mm,
                    area.u_max_mm, area.v_min_mm, area.v_max_mm, step);
    }
    return t;
  }
};

// --shear: prints the table, returns the CSV.
std::string shear_report(const skinbus::sim::PatchModel& model, const std::vector<double>& depths,
                         const MapGrid& map, double tip_radius, double noise_xy, double noise_z,
                         bool ambient) {
  using namespace skinbus::sim;
  std::string out;
  skinbus::tools::appendf(out,
                          "# tip_radius_mm: %.3f\n# noise_xy_ut: %.4f\n# noise_z_ut: %.4f\n"
                          "# ambient_nuisance: %d\n",
                          tip_radius, noise_xy, noise_z, ambient);
  out +=
      "depth_mm,u_mm,v_mm,sd_shear_u_n,sd_shear_v_n,sd_shear_n,sd_xy_mm,sd_xy_known_shear_mm,"
      "sd_depth_mm,identifiable\n";
  std::printf(
      "Cramer-Rao bound of a contact's shear force (u, v, depth, F_u, F_v unknown), %s design, "
      "noise %.2f / %.2f uT%s, tip %.1f mm, shear stiffness %.2f N/mm, spread %.1f mm, over "
      "%s\n\n",
      model.design().magnet_list.empty() ? "grid" : "listed", noise_xy, noise_z,
      ambient ? ", ambient estimated" : "", tip_radius, model.design().shear_stiffness_n_per_mm,
      model.design().shear_spread_mm, map.text().c_str());
  std::printf(
      "| depth (mm) | normal force (N) | shear bound mean (N) | median | p95 | mean / normal "
      "force | XY bound, shear unknown (mm) | shear known (mm) | x known | points without "
      "information |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  for (double depth : depths) {
    std::vector<double> sh, xy, known;
    int unident = 0;
    for (int j = 0; j < map.nv; ++j) {
      for (int i = 0; i < map.nu; ++i) {
        const double u = map.u(i), v = map.v(j);
        const Contact c{u, v, depth, tip_radius};
        const CrlbShear p = crlb_shear_at(model, c, noise_xy, noise_z, ambient);
        const CrlbPoint k = crlb_at(model, c, noise_xy, noise_z, ambient);
        const bool ok = p.identifiable && k.identifiable;
        if (ok) {
          sh.push_back(p.sd_shear_n);
          xy.push_back(p.contact.sd_xy_mm);
          known.push_back(k.sd_xy_mm);
        } else {
          ++unident;
        }
        skinbus::tools::appendf(out, "%g,%g,%g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%d\n", depth, u, v,
                                p.sd_shear_u_n, p.sd_shear_v_n, p.sd_shear_n, p.contact.sd_xy_mm,
                                k.sd_xy_mm, p.contact.sd_depth_mm, ok);
      }
    }
    const Stats a = stats_of(sh, unident);
    const double m_xy = xy.empty() ? 0 : skinbus::tools::mean(xy);
    const double m_known = known.empty() ? 0 : skinbus::tools::mean(known);
    const double fn = model.force_n(depth);
    std::printf("| %.1f | %.2f | %.4f | %.4f | %.4f | %.3f | %.3f | %.3f | %.2f | %d |\n", depth,
                fn, a.mean, a.median, a.p95, fn > 0 ? a.mean / fn : 0.0, m_xy, m_known,
                m_known > 0 ? m_xy / m_known : 0.0, unident);
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace skinbus::sim;
  CLI::App app{
      "skinbus-crlb: the best position and depth error any unbiased estimator can reach at each\n"
      "point of a patch (Cramer-Rao lower bound from the forward model's Jacobian), for a noise\n"
      "level and press depth. Prints a Markdown table; --csv writes the map for plotting\n"
      "(tools/plot_crlb.py).\n\n"
      "--pair: the bound for two simultaneous contacts of the same depth, against their\n"
      "separation: each pair's midpoint on a grid within +-30 mm of the centre (10 mm step), the\n"
      "pair along u and along v; the table gives the mean bound per contact, its ratio to the\n"
      "bound of the same contact pressed alone, and the pairs the field cannot tell apart\n"
      "(tools/plot_crlb_pair.py plots the CSV).\n\n"
      "--shear: the bound on a tangential (shear) force at the contact, its (u, v, depth) and the\n"
      "force's two components all unknown, over the map's grid; the table gives the force's bound\n"
      "(N, and as a fraction of the normal force at that depth: the friction coefficient one can\n"
      "tell) and what not knowing the shear costs the position (the design file's\n"
      "lattice.shear_stiffness_n_per_mm and shear_spread_mm set the physics).\n\n"
      "Examples:\n"
      "  skinbus-crlb\n"
      "  skinbus-crlb --depths 1,2,4 --csv crlb.csv && tools/plot_crlb.py crlb.csv crlb.png\n"
      "  skinbus-crlb --pair --csv pair.csv && tools/plot_crlb_pair.py pair.csv pair.png\n"
      "  skinbus-crlb --shear --depths 1,2,3,4 --step 5\n"};
  std::vector<double> depths = {1, 2, 4};
  double step = 2.5, extent = 67.5, noise_xy = -1, noise_z = -1;
  bool ambient = false, pair = false, shear = false;
  std::vector<double> separations = {10, 15, 20, 30, 40, 50, 60, 80};
  double tip_radius = 5.0;
  std::string csv;
  app.add_option("--depths", depths, "press depths, mm")->delimiter(',')->capture_default_str();
  app.add_option("--step", step, "map grid step, mm")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 50.0));
  CLI::Option* extent_given =
      app.add_option("--extent", extent, "map covers +-extent mm (67.5: the seed's press grid)")
          ->capture_default_str();
  std::string area_text;
  app.add_option("--area", area_text,
                 "the map covers this rectangle instead of the +-extent square: 'U0,U1,V0,V1' "
                 "(mm) or 'surface' (the design's whole surface: a patch that is not square, or "
                 "larger than the seed's grid)")
      ->excludes(extent_given);
  app.add_option("--noise-xy", noise_xy,
                 "noise RMS of x/y channels, uT (default: the sensor model's)");
  app.add_option("--noise-z", noise_z, "noise RMS of z channels, uT (default: the sensor model's)");
  CLI::Option* tip_given =
      app.add_option("--tip-radius", tip_radius,
                     "round indenter tip radius, mm (0: a point; default: the design's indenter, "
                     "5 mm on the built-in design)")
          ->check(CLI::Range(0.0, skinbus::sim::kMaxIndenterTipRadiusMm));
  app.add_flag("--ambient", ambient,
               "also estimate a uniform ambient field (3 nuisance parameters)");
  app.add_option("--csv", csv, "write every map point (every pair with --pair) to this CSV file");
  app.add_flag("--pair", pair, "two contacts: the bound against their separation (see above)");
  app.add_flag("--shear", shear, "a shear force's bound and its cost to the position (see above)")
      ->excludes("--pair");
  app.add_option("--separations", separations, "--pair: separations, mm")
      ->delimiter(',')
      ->capture_default_str();
  std::string design_path;
  app.add_option("--design", design_path,
                 "patch design file (docs/design_file.md; default: the built-in design, "
                 "sim/designs/nominal.yaml)")
      ->check(CLI::ExistingFile);
  CLI11_PARSE(app, argc, argv);

  const skinbus::Result<PatchDesign> design = read_design_or_builtin(design_path);
  if (!design.ok()) return skinbus::tools::fail("skinbus-crlb", design.error().to_string(), 2);
  if (tip_given->count() == 0) tip_radius = design->indenter_tip_radius_mm;
  const skinbus::Result<skinbus::sim::PressedArea> area =
      area_text.empty() ? skinbus::sim::PressedArea::square(extent)
                        : skinbus::sim::parse_press_area(area_text, design.value());
  if (!area.ok()) return skinbus::tools::fail("skinbus-crlb", area.error().message, 2);
  const MapGrid map{*area, step};
  if (map.nu > 2000 || map.nv > 2000) {
    return skinbus::tools::fail("skinbus-crlb", "the map's area at --step is too many points", 2);
  }
  auto model = PatchModel::nominal(design.value());
  if (!model.ok()) {
    return skinbus::tools::fail("skinbus-crlb", model.error().message, 1);
  }
  const skinbus::mlx90393::Config& cfg = model->design().sensor_config;
  if (noise_xy <= 0) noise_xy = mlx90393_noise_xy_ut(cfg);
  if (noise_z <= 0) noise_z = mlx90393_noise_z_ut(cfg);
  if (pair || shear) {
    const std::string out =
        pair ? pair_report(*model, depths, separations, tip_radius, noise_xy, noise_z, ambient)
             : shear_report(*model, depths, map, tip_radius, noise_xy, noise_z, ambient);
    if (!csv.empty()) {
      try {
        skinbus::tools::write_output(csv, out, pair ? "CRLB pair table" : "CRLB shear table");
      } catch (const std::exception& e) {
        return skinbus::tools::fail("skinbus-crlb", e.what(), 1);
      }
    }
    return 0;
  }
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
      "mm, over %s\n\n",
      noise_xy, noise_z, ambient ? ", ambient field estimated too" : "", tip_radius,
      map.text().c_str());
  std::printf(
      "| depth (mm) | XY mean (mm) | XY median | XY p95 | depth mean (mm) | depth median | depth "
      "p95 | points without information |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  std::vector<double> deeper;  // depths beyond the lattice's
  for (double depth : depths) {
    std::vector<double> xy, dd;
    int unident = 0;
    for (int j = 0; j < map.nv; ++j) {
      for (int i = 0; i < map.nu; ++i) {
        const double u = map.u(i), v = map.v(j);
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
    if (xy.empty()) {  // no point bounded: no figure, rather than a bound of 0
      std::printf("| %.1f | - | - | - | - | - | - | %d |\n", depth, unident);
    } else {
      std::printf("| %.1f | %.3f | %.3f | %.3f | %.4f | %.4f | %.4f | %d |\n", depth, a.mean,
                  a.median, a.p95, b.mean, b.median, b.p95, unident);
    }
    if (depth > model->max_depth_mm()) deeper.push_back(depth);
  }
  if (!deeper.empty()) {
    std::string deeper_text;
    for (double d : deeper)
      deeper_text += (deeper_text.empty() ? "" : ", ") + skinbus::tools::format_g(d);
    std::printf(
        "\n%s mm: deeper than the %g mm lattice compresses (%.2f mm, 0.6 x thickness_mm). The "
        "model holds such presses there, so their field tells nothing of their depth.\n",
        deeper_text.c_str(), model->design().thickness_mm, model->max_depth_mm());
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
