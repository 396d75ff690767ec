// Patch design files (design_file.h): YAML in, PatchDesign out, and back.
#include "skinbus/sim/design_file.h"

#include <cstdio>
#include <sstream>
#include <string>

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/yaml_reader.h"

namespace skinbus::sim {
namespace {

constexpr const char* kFormat = "skinbus-patch-design";
constexpr long long kVersion = 1;

// Wide bounds: the file reader refuses what is not a patch at all; validate() checks the
// design's consistency (sensors inside the patch, a cylinder larger than the sensor depth).
constexpr double kMaxLengthMm = 10'000;

void read_grid(YamlReader& r, const YAML::Node& grid, const std::string& path, int* u, int* v,
               double* pitch_mm) {
  if (!grid) return;
  r.only(grid, path, {"u", "v", "pitch_mm"});
  r.get_int(grid, "u", path + ".", 1, 64, u);
  r.get_int(grid, "v", path + ".", 1, 64, v);
  r.get_double(grid, "pitch_mm", path + ".", 1e-3, kMaxLengthMm, pitch_mm);
}

// A YAML sequence of mappings at `path`: calls `entry(node, "path[k].")` for each.
template <typename F>
void read_list(YamlReader& r, const YAML::Node& list, const std::string& path, std::size_t max,
               F entry) {
  if (!list || r.error) return;
  if (!list.IsSequence() || list.size() == 0) {
    r.fail(path, list, "expected a non-empty list");
    return;
  }
  if (list.size() > max) {
    r.fail(path, list, "more than " + std::to_string(max) + " entries");
    return;
  }
  for (std::size_t k = 0; k < list.size() && !r.error; ++k) {
    entry(list[k], path + "[" + std::to_string(k) + "]");
  }
}

Result<PatchDesign> parse_root(const YAML::Node& root) {
  YamlReader r;
  PatchDesign d;
  r.only(
      root, "",
      {"format", "version", "surface", "magnets", "sensors", "lattice", "force_law", "indenter"});
  std::string format;
  r.get_string(root, "format", "", &format);
  if (!r.error && format != kFormat) {
    r.fail("format", root["format"] ? root["format"] : root,
           format.empty()
               ? std::string("missing: a design file starts with 'format: ") + kFormat + "'"
               : "'" + format + "' is not " + kFormat);
  }
  long long version = kVersion;
  r.get_int(root, "version", "", 1, kVersion, &version);

  if (const YAML::Node s = root["surface"]; s && !r.error) {
    r.only(s, "surface", {"kind", "size_u_mm", "size_v_mm", "radius_mm", "thickness_mm"});
    std::string kind = d.surface == SurfaceKind::kFlat ? "flat" : "cylinder";
    r.get_string(s, "kind", "surface.", &kind);
    if (!r.error && kind != "flat" && kind != "cylinder") {
      r.fail("surface.kind", s["kind"], "'" + kind + "' is not flat or cylinder");
    }
    d.surface = kind == "cylinder" ? SurfaceKind::kCylinder : SurfaceKind::kFlat;
    r.get_double(s, "size_u_mm", "surface.", 1e-3, kMaxLengthMm, &d.size_u_mm);
    r.get_double(s, "size_v_mm", "surface.", 1e-3, kMaxLengthMm, &d.size_v_mm);
    r.get_double(s, "radius_mm", "surface.", 0, kMaxLengthMm, &d.radius_mm);
    r.get_double(s, "thickness_mm", "surface.", 1e-3, kMaxLengthMm, &d.thickness_mm);
  }
  if (const YAML::Node m = root["magnets"]; m && !r.error) {
    r.only(m, "magnets",
           {"grid", "list", "polarity", "diameter_mm", "height_mm", "remanence_t",
            "centre_height_mm", "remanence_tempco_per_c"});
    if (!r.error && m["grid"] && m["list"]) {
      r.fail("magnets.list", m["list"], "give the magnets as a grid or as a list, not both");
    }
    read_grid(r, m["grid"], "magnets.grid", &d.magnets_u, &d.magnets_v, &d.magnet_pitch_mm);
    std::string polarity = d.polarity == Polarity::kUniform ? "uniform" : "checkerboard";
    r.get_string(m, "polarity", "magnets.", &polarity);
    if (!r.error && polarity != "uniform" && polarity != "checkerboard") {
      r.fail("magnets.polarity", m["polarity"],
             "'" + polarity + "' is not uniform or checkerboard");
    }
    d.polarity = polarity == "uniform" ? Polarity::kUniform : Polarity::kCheckerboard;
    r.get_double(m, "diameter_mm", "magnets.", 1e-3, 1000, &d.magnet_diameter_mm);
    r.get_double(m, "height_mm", "magnets.", 1e-3, 1000, &d.magnet_height_mm);
    r.get_double(m, "remanence_t", "magnets.", 1e-3, 2.0, &d.remanence_t);
    r.get_double(m, "centre_height_mm", "magnets.", -kMaxLengthMm, kMaxLengthMm,
                 &d.magnet_centre_height_mm);
    r.get_double(m, "remanence_tempco_per_c", "magnets.", -0.1, 0.1, &d.remanence_tempco_per_c);
    // After centre_height_mm: an entry without its own height takes it.
    read_list(r, m["list"], "magnets.list", 4096, [&](const YAML::Node& e, const std::string& at) {
      r.only(e, at, {"u_mm", "v_mm", "centre_height_mm", "polarity"});
      MagnetPlacement mp;
      mp.centre_height_mm = d.magnet_centre_height_mm;
      r.get_double(e, "u_mm", at + ".", -kMaxLengthMm, kMaxLengthMm, &mp.u_mm);
      r.get_double(e, "v_mm", at + ".", -kMaxLengthMm, kMaxLengthMm, &mp.v_mm);
      r.get_double(e, "centre_height_mm", at + ".", -kMaxLengthMm, kMaxLengthMm,
                   &mp.centre_height_mm);
      r.get_int(e, "polarity", at + ".", -1, 1, &mp.polarity);
      if (!r.error && mp.polarity == 0) r.fail(at + ".polarity", e["polarity"], "must be 1 or -1");
      if (!r.error && (!e["u_mm"] || !e["v_mm"])) r.fail(at, e, "u_mm and v_mm are required");
      d.magnet_list.push_back(mp);
    });
  }
  if (const YAML::Node s = root["sensors"]; s && !r.error) {
    r.only(s, "sensors", {"grid", "list", "depth_mm", "chip"});
    if (!r.error && s["grid"] && s["list"]) {
      r.fail("sensors.list", s["list"], "give the sensors as a grid or as a list, not both");
    }
    read_grid(r, s["grid"], "sensors.grid", &d.sensors_u, &d.sensors_v, &d.sensor_pitch_mm);
    r.get_double(s, "depth_mm", "sensors.", 1e-3, kMaxLengthMm, &d.sensor_depth_mm);
    // After depth_mm: an entry without its own depth takes it.
    read_list(r, s["list"], "sensors.list", kMaxSensors,
              [&](const YAML::Node& e, const std::string& at) {
                r.only(e, at, {"u_mm", "v_mm", "depth_mm", "yaw_deg"});
                SensorPlacement sp;
                sp.depth_mm = d.sensor_depth_mm;
                r.get_double(e, "u_mm", at + ".", -kMaxLengthMm, kMaxLengthMm, &sp.u_mm);
                r.get_double(e, "v_mm", at + ".", -kMaxLengthMm, kMaxLengthMm, &sp.v_mm);
                r.get_double(e, "depth_mm", at + ".", 1e-3, kMaxLengthMm, &sp.depth_mm);
                r.get_double(e, "yaw_deg", at + ".", -360, 360, &sp.yaw_deg);
                if (!r.error && (!e["u_mm"] || !e["v_mm"]))
                  r.fail(at, e, "u_mm and v_mm are required");
                d.sensor_list.push_back(sp);
              });
    if (const YAML::Node c = s["chip"]; c && !r.error) {
      r.only(c, "sensors.chip", {"gain_sel", "res_xy", "res_z", "osr", "dig_filt", "temperature"});
      mlx90393::Config& cfg = d.sensor_config;
      r.get_int(c, "gain_sel", "sensors.chip.", 0, 7, &cfg.gain_sel);
      r.get_int(c, "res_xy", "sensors.chip.", 0, 3, &cfg.res_xy);
      r.get_int(c, "res_z", "sensors.chip.", 0, 3, &cfg.res_z);
      r.get_int(c, "osr", "sensors.chip.", 0, 3, &cfg.osr);
      r.get_int(c, "dig_filt", "sensors.chip.", 0, 7, &cfg.dig_filt);
      r.get_bool(c, "temperature", "sensors.chip.", &cfg.temperature);
    }
  }
  if (const YAML::Node l = root["lattice"]; l && !r.error) {
    r.only(l, "lattice",
           {"spread_mm", "lateral_mm", "anisotropy", "tip_crush_mm", "inplane_drag",
            "creep_fraction", "creep_time_s", "creep_slow_fraction", "creep_slow_time_s",
            "shear_stiffness_n_per_mm", "shear_spread_mm"});
    r.get_double(l, "spread_mm", "lattice.", 1e-3, kMaxLengthMm, &d.spread_mm);
    r.get_double(l, "lateral_mm", "lattice.", 0, kMaxLengthMm, &d.lateral_mm);
    r.get_double(l, "anisotropy", "lattice.", -0.499, 0.499, &d.anisotropy);
    r.get_double(l, "tip_crush_mm", "lattice.", 0, kMaxLengthMm, &d.tip_crush_mm);
    r.get_double(l, "inplane_drag", "lattice.", 0, 1, &d.inplane_drag);
    r.get_double(l, "creep_fraction", "lattice.", 0, 0.999, &d.creep_fraction);
    r.get_double(l, "creep_time_s", "lattice.", 1e-3, 3600, &d.creep_time_s);
    r.get_double(l, "creep_slow_fraction", "lattice.", 0, 0.999, &d.creep_slow_fraction);
    r.get_double(l, "creep_slow_time_s", "lattice.", 1e-3, 3600, &d.creep_slow_time_s);
    r.get_double(l, "shear_stiffness_n_per_mm", "lattice.", 1e-6, 1e6, &d.shear_stiffness_n_per_mm);
    r.get_double(l, "shear_spread_mm", "lattice.", 1e-3, kMaxLengthMm, &d.shear_spread_mm);
  }
  if (const YAML::Node f = root["force_law"]; f && !r.error) {
    r.only(f, "force_law", {"stiffness_n_per_mm", "stiffening_n_per_mm3"});
    r.get_double(f, "stiffness_n_per_mm", "force_law.", 1e-6, 1e6, &d.stiffness_n_per_mm);
    r.get_double(f, "stiffening_n_per_mm3", "force_law.", 0, 1e6, &d.stiffening_n_per_mm3);
  }
  if (const YAML::Node t = root["indenter"]; t && !r.error) {
    r.only(t, "indenter", {"tip_radius_mm"});
    r.get_double(t, "tip_radius_mm", "indenter.", 0, kMaxIndenterTipRadiusMm,
                 &d.indenter_tip_radius_mm);
  }
  if (r.error) return *r.error;
  // Consistency across settings (no one line to name): validate()'s message names them.
  if (Status s = validate(d); !s.ok()) return s.error();
  return d;
}

}  // namespace

Result<PatchDesign> parse_design(const std::string& text, const std::string& source) {
  Result<YAML::Node> root = parse_yaml_text(text);
  if (!root.ok()) return make_error(root.error().code, source + ": " + root.error().message);
  try {
    Result<PatchDesign> d = parse_root(root.value());
    if (!d.ok()) return make_error(d.error().code, source + ": " + d.error().message);
    return d;
  } catch (const YAML::Exception& e) {
    return make_error(ErrorCode::kParse,
                      source + ": line " + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
}

Result<PatchDesign> read_design_file(const std::string& path) {
  Result<std::string> text = read_text_file(path, "patch design");
  if (!text.ok()) return text.error();
  return parse_design(text.value(), path);
}

Result<PatchDesign> read_design_or_builtin(const std::string& path) {
  if (path.empty()) return PatchDesign{};
  return read_design_file(path);
}

std::string design_to_yaml(const PatchDesign& d) {
  const mlx90393::Config& c = d.sensor_config;
  std::ostringstream o;
  o << "# skinbus patch design (docs/design_file.md). Lengths in mm, the surface frame's u and v\n"
       "# along the sensor grid, heights out of the skin.\n"
    << "format: " << kFormat << "\n"
    << "version: " << kVersion << "\n"
    << "surface:\n"
    << "  kind: " << (d.surface == SurfaceKind::kCylinder ? "cylinder" : "flat") << "\n"
    << "  size_u_mm: " << yaml_number(d.size_u_mm) << "   # arc length along u on a cylinder\n"
    << "  size_v_mm: " << yaml_number(d.size_v_mm) << "\n"
    << "  radius_mm: " << yaml_number(d.radius_mm) << "   # cylinder: the skin surface's radius\n"
    << "  thickness_mm: " << yaml_number(d.thickness_mm) << "   # the lattice\n"
    << "magnets:\n";
  if (d.magnet_list.empty()) {
    o << "  grid: {u: " << d.magnets_u << ", v: " << d.magnets_v
      << ", pitch_mm: " << yaml_number(d.magnet_pitch_mm) << "}   # centred on the patch\n";
  } else {
    o << "  list:   # rest positions; polarity 1: north pole out of the skin\n";
    for (const MagnetPlacement& m : d.magnet_list) {
      o << "    - {u_mm: " << yaml_number(m.u_mm) << ", v_mm: " << yaml_number(m.v_mm)
        << ", centre_height_mm: " << yaml_number(m.centre_height_mm) << ", polarity: " << m.polarity
        << "}\n";
    }
  }
  o << "  polarity: " << (d.polarity == Polarity::kUniform ? "uniform" : "checkerboard") << "\n"
    << "  diameter_mm: " << yaml_number(d.magnet_diameter_mm) << "\n"
    << "  height_mm: " << yaml_number(d.magnet_height_mm) << "\n"
    << "  remanence_t: " << yaml_number(d.remanence_t) << "\n"
    << "  centre_height_mm: " << yaml_number(d.magnet_centre_height_mm)
    << "   # magnet centre above the surface (negative: below)\n"
    << "  remanence_tempco_per_c: " << yaml_number(d.remanence_tempco_per_c) << "\n"
    << "sensors:\n";
  if (d.sensor_list.empty()) {
    o << "  grid: {u: " << d.sensors_u << ", v: " << d.sensors_v
      << ", pitch_mm: " << yaml_number(d.sensor_pitch_mm) << "}   # centred on the patch\n";
  } else {
    o << "  list:   # channels 3k..3k+2 are the k-th sensor's x, y, z\n";
    for (const SensorPlacement& sp : d.sensor_list) {
      o << "    - {u_mm: " << yaml_number(sp.u_mm) << ", v_mm: " << yaml_number(sp.v_mm)
        << ", depth_mm: " << yaml_number(sp.depth_mm) << ", yaw_deg: " << yaml_number(sp.yaw_deg)
        << "}\n";
    }
  }
  o << "  depth_mm: " << yaml_number(d.sensor_depth_mm) << "   # below the surface\n"
    << "  chip: {gain_sel: " << int{c.gain_sel} << ", res_xy: " << int{c.res_xy}
    << ", res_z: " << int{c.res_z} << ", osr: " << int{c.osr} << ", dig_filt: " << int{c.dig_filt}
    << ", temperature: " << (c.temperature ? "true" : "false") << "}   # MLX90393 settings\n"
    << "lattice:\n"
    << "  spread_mm: " << yaml_number(d.spread_mm) << "   # plate-on-foundation length\n"
    << "  lateral_mm: " << yaml_number(d.lateral_mm) << "   # in-plane motion = -lateral x slope\n"
    << "  anisotropy: " << yaml_number(d.anisotropy)
    << "   # spread l(1+a) along u, l(1-a) along v\n"
    << "  tip_crush_mm: " << yaml_number(d.tip_crush_mm)
    << "   # the plate bends d / (1 + d / this) under a press d deep (0: no crush)\n"
    << "  inplane_drag: " << yaml_number(d.inplane_drag)
    << "   # also dragged toward a press by this x deflection x distance / spread\n"
    << "  creep_fraction: " << yaml_number(d.creep_fraction)
    << "   # this part of the bend lags the press (0: no creep) ...\n"
    << "  creep_time_s: " << yaml_number(d.creep_time_s) << "   # ... with this time constant\n"
    << "  creep_slow_fraction: " << yaml_number(d.creep_slow_fraction)
    << "   # a further part lags the press (0: none) ...\n"
    << "  creep_slow_time_s: " << yaml_number(d.creep_slow_time_s)
    << "   # ... with this slower time constant\n"
    << "  shear_stiffness_n_per_mm: " << yaml_number(d.shear_stiffness_n_per_mm)
    << "   # in-plane shift under a tangential force F: F / this\n"
    << "  shear_spread_mm: " << yaml_number(d.shear_spread_mm)
    << "   # ... decaying as exp(-r / this) around the contact\n"
    << "force_law:   # F = k d + k3 d^3\n"
    << "  stiffness_n_per_mm: " << yaml_number(d.stiffness_n_per_mm) << "\n"
    << "  stiffening_n_per_mm3: " << yaml_number(d.stiffening_n_per_mm3) << "\n"
    << "indenter:   # the lab probe's round tip, and the tip the host's refinement assumes\n"
    << "  tip_radius_mm: " << yaml_number(d.indenter_tip_radius_mm) << "   # 0: a point\n";
  return o.str();
}

Status write_design_file(const PatchDesign& design, const std::string& path) {
  return write_file_atomic(path, design_to_yaml(design), "patch design");
}

}  // namespace skinbus::sim
