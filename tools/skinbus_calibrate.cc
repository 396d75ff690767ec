// skinbus-calibrate: patch poses on the robot from a calibration touch log.
//
//   skinbus-calibrate --map skin.yaml --touches touches.csv --out calibrated.yaml
//       --report report.md --plot residuals.png
#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <string>

#include "skinbus/body_map/calibration.h"
#include "skinbus/body_map/touch_log.h"
#include "skinbus/common/atomic_file.h"
#include "skinbus/common/plot_script.h"
#include "tool_util.h"

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

namespace {

using namespace skinbus::body_map;
constexpr double kRadToDeg = 180.0 / std::numbers::pi;

std::string fmt(const char* f, double a, double b = 0, double c = 0, double d = 0) {
  char buf[256];
  std::snprintf(buf, sizeof buf, f, a, b, c, d);
  return buf;
}

// A path named inside a file, taken relative to that file's folder.
struct PatchOutcome {
  const PatchPlacement* initial = nullptr;
  std::string status = "kept";  // calibrated | refused | kept (no touches)
  std::string note;
  std::vector<int> lines;  // touch log lines of this patch's touches
  skinbus::Result<PatchCalibration> result = skinbus::make_error(skinbus::ErrorCode::kInternal, "");
  double solve_ms = 0;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-calibrate: finds each patch's pose on its link (and optionally its cylinder\n"
      "radius) from calibration touches: a probe pressed at known positions, paired with the\n"
      "patch's own estimates of each touch. Ceres least squares with a robust loss; outlier\n"
      "touches are flagged; a touch set that cannot fix a pose (too few, collinear, clustered)\n"
      "is refused with what to add, and that patch keeps its pose.\n\n"
      "Writes the calibrated skin map (--out), a Markdown report (--report: per patch the pose\n"
      "change, uncertainty, residuals and outliers), the residual of every touch (--residuals)\n"
      "and a residual plot (--plot). Formats: docs/body_map.md.\n\n"
      "Exit status: 0 all patches with touches calibrated, 3 some refused (the others are\n"
      "written), 2 bad input (map, log, robot, options), 1 cannot write.\n\n"
      "Example:\n"
      "  skinbus-touchsim --robot body_map/robots/skinbot.urdf --out-dir s\n"
      "  skinbus-calibrate --map s/initial.yaml --touches s/touches.csv --truth s/truth.yaml \\\n"
      "      --out s/calibrated.yaml --report s/report.md --plot s/residuals.png\n"};
  std::string map_path, touches_path, robot_path, out_path, report_path, residuals_path, plot_path,
      truth_path;
  CalibrationOptions o;
  app.add_option("--map", map_path, "skin map to start from (YAML)")->required();
  app.add_option("--touches", touches_path, "touch log (CSV)")->required();
  app.add_option("--robot", robot_path,
                 "robot description (URDF); default: the map's robot key. Needed for "
                 "base-frame touches");
  app.add_option("--out", out_path, "write the calibrated skin map here");
  app.add_option("--report", report_path, "write a Markdown report here");
  app.add_option("--residuals", residuals_path, "write every touch's residual here (CSV)");
  app.add_option("--plot", plot_path,
                 "draw the residuals into this PNG (tools/plot_calibration.py; implies a "
                 "residuals CSV beside it unless --residuals is given)");
  app.add_option("--truth", truth_path,
                 "a skin map with the true poses (simulated sessions): report the errors");
  app.add_option("--probe-sigma", o.probe_sigma_mm, "probe position noise, mm (1 sd)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--estimate-sigma", o.estimate_sigma_mm,
                 "error of the patches' u, v estimates, mm (1 sd)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--depth-sigma", o.estimate_depth_sigma_mm,
                 "error of the patches' depth estimates, mm (1 sd)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--outlier-sigma", o.outlier_sigma,
                 "a touch whose residual exceeds this many sd is an outlier")
      ->capture_default_str()
      ->check(CLI::Range(1.5, 1000.0));
  app.add_flag("--fit-radius", o.fit_radius, "also fit the radius of cylinder patches");
  app.add_option("--min-touches", o.min_touches, "refuse a patch with fewer touches")
      ->capture_default_str()
      ->check(CLI::Range(3, 100000));
  CLI11_PARSE(app, argc, argv);

