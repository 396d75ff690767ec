// Fuzzes the unit-file reader (sim/unit_parameters.h): the input is the file's text.
// Invariants beyond "does not crash", for a file that parses:
// - writing the parameters and reading them back gives the same bits (spread, lateral and every
//   magnet's and sensor's numbers), and the same note;
// - PatchModel::from_parameters() on the default design either refuses them with a message or
//   builds a unit whose rest field is finite.
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
  if (note_back.source != note.source || note_back.refused != note.refused) {
    fail("the note changed");
  }
  if (!same(back->spread_mm, p->spread_mm) || !same(back->lateral_mm, p->lateral_mm)) {
    fail("lattice numbers changed");
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
  return 0;
}
