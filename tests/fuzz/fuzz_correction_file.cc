// Fuzzes the correction-file reader (estimators/bias_correction.h): the input is the file's text.
// Invariants beyond "does not crash", for a file that parses:
// - writing the correction and reading it back gives the same options and note, and the same
//   corrected estimate bit for bit at a few places;
// - a corrected estimate is finite (apply() keeps the estimate when the correction is not).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>

#include "skinbus/estimators/bias_correction.h"

using namespace skinbus;
using namespace skinbus::estimators;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_correction_file: %s\n", what);
  std::abort();
}

bool same(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::string source;
  Result<BiasCorrection> c = BiasCorrection::parse(text, &source);
  if (!c.ok()) {
    if (c.error().message.empty()) fail("an error without a message");
    return 0;
  }
  std::string source_back;
  Result<BiasCorrection> back = BiasCorrection::parse(c->to_json(nullptr, source), &source_back);
  if (!back.ok()) fail("what was written does not parse");
  if (source_back != source) fail("the note changed");
  const BiasCorrectionOptions &a = c->options(), &b = back->options();
  if (a.degree_uv != b.degree_uv || a.depth_uv() != b.depth_uv() ||
      a.degree_depth != b.degree_depth || !same(a.half_u_mm, b.half_u_mm) ||
      !same(a.min_depth_mm, b.min_depth_mm) || a.correct_position != b.correct_position ||
      a.correct_depth != b.correct_depth || back->terms() != c->terms() ||
      back->depth_terms() != c->depth_terms()) {
    fail("the options changed");
  }
  for (double u : {-60.0, 0.0, 33.0}) {
    for (double depth : {0.5, 2.0, 4.0}) {
      ContactEstimate e;
      e.u_mm = u;
      e.v_mm = -u / 2;
      e.depth_mm = depth;
      const ContactEstimate x = c->apply(e), y = back->apply(e);
      if (!std::isfinite(x.u_mm) || !std::isfinite(x.v_mm) || !std::isfinite(x.depth_mm)) {
        fail("a corrected estimate is not finite");
      }
      if (!same(x.u_mm, y.u_mm) || !same(x.v_mm, y.v_mm) || !same(x.depth_mm, y.depth_mm)) {
        fail("the read-back correction applies differently");
      }
    }
  }
  return 0;
}
