#include "skinbus/patch_sim/sim_source.h"

#include <gtest/gtest.h>

namespace skinbus::patch_sim {
namespace {

TEST(ContactScript, ReadsRowsForThisNode) {
  Result<std::vector<sim::SceneContact>> c = parse_contact_script(
      "t_start_s,t_end_s,u_mm,v_mm,depth_mm,tip_radius_mm,node\n"
      "# a comment\n\n"
      "0.5, 1.5, -10, 20.5, 2 # trailing comment\n"
      "2,3,0,0,1,4,3\r\n"
      "2,3,0,0,1,4,4\n",
      3);
  ASSERT_TRUE(c.ok()) << c.error().to_string();
  ASSERT_EQ(c.value().size(), 2u);  // node 4's row is for another node
  EXPECT_EQ(c.value()[0].u_mm, -10);
  EXPECT_EQ(c.value()[0].v_mm, 20.5);
  EXPECT_EQ(c.value()[0].tip_radius_mm, 8.0);  // the default
  EXPECT_EQ(c.value()[1].tip_radius_mm, 4.0);
  EXPECT_FALSE(c.value()[1].slides());
  // A slide: its end and friction; without a friction, none.
  Result<std::vector<sim::SceneContact>> s =
      parse_contact_script("1,3,-30,0,2,5,0,30,10,0.4\n1,3,0,0,1,5,0,5,5\n", 7);
  ASSERT_TRUE(s.ok()) << s.error().to_string();
  ASSERT_EQ(s.value().size(), 2u);
  EXPECT_TRUE(s.value()[0].slides());
  EXPECT_EQ(s.value()[0].u_end_mm, 30);
  EXPECT_EQ(s.value()[0].v_end_mm, 10);
  EXPECT_EQ(s.value()[0].friction, 0.4);
  EXPECT_EQ(s.value()[1].friction, 0.0);
}

TEST(ContactScript, ErrorsNameLineAndField) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"0,1,0,0,x\n", "line 1: field 5 'x'"},
      {"\n0,1,0,0,nan\n", "line 2: field 5 'nan'"},
      {"0,1,0,0,1,2,3,4\n", "8 fields"},
      {"0,1,0\n", "3 fields (5 to 7"},
      {"0,1,0,0,1,2,3,4,5,6,7\n", "field 11 '7'"},
      {"0,1,0,0,1,2,3,4,5,-0.5\n", "friction 0..2"},
      {"0,1,0,,1\n", "field 4 ''"},
      {"2,1,0,0,1\n", "t_end_s > t_start_s"},
  };
  for (const auto& [text, says] : cases) {
    Result<std::vector<sim::SceneContact>> c = parse_contact_script(text, 1);
    ASSERT_FALSE(c.ok()) << text;
    EXPECT_NE(c.error().message.find(says), std::string::npos)
        << "expected '" << says << "' in: " << c.error().message;
  }
}

}  // namespace
}  // namespace skinbus::patch_sim
