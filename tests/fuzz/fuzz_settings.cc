// Fuzzes the patch node's text inputs: the YAML settings file and the contact script.
// Invariants beyond "does not crash": a settings text that loads and validates prints to YAML
// that loads and validates to the same print; an accepted contact script has only finite,
// ordered presses.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "skinbus/patch_fw/config.h"
#include "skinbus/patch_sim/sim_source.h"

using namespace skinbus::patch_fw;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string text(reinterpret_cast<const char*>(data + 1), size - 1);
  if (data[0] & 1) {
    auto r = skinbus::patch_sim::parse_contact_script(text, static_cast<uint8_t>(data[0] >> 1));
    if (r.ok()) {
      for (const auto& c : *r) {
        if (!std::isfinite(c.t_start_s) || !std::isfinite(c.u_mm) || !(c.t_end_s > c.t_start_s) ||
            !(c.depth_mm >= 0))
          std::abort();
      }
    }
    return 0;
  }
  PatchNodeSettings s = default_settings();
  if (!load_settings_text(text, &s).ok() || !validate_settings(&s).ok()) return 0;
  const std::string printed = settings_to_yaml(s);
  PatchNodeSettings again = default_settings();
  if (!load_settings_text(printed, &again).ok() || !validate_settings(&again).ok()) std::abort();
  if (settings_to_yaml(again) != printed) {
    std::fprintf(stderr, "printed:\n%s\nreprinted:\n%s\n", printed.c_str(),
                 settings_to_yaml(again).c_str());
    std::abort();
  }
  return 0;
}
