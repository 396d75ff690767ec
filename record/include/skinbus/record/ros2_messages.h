// skinbus/record/ros2_messages.h: the messages a recording holds, as ROS 2 puts them on the wire
// (CDR, cdr.h) and describes them (ros2msg schemas, as rosbag2 stores them in MCAP):
//
//   type                                 topic                host type
//   skin_msgs/msg/ContactArray           /skin/contacts       host::ContactArray
//   skin_msgs/msg/PatchStatusArray       /skin/patch_status   host::PatchStatusArray
//   diagnostic_msgs/msg/DiagnosticArray  /diagnostics         host::DiagnosticArray
//   skin_msgs/msg/PatchSample            /skin/samples        PatchSampleMsg (below)
//   skin_msgs/msg/CanFrame               /skin/can            CanFrameMsg (below)
//   sensor_msgs/msg/JointState           /joint_states        JointStateMsg (below)
//
// The fields and units are those of the DDS topics (docs/dds.md): metres, seconds, the contact
// and status fields as dds/msg/ros2/skin_msgs/msg/ defines them. Encoders refuse (kInvalidArgument
// naming the field) a non-finite number and (kOutOfRange) a time beyond builtin_interfaces/Time,
// so nothing is written that a reader could not take back; decoders check every length against
// the message (cdr.h) and name the field they could not read. Nothing throws.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/bus/can_frame.h"
#include "skinbus/common/result.h"
#include "skinbus/host/contacts.h"
#include "skinbus/host/diagnostics.h"

namespace skinbus::record {

// The ros2msg schema of a type ("skin_msgs/msg/ContactArray"): its definition, then each type it
// uses (first use first) after a line of 80 '=' and "MSG: package/Type", as rosbag2 writes it.
// kNotFound for a type this library does not know.
Result<std::string> ros2_schema(std::string_view type);

struct PatchSampleMsg {
  uint64_t stamp_us = 0;  // the sample's time on the host's clock
  std::string link;       // header.frame_id: the patch's link ("" unmapped)
  uint8_t node = 0;
  uint64_t hardware_uid = 0;
  uint32_t patch_time_us = 0;
  uint16_t flags = 0, fault_mask = 0, saturation_mask = 0;
  std::vector<float> field_ut;  // 48: sensor-major x, y, z
  bool operator==(const PatchSampleMsg&) const = default;
};

struct CanFrameMsg {
  uint64_t rx_us = 0;     // header.stamp
  std::string interface;  // header.frame_id
  bus::CanFrame frame;
};

struct JointStateMsg {
  uint64_t stamp_us = 0;
  std::vector<std::string> names;
  std::vector<double> positions;  // rad, prismatic joints in metres (ROS 2 units)
  bool operator==(const JointStateMsg&) const = default;
};

// Encoders: `out` is overwritten with the CDR message.
Status encode(const host::ContactArray& contacts, std::vector<uint8_t>* out);
Status encode(const host::PatchStatusArray& status, std::vector<uint8_t>* out);
Status encode(const host::DiagnosticArray& diagnostics, std::vector<uint8_t>* out);
Status encode(const PatchSampleMsg& sample, std::vector<uint8_t>* out);
Status encode(const CanFrameMsg& frame, std::vector<uint8_t>* out);
Status encode(const JointStateMsg& joints, std::vector<uint8_t>* out);

// Decoders (kParse naming the type and field; kOutOfRange for a frame's data beyond 64 bytes or a
// length the frame kind does not have, or a negative time).
Result<host::ContactArray> decode_contacts(std::span<const uint8_t> cdr);
Result<PatchSampleMsg> decode_patch_sample(std::span<const uint8_t> cdr);
Result<CanFrameMsg> decode_can_frame(std::span<const uint8_t> cdr);
Result<JointStateMsg> decode_joint_state(std::span<const uint8_t> cdr);

}  // namespace skinbus::record
