#include "skinbus/body_map/touch_log.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <sstream>

namespace skinbus::body_map {
namespace {

Result<TouchLog> parse(const std::string& text) {
  std::istringstream in(text);
  return read_touch_log(in);
}

const std::string kHeader = "node,frame,probe_x_mm,probe_y_mm,probe_z_mm,u_mm,v_mm,depth_mm";

TEST(TouchLog, ReadsRowsCommentsAndJointColumns) {
  Result<TouchLog> log =
      parse("# a session\n" + kHeader +
            ",q:a,q:b\n3,link,1,2,3,4,5,6,,\n\n4,base, 1.5 ,-2,3e2,0,0,1,0.1,-0.2\r\n");
  ASSERT_TRUE(log.ok()) << log.error().to_string();
  ASSERT_EQ(log.value().touches.size(), 2u);
  EXPECT_EQ(log.value().joint_names, (std::vector<std::string>{"a", "b"}));
  const TouchRecord& b = log.value().touches[1];
  EXPECT_EQ(b.node_id, 4);
  EXPECT_EQ(b.frame, ProbeFrame::kBase);
  EXPECT_EQ(b.probe_mm, Eigen::Vector3d(1.5, -2, 300));
  EXPECT_EQ(b.joint_positions, (std::vector<double>{0.1, -0.2}));
  EXPECT_EQ(b.line, 5);
}

TEST(TouchLog, ErrorsNameLineAndColumn) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"", "no header"},
      {"node,frame\n", "the header needs"},
      {"node,frame,x,probe_y_mm,probe_z_mm,u_mm,v_mm,depth_mm\n", "column 3 is 'x'"},
      {kHeader + ",joint\n", "joint columns are q:<joint>"},
      {kHeader + ",q:a,q:a\n", "appears twice"},
      {kHeader + "\n0,link,1,2,3,4,5,6\n", "line 2: node '0'"},
      {kHeader + "\n3,world,1,2,3,4,5,6\n", "frame 'world'"},
      {kHeader + "\n3,link,1,2,nan,4,5,6\n", "probe_z_mm 'nan'"},
      {kHeader + "\n3,link,1,2,3,4,5\n", "7 fields"},
      {kHeader + "\n3,base,1,2,3,4,5,6\n", "needs the joint positions"},
      {kHeader + ",q:a\n3,base,1,2,3,4,5,6,x\n", "q:a 'x'"},
      // Every row given twice: accepted, the calibration's uncertainty shrank by sqrt(2).
      {kHeader + "\n3,link,1,2,3,4,5,6\n4,link,1,2,3,4,5,6\n3,link,1.0,2,3,4,5,6e0\n",
       "line 4: repeats the touch of line 2 exactly"},
      {kHeader + ",q:a\n3,base,1,2,3,4,5,6,0.5\n3,base,1,2,3,4,5,6,0.5\n",
       "line 3: repeats the touch of line 2"},
      {kHeader + "\n3,link,1,2,3,4,5," + std::string(100000, '6') + "\n",
       "line 2: longer than 65536 bytes"},
  };
  for (const auto& [text, says] : cases) {
    Result<TouchLog> log = parse(text);
    ASSERT_FALSE(log.ok()) << text;
    EXPECT_EQ(log.error().code, ErrorCode::kParse);
    EXPECT_NE(log.error().message.find(says), std::string::npos)
        << "expected '" << says << "' in: " << log.error().message;
  }
  EXPECT_EQ(load_touch_log_file("/nonexistent.csv").error().code, ErrorCode::kNotFound);
  EXPECT_NE(load_touch_log_file("/tmp").error().message.find("is a directory"), std::string::npos);
  // The same probe point with another joint state, or another estimate, is another touch.
  EXPECT_TRUE(parse(kHeader + ",q:a\n3,base,1,2,3,4,5,6,0.5\n3,base,1,2,3,4,5,6,0.6\n").ok());
  EXPECT_TRUE(parse(kHeader + "\n3,link,1,2,3,4,5,6\n3,link,1,2,3,4,5,6.5\n").ok());
}

TEST(TouchLog, WritesWhatItReads) {
  TouchLog log;
  log.joint_names = {"j1", "j2"};
  log.touches.push_back({3, ProbeFrame::kLink, {0.1, 1.0 / 3, -7e-5}, 1.25, -2.5, 1.0 / 7, {}, 0});
  log.touches.push_back({9, ProbeFrame::kBase, {100, 200, 300}, 0, 0, 2, {0.3, -1.0 / 3}, 0});
  Result<TouchLog> back = parse(touch_log_to_csv(log));
  ASSERT_TRUE(back.ok()) << back.error().to_string();
  ASSERT_EQ(back.value().touches.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    const TouchRecord &a = log.touches[i], &b = back.value().touches[i];
    EXPECT_EQ(a.node_id, b.node_id);
    EXPECT_EQ(a.frame, b.frame);
    EXPECT_EQ(a.probe_mm, b.probe_mm);
    EXPECT_EQ(a.u_mm, b.u_mm);
    EXPECT_EQ(a.depth_mm, b.depth_mm);
  }
  EXPECT_EQ(back.value().touches[1].joint_positions, log.touches[1].joint_positions);
}

const char* kArm = R"(<robot name="arm">
  <link name="base"/>
  <link name="upper"/>
  <link name="fore"/>
  <link name="other"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="elbow" type="revolute">
    <parent link="upper"/><child link="fore"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="spin" type="continuous">
    <parent link="base"/><child link="other"/><axis xyz="1 0 0"/>
  </joint>
</robot>)";

TEST(TouchLog, BaseFrameTouchesMoveIntoTheLinkFrame) {
  Result<RobotModel> robot = RobotModel::from_urdf_string(kArm);
  ASSERT_TRUE(robot.ok()) << robot.error().to_string();
  PatchPlacement patch;
  patch.node_id = 5;
  patch.link = "fore";
  // At shoulder = 90 deg, elbow = 0: fore's origin is at (0, 300, 500) mm, its x along base y.
  Result<TouchLog> log =
      parse(kHeader + ",q:elbow,q:shoulder\n5,base,0,350,510,0,0,0,0," + "1.5707963267948966" +
            "\n5,link,1,2,3,0,0,0,,\n7,link,0,0,0,0,0,0,,\n");
  ASSERT_TRUE(log.ok()) << log.error().to_string();
  Result<std::vector<CalibrationTouch>> t = link_frame_touches(log.value(), patch, &robot.value());
  ASSERT_TRUE(t.ok()) << t.error().to_string();
  ASSERT_EQ(t.value().size(), 2u);  // node 7's row is not this patch's
  EXPECT_LT((t.value()[0].probe_mm - Eigen::Vector3d(50, 0, 10)).norm(), 1e-9);
  EXPECT_EQ(t.value()[1].probe_mm, Eigen::Vector3d(1, 2, 3));
  // Without the robot, or without a joint that moves the link: a clear error.
  EXPECT_FALSE(link_frame_touches(log.value(), patch, nullptr).ok());
  Result<TouchLog> missing = parse(kHeader + ",q:spin\n5,base,0,350,510,0,0,0,0\n");
  ASSERT_TRUE(missing.ok());
  Result<std::vector<CalibrationTouch>> e =
      link_frame_touches(missing.value(), patch, &robot.value());
  ASSERT_FALSE(e.ok());
  EXPECT_NE(e.error().message.find("q:elbow"), std::string::npos) << e.error().message;
}

}  // namespace
}  // namespace skinbus::body_map
