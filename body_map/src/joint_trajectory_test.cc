#include "skinbus/body_map/joint_trajectory.h"

#include <gtest/gtest.h>

namespace skinbus::body_map {
namespace {

TEST(JointTrajectory, InterpolatesAndHolds) {
  auto t = parse_joint_trajectory("# a test\ntime_s,a,b\n0,0,1\n2,1,3\n", "t.csv");
  ASSERT_TRUE(t.ok()) << t.error().to_string();
  ASSERT_EQ(t->names.size(), 2u);
  double q[2];
  t->sample(1.0, q);
  EXPECT_DOUBLE_EQ(q[0], 0.5);
  EXPECT_DOUBLE_EQ(q[1], 2.0);
  t->sample(-5, q);
  EXPECT_DOUBLE_EQ(q[0], 0.0);
  t->sample(9, q);
  EXPECT_DOUBLE_EQ(q[1], 3.0);
  t->sample(2.0, q);
  EXPECT_DOUBLE_EQ(q[0], 1.0);
}

TEST(JointTrajectory, RoundTripsThroughCsv) {
  auto t = parse_joint_trajectory("time_s,j\n0,0.125\n0.5,-1e-3\n", "t.csv");
  ASSERT_TRUE(t.ok());
  auto u = parse_joint_trajectory(joint_trajectory_to_csv(*t), "u.csv");
  ASSERT_TRUE(u.ok());
  EXPECT_EQ(u->t_s, t->t_s);
  EXPECT_EQ(u->q, t->q);
}

TEST(JointTrajectory, ErrorsNameTheLine) {
  struct Case {
    const char* text;
    const char* expect;
  } cases[] = {
      {"", "no header"},
      {"t,a\n0,1\n", ":1: the header"},
      {"time_s,a,a\n", "named twice"},
      {"time_s,a\n0,1,2\n", ":2: 3 fields"},
      {"time_s,a\n0,nan\n", ":2: joint 'a'"},
      {"time_s,a\n1,0\n1,0\n", ":3: times must increase"},
      {"time_s,a\n", "no rows"},
      {"time_s,a\n0,-1e308\n1,1e308\n", ":2: joint 'a' beyond"},
      {"time_s,a\n-1.7e308,0\n1.7e308,0\n", ":2: time beyond"},
  };
  for (const Case& c : cases) {
    auto t = parse_joint_trajectory(c.text, "f.csv");
    ASSERT_FALSE(t.ok()) << c.text;
    EXPECT_NE(t.error().message.find(c.expect), std::string::npos) << t.error().message;
  }
  EXPECT_EQ(load_joint_trajectory("/nonexistent/j.csv").error().code, ErrorCode::kNotFound);
}

}  // namespace
}  // namespace skinbus::body_map
