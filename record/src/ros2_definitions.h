// The ROS 2 message definitions the recorder knows (generated into ros2_definitions.cc by CMake
// from record/msg/ and dds/msg/ros2/skin_msgs/msg/).
#pragma once

#include <cstddef>

namespace skinbus::record {

struct Ros2Definition {
  const char* type;  // "skin_msgs/msg/ContactArray"
  const char* text;  // the .msg file
};

extern const Ros2Definition kRos2Definitions[];
extern const std::size_t kRos2DefinitionCount;

}  // namespace skinbus::record
