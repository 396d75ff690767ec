// Fuzzes the dataset CSV reader (sim/dataset.h; docs/dataset_format.md): the input is the file.
// Invariants beyond "does not crash":
// - a dataset that reads has rows, every column name once (u_mm and x_mm count as one), finite
//   positions and depths, no infinite field value, and at most the reader's bounds;
// - written and read again, it reads the same; written and read once more, every number is the
//   same bit for bit (the writer keeps 9 significant digits, so the first round may round);
// - its stuck channels (sim::leave_out_stuck_channels) are read as dead and named, the rest of
//   the dataset unchanged, and none is stuck after.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <set>
#include <string>
#include <vector>

#include "skinbus/sim/dataset.h"

using namespace skinbus;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_dataset: %s\n", what);
  std::abort();
}

bool same(double a, double b) {
  if (std::isnan(a) || std::isnan(b)) return std::isnan(a) && std::isnan(b);
  uint64_t x, y;
  std::memcpy(&x, &a, 8);
  std::memcpy(&y, &b, 8);
  return x == y;
}

bool same(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i)
    if (!same(a[i], b[i])) return false;
  return true;
}

bool same(const sim::Dataset& a, const sim::Dataset& b) {
  return a.press == b.press && a.extra_columns == b.extra_columns &&
         a.sensors.size() == b.sensors.size() && same(a.t_s, b.t_s) && same(a.u_mm, b.u_mm) &&
         same(a.v_mm, b.v_mm) && same(a.depth_mm, b.depth_mm) && same(a.force_n, b.force_n) &&
         same(a.field_ut, b.field_ut) && same(a.extra, b.extra);
}

std::string temp(const char* name) {
  return (std::filesystem::temp_directory_path() /
          ("fuzz_dataset_" + std::to_string(getpid()) + "_" + name))
      .string();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  const std::string in = temp("in.csv");
  {
    std::FILE* f = std::fopen(in.c_str(), "wb");
    if (f == nullptr) return 0;
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  Result<sim::Dataset> d = sim::read_dataset_csv(in);
  if (!d.ok()) return 0;
  if (d->rows() == 0) fail("a dataset without rows was accepted");
  std::set<std::string> names(d->extra_columns.begin(), d->extra_columns.end());
  if (names.size() != d->extra_columns.size()) fail("a column name twice was accepted");
  for (const std::string& n : d->extra_columns) {
    if (n == "u_mm" || n == "x_mm" || n == "v_mm" || n == "y_mm" || n == "depth_mm" ||
        n == "press" || n == "t_s" || n == "force_n") {
      fail("a standard column was kept as an extra one");
    }
  }
  if (d->extra_columns.size() + 3 + d->field_ut.size() / d->rows() > sim::kMaxDatasetColumns + 3)
    fail("more columns than the bound");
  for (std::size_t r = 0; r < d->rows(); ++r) {
    if (!std::isfinite(d->u_mm[r]) || !std::isfinite(d->v_mm[r]) || !std::isfinite(d->depth_mm[r]))
      fail("a non-finite label was accepted");
  }
  for (double x : d->field_ut)
    if (std::isinf(x)) fail("an infinite field value was accepted");
  const std::string out = temp("out.csv");
  if (!sim::write_dataset_csv(*d, out).ok()) fail("a dataset that read does not write");
  Result<sim::Dataset> once = sim::read_dataset_csv(out);
  if (!once.ok()) fail(("a written dataset does not read: " + once.error().message).c_str());
  if (once->rows() != d->rows() || once->channels() != d->channels())
    fail("rows or channels changed");
  if (!sim::write_dataset_csv(*once, out).ok()) fail("a dataset that read does not write (2)");
  Result<sim::Dataset> twice = sim::read_dataset_csv(out);
  if (!twice.ok() || !same(*once, *twice)) fail("the second round trip changed a number");
  const std::vector<int> stuck = sim::stuck_channels(*twice);
  sim::Dataset left = *twice;
  const std::string note = sim::leave_out_stuck_channels(&left);
  if (stuck.empty() != note.empty()) fail("stuck channels and their note disagree");
  for (int c : stuck) {
    if (note.find(sim::field_column_name(c)) == std::string::npos) fail("a stuck channel unnamed");
  }
  const std::size_t nc = static_cast<std::size_t>(left.channels());
  for (std::size_t i = 0; i < left.field_ut.size(); ++i) {
    const bool is_stuck =
        std::find(stuck.begin(), stuck.end(), static_cast<int>(i % nc)) != stuck.end();
    if (is_stuck ? !std::isnan(left.field_ut[i]) : !same(left.field_ut[i], twice->field_ut[i]))
      fail("leaving out the stuck channels changed another value or kept one");
  }
  if (!sim::stuck_channels(left).empty()) fail("a channel still stuck after leaving it out");
  std::remove(in.c_str());
  std::remove(out.c_str());
  return 0;
}