  auto bad = [](const std::string& m) { return skinbus::tools::fail("skinbus-calibrate", m, 2); };
  skinbus::Result<SkinMap> map = load_skin_map_file(map_path);
  if (!map.ok()) return bad(map.error().to_string());
  if (robot_path.empty()) robot_path = path_beside(map_path, map.value().robot);
  std::optional<RobotModel> robot;
  if (!robot_path.empty()) {
    skinbus::Result<RobotModel> r = RobotModel::from_urdf_file(robot_path);
    if (!r.ok()) return bad(r.error().to_string());
    robot = std::move(r.value());
    if (skinbus::Status st = validate_skin_map(map.value(), &*robot); !st.ok()) {
      return bad(map_path + ": " + st.error().message);
    }
  }
  skinbus::Result<TouchLog> log = load_touch_log_file(touches_path);
  if (!log.ok()) return bad(log.error().to_string());
  std::optional<SkinMap> truth;
  if (!truth_path.empty()) {
    skinbus::Result<SkinMap> t = load_skin_map_file(truth_path);
    if (!t.ok()) return bad(t.error().to_string());
    truth = std::move(t.value());
  }
  // Touches of nodes the map does not have: said, not silently dropped.
  std::map<int, int> unknown;
  for (const TouchRecord& r : log.value().touches)
    if (!map.value().find_node(r.node_id)) ++unknown[r.node_id];
  for (auto [node, count] : unknown) {
    std::fprintf(stderr,
                 "skinbus-calibrate: warning: %d touches of node %d, which the map does "
                 "not place: ignored\n",
                 count, node);
  }

  SkinMap out = map.value();
  std::vector<PatchOutcome> outcomes(map.value().patches.size());
  int refused = 0, calibrated = 0;
  const int count = static_cast<int>(outcomes.size());
  for (int i = 0; i < count; ++i) {
    const PatchPlacement& p = map.value().patches[i];
    PatchOutcome& oc = outcomes[i];
    oc.initial = &p;
    for (const TouchRecord& r : log.value().touches)
      if (r.node_id == p.node_id) oc.lines.push_back(r.line);
    skinbus::Result<std::vector<CalibrationTouch>> t =
        link_frame_touches(log.value(), p, robot ? &*robot : nullptr);
    if (!t.ok()) return bad(t.error().to_string());
    if (t.value().empty()) {
      oc.note = "no touches: pose kept";
    } else {
      const auto t0 = std::chrono::steady_clock::now();
      oc.result = calibrate_patch(p, t.value(), o);
      oc.solve_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (oc.result.ok()) {
        oc.status = "calibrated";
        ++calibrated;
        const PatchCalibration& c = oc.result.value();
        PatchPlacement& q = out.patches[i];
        q.pose_on_link = c.pose_on_link;
        if (o.fit_radius && q.geometry.kind == SurfaceKind::kCylinder) {
          q.geometry.radius_mm = c.radius_mm;
        }
        q.calibration = c.uncertainty;
        for (const std::string& w : c.warnings) oc.note += (oc.note.empty() ? "" : "; ") + w;
      } else {
        oc.status = "refused";
        ++refused;
        oc.note = oc.result.error().to_string() + " (pose kept)";
      }
    }
    std::fprintf(stderr, "[%d/%d] node %d (%s): %zu touches: %s%s%s\n", i + 1, count, p.node_id,
                 p.link.c_str(), oc.lines.size(), oc.status.c_str(), oc.note.empty() ? "" : ": ",
                 oc.note.c_str());
  }

