// Unit files: UnitParameters as JSON ("skinbus-unit 1").
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include "skinbus/common/atomic_file.h"
#include "skinbus/common/json_text.h"
#include "skinbus/common/yaml_reader.h"
#include "skinbus/sim/unit_parameters.h"

namespace skinbus::sim {
namespace {

using json = nlohmann::json;

constexpr const char* kFormat = "skinbus-unit";
constexpr int kMajorVersion = 1;

json vec(const Vec3<double>& v) {
  return json::array({v.x, v.y, v.z});
}

// Reads a JSON document field by field; the first problem is kept with the field's path.
class Reader {
 public:
  bool ok() const { return error_.empty(); }
  const std::string& error() const { return error_; }

  double number(const json& j, const char* key, const std::string& where) {
    if (!ok()) return 0;
    const auto it = j.find(key);
    if (it == j.end() || !it->is_number()) {
      fail(where + key + (it == j.end() ? " is missing" : " is not a number"));
      return 0;
    }
    return it->get<double>();
  }
  Vec3<double> triple(const json& j, const char* key, const std::string& where) {
    if (!ok()) return {};
    const auto it = j.find(key);
    if (it == j.end()) {
      fail(where + key + " is missing");
      return {};
    }
    return triple_of(*it, where + key);
  }
  // An optional string: empty when absent.
  std::string text(const json& j, const char* key, const std::string& where) {
    if (!ok()) return {};
    const auto it = j.find(key);
    if (it == j.end()) return {};
    if (!it->is_string()) {
      fail(where + key + " is not a string");
      return {};
    }
    return it->get<std::string>();
  }
  // A magnet's or sensor's surface position: u_mm, v_mm, h_mm.
  template <typename Part>
  void position(const json& j, const std::string& where, Part* part) {
    part->u_mm = number(j, "u_mm", where);
    part->v_mm = number(j, "v_mm", where);
    part->h_mm = number(j, "h_mm", where);
  }
  // `node` must be an array of 3 numbers; `name` names it in the error.
  Vec3<double> triple_of(const json& node, const std::string& name) {
    if (!ok()) return {};
    if (!node.is_array() || node.size() != 3) {
      fail(name + " must be an array of 3 numbers");
      return {};
    }
    double v[3];
    for (std::size_t i = 0; i < 3; ++i) {
      if (!node[i].is_number()) {
        fail(name + "[" + std::to_string(i) + "] is not a number");
        return {};
      }
      v[i] = node[i].get<double>();
    }
    return {v[0], v[1], v[2]};
  }
  // Calls fn(element, "key[i].") for every element of the array `key`, each of which must be an
  // object; stops at the first problem.
  template <typename Fn>
  void each_object(const json& j, const char* key, Fn fn) {
    if (!ok()) return;
    const auto it = j.find(key);
    if (it == j.end() || !it->is_array()) {
      fail(std::string(key) + " must be an array");
      return;
    }
    for (std::size_t i = 0; i < it->size() && ok(); ++i) {
      const std::string name = std::string(key) + "[" + std::to_string(i) + "]";
      if (!(*it)[i].is_object()) {
        fail(name + " is not an object");
        return;
      }
      fn((*it)[i], name + ".");
    }
  }
  void fail(const std::string& what) {
    if (ok()) error_ = what;
  }
  // A whole integer field; `where` + key names it in the error.
  int integer(const json& j, const char* key, const std::string& where) {
    const double x = number(j, key, where);
    if (ok() && (x != std::floor(x) || std::fabs(x) > 1e6))
      fail(where + key + " is not an integer");
    return ok() ? static_cast<int>(x) : 0;
  }
  // The optional `field_correction` object (FieldCorrection::make() checks its sizes).
  std::shared_ptr<const FieldCorrection> field_correction(const json& f) {
    const std::string where = "field_correction.";
    if (!f.is_object()) {
      fail("field_correction is not an object");
      return nullptr;
    }
    FieldCorrection::Grid g;
    g.u0_mm = number(f, "u0_mm", where);
    g.v0_mm = number(f, "v0_mm", where);
    g.step_mm = number(f, "step_mm", where);
    g.nu = integer(f, "nu", where);
    g.nv = integer(f, "nv", where);
    g.max_depth_mm = number(f, "max_depth_mm", where);
    const int terms = integer(f, "depth_terms", where);
    const int channels = integer(f, "channels", where);
    if (ok() && terms != FieldCorrection::kDepthTerms) {
      fail(where + "depth_terms must be " + std::to_string(FieldCorrection::kDepthTerms));
    }
    const auto c = f.find("coefficients_ut");
    if (ok() && (c == f.end() || !c->is_array())) fail(where + "coefficients_ut must be an array");
    if (!ok()) return nullptr;
    std::vector<double> coef;
    coef.reserve(c->size());
    for (std::size_t i = 0; i < c->size(); ++i) {
      if (!(*c)[i].is_number()) {
        fail(where + "coefficients_ut[" + std::to_string(i) + "] is not a number");
        return nullptr;
      }
      coef.push_back((*c)[i].get<double>());
    }
    Result<FieldCorrection> made = FieldCorrection::make(g, channels, std::move(coef));
    if (!made.ok()) {
      fail(made.error().message);
      return nullptr;
    }
    return std::make_shared<const FieldCorrection>(std::move(*made));
  }
  // The optional `creep` object: {"fraction": f in [0, 1), "time_s": tau in (0, 3600]}, and
  // optionally a second, slower lag: "slow_fraction" f_s >= 0 (f + f_s < 1), "slow_time_s".
  void creep(const json& c, UnitParameters* p) {
    if (!c.is_object()) {
      fail("creep is not an object");
      return;
    }
    p->creep_fraction = number(c, "fraction", "creep.");
    p->creep_time_s = number(c, "time_s", "creep.");
    if (ok() && !(p->creep_fraction >= 0 && p->creep_fraction < 1)) {
      fail("creep.fraction must be in [0, 1)");
    }
    if (ok() && !(p->creep_time_s > 0 && p->creep_time_s <= 3600)) {
      fail("creep.time_s must be in (0, 3600]");
    }
    if (!ok() || !c.contains("slow_fraction")) return;
    p->creep_slow_fraction = number(c, "slow_fraction", "creep.");
    p->creep_slow_time_s = number(c, "slow_time_s", "creep.");
    if (ok() && !(p->creep_slow_fraction >= 0 && p->creep_fraction + p->creep_slow_fraction < 1)) {
      fail("creep.slow_fraction must be >= 0, and fraction + slow_fraction < 1");
    }
    if (ok() && !(p->creep_slow_time_s > 0 && p->creep_slow_time_s <= 3600)) {
      fail("creep.slow_time_s must be in (0, 3600]");
    }
  }
  // The optional `pressed_area_mm` object: {"u": [min, max], "v": [min, max]}, finite, min <= max.
  PressedArea pressed_area(const json& a) {
    const std::string where = "pressed_area_mm";
    if (!a.is_object()) {
      fail(where + " is not an object");
      return {};
    }
    double range[2][2] = {};
    const char* const keys[2] = {"u", "v"};
    for (int k = 0; k < 2 && ok(); ++k) {
      const std::string name = where + "." + keys[k];
      const auto it = a.find(keys[k]);
      if (it == a.end() || !it->is_array() || it->size() != 2 || !(*it)[0].is_number() ||
          !(*it)[1].is_number()) {
        fail(name + " must be an array of 2 numbers, [min, max]");
        return {};
      }
      range[k][0] = (*it)[0].get<double>();
      range[k][1] = (*it)[1].get<double>();
      if (!std::isfinite(range[k][0]) || !std::isfinite(range[k][1]) ||
          !(range[k][0] <= range[k][1])) {
        fail(name + " must be finite with min <= max");
      }
    }
    return {range[0][0], range[0][1], range[1][0], range[1][1]};
  }

