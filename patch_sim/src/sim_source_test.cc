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
}

TEST(ContactScript, ErrorsNameLineAndField) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"0,1,0,0,x\n", "line 1: field 5 'x'"}, {"\n0,1,0,0,nan\n", "line 2: field 5 'nan'"},
      {"0,1,0,0,1,2,3,4\n", "field 8 '4'"},   {"0,1,0\n", "3 fields, at least 5 needed"},
      {"0,1,0,,1\n", "field 4 ''"},           {"2,1,0,0,1\n", "t_end_s > t_start_s"},
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
