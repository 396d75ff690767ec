// Fuzzes the patch design file reader (sim/design_file.h): the input is the file's text.
// Invariants beyond "does not crash", for a file that parses:
// - the design validates and holds only finite numbers;
// - writing it and reading it back gives the same file again (every setting, exactly);
// - PatchModel::nominal() builds it (a design the reader accepts is one the physics can model)
//   when it is small enough to build quickly, and its rest field is finite.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "skinbus/sim/design_file.h"
#include "skinbus/sim/patch_model.h"

using namespace skinbus;
using namespace skinbus::sim;

namespace {

[[noreturn]] void fail(const char* what, const std::string& text) {
  std::fprintf(stderr, "fuzz_design_file: %s\n%s\n", what, text.c_str());
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  Result<PatchDesign> d = parse_design(text, "fuzz.yaml");
  if (!d.ok()) {
    if (d.error().message.rfind("fuzz.yaml: ", 0) != 0) fail("error without the file", text);
    return 0;
  }
  const PatchDesign& design = d.value();
  if (!validate(design).ok()) fail("accepted a design validate() refuses", text);
  const double numbers[] = {design.size_u_mm,
                            design.size_v_mm,
                            design.radius_mm,
                            design.thickness_mm,
                            design.magnet_pitch_mm,
                            design.remanence_t,
                            design.sensor_pitch_mm,
                            design.sensor_depth_mm,
                            design.spread_mm,
                            design.lateral_mm,
                            design.anisotropy,
                            design.stiffness_n_per_mm,
                            design.magnet_centre_height_mm,
                            design.stiffening_n_per_mm3};
  for (double x : numbers) {
    if (!std::isfinite(x)) fail("non-finite number", text);
  }
  const std::string yaml = design_to_yaml(design);
  Result<PatchDesign> back = parse_design(yaml, "fuzz.yaml");
  if (!back.ok())
    fail(("written design does not read back: " + back.error().message).c_str(), yaml);
  if (design_to_yaml(back.value()) != yaml) fail("round trip changed the design", yaml);
  if (design.magnet_count() * design.sensor_count() <= 64 * 64) {
    Result<PatchModel> model = PatchModel::nominal(design);
    if (model.ok()) {
      std::vector<double> field(static_cast<std::size_t>(design.channel_count()));
      model->rest_field_ut(field);
      for (double f : field) {
        if (!std::isfinite(f)) fail("non-finite rest field", yaml);
      }
    }
  }
  return 0;
}