 private:
  std::string error_;
};

}  // namespace

std::string unit_parameters_json(const UnitParameters& p, const UnitFileNote& note) {
  json j;
  j["format"] = json_format_name(kFormat, kMajorVersion);
  j["source"] = note.source;
  if (!note.refused.empty()) j["refused"] = note.refused;
  if (const std::optional<PressedArea>& a = note.pressed_area; a) {
    j["pressed_area_mm"] = {{"u", {a->u_min_mm, a->u_max_mm}}, {"v", {a->v_min_mm, a->v_max_mm}}};
  }
  j["units"] = {{"length", "mm"}, {"moment", "A m^2"}};
  j["spread_mm"] = p.spread_mm;
  if (p.anisotropy != 0) j["anisotropy"] = p.anisotropy;
  j["lateral_mm"] = p.lateral_mm;
  if (p.depth_zero_mm != 0) j["depth_zero_mm"] = p.depth_zero_mm;
  json magnets = json::array();
  for (const MagnetParameters& m : p.magnets) {
    magnets.push_back(
        {{"u_mm", m.u_mm}, {"v_mm", m.v_mm}, {"h_mm", m.h_mm}, {"moment_am2", vec(m.moment_am2)}});
  }
  j["magnets"] = std::move(magnets);
  json sensors = json::array();
  for (const SensorParameters& s : p.sensors) {
    sensors.push_back(
        {{"u_mm", s.u_mm},
         {"v_mm", s.v_mm},
         {"h_mm", s.h_mm},
         {"mounting", {vec(s.mounting.r[0]), vec(s.mounting.r[1]), vec(s.mounting.r[2])}},
         {"gain", vec(s.gain)}});
  }
  j["sensors"] = std::move(sensors);
  if (p.creep_fraction > 0 || p.creep_slow_fraction > 0) {
    j["creep"] = {{"fraction", p.creep_fraction}, {"time_s", p.creep_time_s}};
    if (p.creep_slow_fraction > 0) {
      j["creep"]["slow_fraction"] = p.creep_slow_fraction;
      j["creep"]["slow_time_s"] = p.creep_slow_time_s;
    }
  }
  if (const FieldCorrection* f = p.field_correction.get(); f != nullptr) {
    const FieldCorrection::Grid& g = f->grid();
    j["field_correction"] = {{"u0_mm", g.u0_mm},
                             {"v0_mm", g.v0_mm},
                             {"step_mm", g.step_mm},
                             {"nu", g.nu},
                             {"nv", g.nv},
                             {"max_depth_mm", g.max_depth_mm},
                             {"depth_terms", FieldCorrection::kDepthTerms},
                             {"channels", f->channels()},
                             {"coefficients_ut", f->coefficients()}};
  }
  // nlohmann::json writes doubles with 17 significant digits: the round trip is exact.
  return j.dump(1) + "\n";
}

Status write_unit_parameters(const UnitParameters& params, const std::string& path,
                             const UnitFileNote& note) {
  // A temporary file, checked, synced and renamed: never a torn or empty unit file.
  return write_file_atomic(path, unit_parameters_json(params, note), "unit file");
}

Result<UnitParameters> parse_unit_parameters(std::string_view text, UnitFileNote* note) {
  Result<json> doc = parse_json_document(text, kFormat, kMajorVersion, "unit file");
  if (!doc.ok()) return doc.error();
  const json& j = *doc;
  Reader r;
  UnitParameters p;
  p.spread_mm = r.number(j, "spread_mm", "");
  if (j.contains("anisotropy")) {  // optional: 0 when absent (a file written before the field)
    p.anisotropy = r.number(j, "anisotropy", "");
    if (r.ok() && !(std::fabs(p.anisotropy) < 0.5)) r.fail("anisotropy must be in (-0.5, 0.5)");
  }
  p.lateral_mm = r.number(j, "lateral_mm", "");
  if (j.contains("depth_zero_mm")) {  // optional: 0 when absent (a file written before the field)
    p.depth_zero_mm = r.number(j, "depth_zero_mm", "");
  }
  r.each_object(j, "magnets", [&](const json& m, const std::string& where) {
    MagnetParameters mp;
    r.position(m, where, &mp);
    mp.moment_am2 = r.triple(m, "moment_am2", where);
    p.magnets.push_back(mp);
  });
  r.each_object(j, "sensors", [&](const json& s, const std::string& where) {
    SensorParameters sp;
    r.position(s, where, &sp);
    sp.gain = r.triple(s, "gain", where);
    const auto mounting = s.find("mounting");
    if (mounting == s.end() || !mounting->is_array() || mounting->size() != 3) {
      r.fail(where + "mounting must be 3 rows of 3 numbers");
    } else {
      for (std::size_t row = 0; row < 3 && r.ok(); ++row) {
        sp.mounting.r[row] =
            r.triple_of((*mounting)[row], where + "mounting[" + std::to_string(row) + "]");
      }
    }
    p.sensors.push_back(sp);
  });
  if (const auto c = j.find("creep"); r.ok() && c != j.end()) r.creep(*c, &p);
  if (const auto fc = j.find("field_correction"); r.ok() && fc != j.end()) {
    p.field_correction = r.field_correction(*fc);
  }
  UnitFileNote read_note{r.text(j, "source", ""), r.text(j, "refused", ""), std::nullopt};
  if (const auto a = j.find("pressed_area_mm"); r.ok() && a != j.end()) {
    read_note.pressed_area = r.pressed_area(*a);
  }
  if (!r.ok()) return make_error(ErrorCode::kParse, r.error());
  if (const std::size_t at = read_note.source.find(kRefusedInSource);
      read_note.refused.empty() && at != std::string::npos) {  // written before the field
    read_note.refused = read_note.source.substr(at + kRefusedInSource.size());
    if (read_note.refused.empty()) read_note.refused = "no reason given";
  }
  if (note != nullptr) *note = std::move(read_note);
  return p;
}

Result<UnitParameters> read_unit_parameters(const std::string& path, UnitFileNote* note) {
  Result<std::string> text = read_text_file(path, "unit file", 16u << 20);
  if (!text.ok()) return text.error();
  Result<UnitParameters> p = parse_unit_parameters(*text, note);
  if (!p.ok()) return make_error(p.error().code, "unit file " + path + ": " + p.error().message);
  return p;
}

}  // namespace skinbus::sim
