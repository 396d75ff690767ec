// The libgpiod back end's error paths (no GPIO chip on the development machines; with
// /dev/gpiochip0 present it also checks a real chip).
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <string>

#include "skinbus/patch_fw/gpio.h"

namespace skinbus::patch_fw {
namespace {

bool contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

TEST(GpiodTest, MissingChipByNameIsNotFound) {
  auto chip = open_gpiod_chip("gpiochip-does-not-exist");
  ASSERT_FALSE(chip.ok());
  EXPECT_EQ(chip.error().code, ErrorCode::kNotFound);
  EXPECT_TRUE(contains(chip.error().message, "gpiochip-does-not-exist")) << chip.error().message;
}

TEST(GpiodTest, MissingChipByPathIsNotFound) {
  auto chip = open_gpiod_chip("/dev/nonexistent_gpiochip");
  ASSERT_FALSE(chip.ok());
  EXPECT_EQ(chip.error().code, ErrorCode::kNotFound);
  EXPECT_TRUE(contains(chip.error().message, "/dev/nonexistent_gpiochip")) << chip.error().message;
}

TEST(GpiodTest, DeviceThatIsNoGpioChipIsNotFound) {
  for (const char* path : {"/dev/null", "/proc/self/status"}) {
    auto chip = open_gpiod_chip(path);
    ASSERT_FALSE(chip.ok()) << path;
    EXPECT_EQ(chip.error().code, ErrorCode::kNotFound) << chip.error().message;
    EXPECT_TRUE(contains(chip.error().message, path)) << chip.error().message;
  }
  auto empty = open_gpiod_chip("");
  ASSERT_FALSE(empty.ok());
  EXPECT_EQ(empty.error().code, ErrorCode::kInvalidArgument);
}

// Only with hardware (or gpio-sim): opens gpiochip0 without requesting lines it might not own.
TEST(GpiodTest, RealChipRejectsOffsetPastItsLines) {
  struct stat st {};
  if (::stat("/dev/gpiochip0", &st) != 0) GTEST_SKIP() << "no /dev/gpiochip0 on this machine";
  auto chip = open_gpiod_chip("gpiochip0");
  ASSERT_TRUE(chip.ok()) << chip.error().message;
  EXPECT_EQ((*chip)->name(), "gpiochip0");
  ASSERT_GT((*chip)->line_count(), 0u);
  auto out = (*chip)->request_output({.offset = (*chip)->line_count()}, "skinbus-test");
  ASSERT_FALSE(out.ok());
  EXPECT_EQ(out.error().code, ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(out.error().message, "gpiochip0")) << out.error().message;
}

}  // namespace
}  // namespace skinbus::patch_fw
