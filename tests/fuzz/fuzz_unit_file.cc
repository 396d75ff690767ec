// Fuzzes the unit-file reader (sim/unit_parameters.h): the input is the file's text.
// Invariants beyond "does not crash", for a file that parses:
// - writing the parameters and reading them back gives the same bits (spread, lateral and every
//   magnet's and sensor's numbers), and the same note;
//   and of its field correction, when it has one (grid and coefficients);
// - PatchModel::from_parameters() on the default design either refuses them with a message or
//   builds a unit whose rest field, and field change and Jacobian under a press, are finite (a
//   field correction included).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/sim/patch_model.h"
#include "skinbus/sim/unit_parameters.h"

using namespace skinbus;
using namespace skinbus::sim;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_unit_file: %s\n", what);
  std::abort();
}

bool same(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}
bool same(const Vec3<double>& a, const Vec3<double>& b) {
  return same(a.x, b.x) && same(a.y, b.y) && same(a.z, b.z);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  UnitFileNote note;
  Result<UnitParameters> p = parse_unit_parameters(text, &note);
  if (!p.ok()) {
    if (p.error().message.empty()) fail("an error without a message");
    return 0;
  }
  UnitFileNote note_back;
  Result<UnitParameters> back = parse_unit_parameters(unit_parameters_json(*p, note), &note_back);
  if (!back.ok()) fail("what was written does not parse");
  if (note_back.source != note.source || note_back.refused != note.refused ||
      note_back.pressed_area.has_value() != note.pressed_area.has_value()) {
    fail("the note changed");
  }
  if (const auto& a = note.pressed_area, &b = note_back.pressed_area; a && b) {
    if (!same(a->u_min_mm, b->u_min_mm) || !same(a->u_max_mm, b->u_max_mm) ||
        !same(a->v_min_mm, b->v_min_mm) || !same(a->v_max_mm, b->v_max_mm)) {
      fail("the pressed area changed");
    }
    if (!(a->u_min_mm <= a->u_max_mm) || !(a->v_min_mm <= a->v_max_mm)) {
      fail("an empty pressed area was taken");
    }
  }
  if (!same(back->spread_mm, p->spread_mm) || !same(back->lateral_mm, p->lateral_mm)) {
    fail("lattice numbers changed");
  }
  // The anisotropy: its value travels (0 is not written, so -0 comes back +0).
  if (!(back->anisotropy == p->anisotropy) || !(std::fabs(p->anisotropy) < 0.5)) {
    fail("the anisotropy changed, or one out of range was taken");
  }
  // The presses' depth zero travels (0 is not written, so -0 comes back +0).
  if (!(back->depth_zero_mm == p->depth_zero_mm) || !std::isfinite(p->depth_zero_mm)) {
    fail("the depth zero changed, or a non-finite one was taken");
  }
  // The creep: a law travels bit for bit; none (both fractions 0) is not written, its times with
  // it, nor is a second lag's time without the lag.
  const bool creeps = p->creep_fraction > 0 || p->creep_slow_fraction > 0;
  if (!same(back->creep_fraction, p->creep_fraction) ||
      !same(back->creep_slow_fraction, p->creep_slow_fraction) ||
      (creeps && !same(back->creep_time_s, p->creep_time_s)) ||
      (p->creep_slow_fraction > 0 && !same(back->creep_slow_time_s, p->creep_slow_time_s))) {
    fail("the creep changed");
  }
  if (!(p->creep_fraction >= 0 && p->creep_fraction < 1) ||
      !(p->creep_time_s > 0 && p->creep_time_s <= 3600) ||
      !(p->creep_slow_fraction >= 0 && p->creep_fraction + p->creep_slow_fraction < 1) ||
      !(p->creep_slow_time_s > 0 && p->creep_slow_time_s <= 3600)) {
    fail("a creep out of range was taken");
  }
  if (back->magnets.size() != p->magnets.size() || back->sensors.size() != p->sensors.size()) {
    fail("counts changed");
  }
  for (std::size_t i = 0; i < p->magnets.size(); ++i) {
    const MagnetParameters &a = p->magnets[i], &b = back->magnets[i];
    if (!same(a.u_mm, b.u_mm) || !same(a.v_mm, b.v_mm) || !same(a.h_mm, b.h_mm) ||
        !same(a.moment_am2, b.moment_am2)) {
      fail("a magnet changed");
    }
  }
  for (std::size_t i = 0; i < p->sensors.size(); ++i) {
    const SensorParameters &a = p->sensors[i], &b = back->sensors[i];
    if (!same(a.u_mm, b.u_mm) || !same(a.v_mm, b.v_mm) || !same(a.h_mm, b.h_mm) ||
        !same(a.gain, b.gain) || !same(a.mounting.r[0], b.mounting.r[0]) ||
        !same(a.mounting.r[1], b.mounting.r[1]) || !same(a.mounting.r[2], b.mounting.r[2])) {
      fail("a sensor changed");
    }
  }
  if ((p->field_correction == nullptr) != (back->field_correction == nullptr)) {
    fail("the field correction came or went");
  }
  if (p->field_correction != nullptr) {
    const FieldCorrection &a = *p->field_correction, &b = *back->field_correction;
    const FieldCorrection::Grid &ga = a.grid(), &gb = b.grid();
    if (!same(ga.u0_mm, gb.u0_mm) || !same(ga.v0_mm, gb.v0_mm) || !same(ga.step_mm, gb.step_mm) ||
        !same(ga.max_depth_mm, gb.max_depth_mm) || ga.nu != gb.nu || ga.nv != gb.nv ||
        a.channels() != b.channels() || a.coefficients().size() != b.coefficients().size()) {
      fail("the field correction's grid changed");
    }
    for (std::size_t i = 0; i < a.coefficients().size(); ++i) {
      if (!same(a.coefficients()[i], b.coefficients()[i])) fail("a correction coefficient changed");
    }
  }
  Result<PatchModel> model = PatchModel::from_parameters(PatchDesign{}, *p);
  if (!model.ok()) {
    if (model.error().message.empty()) fail("a refusal without a message");
    return 0;
  }
  std::vector<double> rest(static_cast<std::size_t>(model->channel_count()));
  model->rest_field_ut(rest);
  for (double v : rest) {
    if (!std::isfinite(v)) fail("a unit that builds has a non-finite rest field");
  }
  if (p->field_correction == nullptr) return 0;
  // The correction at presses inside and outside its grid.
  std::vector<double> field(rest.size()), jac(3 * rest.size());
  for (const Contact c : {Contact{3.0, -7.5, 2.0, 5.0}, Contact{500.0, -900.0, 30.0, 5.0}}) {
    model->contact_field_ut(std::span<const Contact>(&c, 1), field);
    for (double v : field) {
      if (!std::isfinite(v)) fail("a unit with a field correction has a non-finite field");
    }
    model->contact_jacobian(c, jac, field);
    for (double v : jac) {
      if (!std::isfinite(v)) fail("a unit with a field correction has a non-finite Jacobian");
    }
  }
  return 0;
}
