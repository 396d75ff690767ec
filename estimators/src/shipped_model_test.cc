// The default model shipped in estimators/models/ loads, runs on the host runtime, and is as
// accurate on a fresh simulated test split of the nominal patch as its metadata says.
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::estimators {
namespace {

std::string shipped_model() {
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  return std::string(dir ? dir : ".") + "/estimators/models/nominal_seed_cnn";
}

TEST(ShippedModel, LoadsAndMatchesItsRecordedErrors) {
  Result<ModelFile> m = read_model(shipped_model());
  ASSERT_TRUE(m.ok()) << m.error().to_string();
  EXPECT_EQ(m->meta.architecture.conv_channels, (std::vector<int>{32, 64, 128, 256}));
  EXPECT_EQ(m->meta.architecture.hidden, (std::vector<int>{512, 256, 128, 64}));
  Result<NetworkRuntime> rt = NetworkRuntime::create(*m);
  ASSERT_TRUE(rt.ok()) << rt.error().to_string();
  // A fresh split (another noise seed and other positions than the one in the metadata).
  sim::SimulatedPatch patch(sim::PatchModel::nominal(sim::PatchDesign{}).value(), 99);
  const sim::Dataset test = sim::generate_random_test_set(patch, 1500, 67.5, 4.0, 1234);
  std::vector<ContactEstimate> out(test.rows());
  ASSERT_TRUE(rt->run(test.field_ut, static_cast<int>(test.rows()), out).ok());
  const ErrorSummary s = summarize_errors(out, {test.u_mm, test.v_mm, test.depth_mm, test.force_n});
  for (int b = 2; b < kDepthBins; ++b) {
    const std::string key = "test_xy_mean_mm_depth_" + depth_bin_name(b);
    ASSERT_TRUE(m->meta.metrics.count(key)) << key;
    const double recorded = m->meta.metrics.at(key);
    const double now = s.bins[static_cast<std::size_t>(b)].xy_mean_mm;
    std::printf("depth %s: XY mean %.3f mm (recorded %.3f)\n", depth_bin_name(b).c_str(), now,
                recorded);
    EXPECT_LT(now, 1.25 * recorded + 0.1) << key;
  }
  EXPECT_LT(s.all.depth_mean_mm, 1.25 * m->meta.metrics.at("test_depth_mean_mm") + 0.02);
  EXPECT_EQ(s.all.rejected, 0);
}

}  // namespace
}  // namespace skinbus::estimators