  // Report.
  std::string report = "# Patch pose calibration\n\n";
  report += "Map `" + map_path + "`, touches `" + touches_path + "`" +
            (robot ? ", robot `" + robot_path + "`" : "") + ".\n" +
            fmt("Noise: probe %.3g mm, estimate %.3g mm (u, v) / %.3g mm (depth); outliers beyond "
                "%.3g sd.\n\n",
                o.probe_sigma_mm, o.estimate_sigma_mm, o.estimate_depth_sigma_mm, o.outlier_sigma) +
            std::to_string(calibrated) + " calibrated, " + std::to_string(refused) + " refused, " +
            std::to_string(count - calibrated - refused) + " without touches.\n\n";
  report +=
      "| node | link | status | touches | outliers | moved mm | turned deg | sd mm | sd deg "
      "| rms residual mm | residual / noise | solve ms |";
  report += truth ? " error mm | error deg |\n" : "\n";
  report += "|---|---|---|---|---|---|---|---|---|---|---|---|";
  report += truth ? "---|---|\n" : "\n";
  for (const PatchOutcome& oc : outcomes) {
    const PatchPlacement& p = *oc.initial;
    report += "| " + std::to_string(p.node_id) + " | " + p.link + " | " + oc.status + " | " +
              std::to_string(oc.lines.size()) + " | ";
    if (oc.status == "calibrated") {
      const PatchCalibration& c = oc.result.value();
      report +=
          std::to_string(c.uncertainty.touches - c.uncertainty.inliers) + " | " +
          fmt("%.2f | %.2f | %.3f | %.3f |",
              (c.pose_on_link.translation_mm - p.pose_on_link.translation_mm).norm(),
              rotation_angle_between(c.pose_on_link.rotation, p.pose_on_link.rotation) * kRadToDeg,
              c.uncertainty.position_sd_mm.norm(), c.uncertainty.rotation_sd_deg.norm()) +
          fmt(" %.3f | %.2f | %.2f |", c.uncertainty.rms_residual_mm, c.residual_sigma,
              oc.solve_ms);
      if (truth) {
        const PatchPlacement* t = truth->find_node(p.node_id);
        report +=
            t ? fmt(" %.3f | %.3f |",
                    (c.pose_on_link.translation_mm - t->pose_on_link.translation_mm).norm(),
                    rotation_angle_between(c.pose_on_link.rotation, t->pose_on_link.rotation) *
                        kRadToDeg)
              : " - | - |";
      }
    } else {
      report += "- | - | - | - | - | - | - | - |";
      if (truth) report += " - | - |";
    }
    report += "\n";
  }
  report +=
      "\nsd: the norm of the per-axis standard deviations from the covariance (scaled up "
      "when residuals exceed the stated noise).\n\n## Notes and outliers\n\n";
  for (const PatchOutcome& oc : outcomes) {
    if (!oc.note.empty()) {
      report += "- node " + std::to_string(oc.initial->node_id) + ": " + oc.note + "\n";
    }
    if (oc.status != "calibrated") continue;
    const PatchCalibration& c = oc.result.value();
    for (std::size_t k = 0; k < c.residuals.size(); ++k) {
      if (c.residuals[k].outlier) {
        report += "  - touch log line " + std::to_string(oc.lines[k]) +
                  fmt(": residual %.2f mm (%.1f sd): outlier, left out\n",
                      c.residuals[k].residual_mm.norm(), c.residuals[k].norm_sigma);
      }
    }
  }
  if (!plot_path.empty()) report += "\n![residuals](" + plot_path + ")\n";

  auto write = [](const std::string& path, const std::string& text) {
    return skinbus::write_file_atomic(path, text, "output file").ok();
  };
  if (!plot_path.empty() && residuals_path.empty()) residuals_path = plot_path + ".csv";
  if (!residuals_path.empty()) {
    std::string csv = "node,line,u_mm,v_mm,residual_mm,residual_sigma,outlier\n";
    for (const PatchOutcome& oc : outcomes) {
      if (oc.status != "calibrated") continue;
      const std::vector<TouchResidual>& rs = oc.result.value().residuals;
      int k = 0;
      for (const TouchRecord& r : log.value().touches) {
        if (r.node_id != oc.initial->node_id) continue;
        csv += std::to_string(r.node_id) + "," + std::to_string(r.line) +
               fmt(",%.3f,%.3f,%.4f,%.3f,", r.u_mm, r.v_mm, rs[k].residual_mm.norm(),
                   rs[k].norm_sigma) +
               (rs[k].outlier ? "1\n" : "0\n");
        ++k;
      }
    }
    if (!write(residuals_path, csv)) {
      return skinbus::tools::fail("skinbus-calibrate", "cannot write " + residuals_path, 1);
    }
  }
  if (!report_path.empty() && !write(report_path, report)) {
    return skinbus::tools::fail("skinbus-calibrate", "cannot write " + report_path, 1);
  }
  if (report_path.empty()) std::fputs(report.c_str(), stdout);
  if (!out_path.empty()) {
    if (!robot_path.empty()) {  // the written map names its robot relative to itself
      const std::filesystem::path dir = std::filesystem::absolute(out_path).parent_path();
      out.robot = std::filesystem::relative(std::filesystem::absolute(robot_path), dir).string();
    }
    if (skinbus::Status st = save_skin_map_file(out, out_path); !st.ok()) {
      return skinbus::tools::fail("skinbus-calibrate", st.error().to_string(), 1);
    }
  }
  if (!plot_path.empty()) {
    if (skinbus::Status s =
            skinbus::run_plot_script(SKINBUS_SOURCE_DIR "/tools", "plot_calibration.py",
                                     {residuals_path, plot_path, fmt("%.6g", o.outlier_sigma)});
        !s.ok()) {
      return skinbus::tools::fail("skinbus-calibrate",
                                  s.error().message + "; map and report are written", 1);
    }
  }
  return refused ? 3 : 0;
}
