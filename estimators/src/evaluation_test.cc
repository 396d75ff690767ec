#include "skinbus/estimators/evaluation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace skinbus::estimators {
namespace {

ContactEstimate placed(double u_mm, double v_mm, double depth_mm, double force_n) {
  ContactEstimate e;
  e.u_mm = u_mm;
  e.v_mm = v_mm;
  e.depth_mm = depth_mm;
  e.force_n = force_n;
  return e;
}

TEST(DepthBin, EdgesBelongToTheDeeperBinAndDeepPressesToTheLast) {
  EXPECT_EQ(depth_bin(-0.01), -1);
  EXPECT_EQ(depth_bin(std::nan("")), -1);
  EXPECT_EQ(depth_bin(0), 0);
  EXPECT_EQ(depth_bin(0.5), 1);
  EXPECT_EQ(depth_bin(1.999), 2);
  EXPECT_EQ(depth_bin(3), 4);
  EXPECT_EQ(depth_bin(9), 4);
  EXPECT_EQ(depth_bin_name(2), "1-2");
  EXPECT_EQ(depth_bin_name(kDepthBins), "none");
}

TEST(SummarizeErrors, PlacedEstimatesAreAveragedPerBinAndOverAll) {
  const std::vector<double> u = {0, 10}, v = {0, 0}, depth = {1.5, 2.5}, force = {1, 2};
  const std::vector<ContactEstimate> est = {placed(3, 4, 1.6, 1.5), placed(10, 1, 2.3, 2)};
  const ErrorSummary s = summarize_errors(est, {u, v, depth, force});
  EXPECT_EQ(s.all.count, 2);
  EXPECT_DOUBLE_EQ(s.all.xy_mean_mm, 3);  // (5 + 1) / 2
  EXPECT_NEAR(s.all.depth_mean_mm, 0.15, 1e-12);
  EXPECT_DOUBLE_EQ(s.all.force_mean_n, 0.25);
  EXPECT_DOUBLE_EQ(s.bins[2].xy_mean_mm, 5);
  EXPECT_DOUBLE_EQ(s.bins[3].xy_mean_mm, 1);
  EXPECT_EQ(s.bins[0].count, 0);
  EXPECT_TRUE(std::isnan(s.bins[0].xy_mean_mm));  // nothing to average: not a perfect score
  EXPECT_TRUE(std::isnan(s.bins[0].depth_mean_mm));
  EXPECT_DOUBLE_EQ(xy_mean_from_bin(s), 3);
  EXPECT_TRUE(std::isnan(xy_mean_from_bin(summarize_errors({}, Truth{}))));
}

// An estimate that found nothing pressed carries a fit to noise (here 9 mm deep, 80 mm away):
// what a consumer is told is "no contact", so the press costs its whole depth and force, and
// the estimate's place counts in no XY mean.
TEST(SummarizeErrors, AnEstimateThatFoundNothingCostsThePressDepth) {
  const std::vector<double> u = {0, 0}, v = {0, 0}, depth = {0.3, 0.1}, force = {0.2, 0.05};
  ContactEstimate nothing = placed(80, 0, 9, 40);
  nothing.flags = kEstimateNoContact | kEstimateOutsidePatch;
  const std::vector<ContactEstimate> est = {placed(1, 0, 0.4, 0.3), nothing};
  const ErrorSummary s = summarize_errors(est, {u, v, depth, force});
  EXPECT_EQ(s.all.count, 1);
  EXPECT_EQ(s.all.no_contact, 1);
  EXPECT_EQ(s.all.flagged, 0);
  EXPECT_DOUBLE_EQ(s.all.xy_mean_mm, 1);
  EXPECT_NEAR(s.all.depth_mean_mm, (0.1 + 0.1) / 2, 1e-12);
  EXPECT_NEAR(s.all.force_mean_n, (0.1 + 0.05) / 2, 1e-12);

  // Only misses: the depth is still scored, the place is not.
  const ErrorSummary m =
      summarize_errors(std::vector<ContactEstimate>{nothing, nothing}, {u, v, depth, force});
  EXPECT_EQ(m.all.count, 0);
  EXPECT_EQ(m.all.no_contact, 2);
  EXPECT_TRUE(std::isnan(m.all.xy_mean_mm));
  EXPECT_NEAR(m.all.depth_mean_mm, 0.2, 1e-12);
}

TEST(SummarizeErrors, RejectedEstimatesAreCountedAndInNoMean) {
  const std::vector<double> u = {0, 0}, v = {0, 0}, depth = {2, 2}, force = {1, 1};
  ContactEstimate rejected = placed(50, 50, 7, 9);
  rejected.flags = kEstimateRejected;
  ContactEstimate flagged = placed(0, 2, 2, 1);
  flagged.flags = kEstimatePoorFit | kEstimateMasked;
  const std::vector<ContactEstimate> est = {rejected, flagged};
  const ErrorSummary s = summarize_errors(est, {u, v, depth, force});
  EXPECT_EQ(s.all.rejected, 1);
  EXPECT_EQ(s.all.count, 1);
  EXPECT_EQ(s.all.flagged, 1);
  EXPECT_DOUBLE_EQ(s.all.xy_mean_mm, 2);
  EXPECT_DOUBLE_EQ(s.all.depth_mean_mm, 0);
}

}  // namespace
}  // namespace skinbus::estimators
