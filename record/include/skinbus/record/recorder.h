// skinbus/record/recorder.h: a host's session into an MCAP file, as rosbag2 records ROS 2 topics
// (profile ros2, ros2msg schemas, CDR messages, one channel per topic; ros2_messages.h):
//
//   /skin/contacts      skin_msgs/msg/ContactArray          every publication
//   /skin/patch_status  skin_msgs/msg/PatchStatusArray      every status (with its events)
//   /diagnostics        diagnostic_msgs/msg/DiagnosticArray with every status (host::diagnose)
//   /skin/samples       skin_msgs/msg/PatchSample           every sample attributed to a patch
//   /skin/can           skin_msgs/msg/CanFrame              every frame the host was fed
//   /joint_states       sensor_msgs/msg/JointState          the robot's pose after each state
//
// plus the files it ran with (skin map, URDF, design and unit files) as attachments and a "skinbus"
// metadata record (the run's options and models). The CAN frames are what a recording is replayed
// from: the host's input exactly (skinbus-mcap candump, with McapJointInput for the joint states),
// so a session can be estimated again with another model.
//
// Times: a message's log time is when the host had it (a frame's or sample's receive time; for
// a publication or status, the newest receive time seen, never before its stamp), in ns of the
// host's clock (a log's time in a fast replay); header stamps as on the DDS topics.
//
// The recorder is the host's InputTap (give it in AggregatorOptions::tap) and is handed the
// loop's publications by the tool's sink. A write that fails (a full disk) stops the recording,
// not the host: the error is kept (error()), later messages are counted as dropped. Cost: one
// CDR encoding and a copy into the open chunk per message; no allocation once the buffers have
// grown. Not thread-safe: call it on the host loop's thread.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "skinbus/body_map/robot_model.h"
#include "skinbus/common/result.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/contacts.h"
#include "skinbus/host/host_loop.h"
#include "skinbus/record/mcap.h"
#include "skinbus/record/ros2_messages.h"

namespace skinbus::record {

// The channels' topics.
inline constexpr const char* kContactsTopic = "/skin/contacts";
inline constexpr const char* kPatchStatusTopic = "/skin/patch_status";
inline constexpr const char* kDiagnosticsTopic = "/diagnostics";
inline constexpr const char* kSamplesTopic = "/skin/samples";
inline constexpr const char* kCanTopic = "/skin/can";
inline constexpr const char* kJointStatesTopic = "/joint_states";

struct RecorderOptions {
  bool samples = true;  // /skin/samples
  bool frames = true;   // /skin/can (needed to replay the recording)
  bool diagnostics = true;
  // Files stored as attachments: name in the recording -> path (read when the recorder is made).
  std::map<std::string, std::string> attachments;
  // The "skinbus" metadata record (options, models, version).
  std::map<std::string, std::string> metadata;
  std::size_t chunk_bytes = 1u << 20;
};

struct RecorderStats {
  uint64_t messages = 0;  // written
  uint64_t dropped = 0;   // not written after an error, or refused by an encoder
  uint64_t bytes = 0;     // the file's size so far
};

class Recorder : public host::InputTap {
 public:
  // Creates `path` and writes the header, schemas, channels, attachments and metadata.
  // `bus_names` name the frames' buses (host::HostLoop::bus_names); `robot` (may be null, then no
  // /joint_states) must outlive the recorder. kIo / kNotFound naming the file that failed.
  static Result<std::unique_ptr<Recorder>> create(const std::string& path,
                                                  std::vector<std::string> bus_names,
                                                  const body_map::RobotModel* robot,
                                                  RecorderOptions options = {});
  ~Recorder() override;

  // InputTap (the aggregator's inputs).
  void frame(int bus, const bus::CanFrame& frame, uint64_t rx_us) override;
  void sample(const host::PatchEntry& patch, const bus::Sample& sample, uint64_t rx_us,
              uint64_t time_us) override;
  void joint_state(std::span<const double> q, uint64_t stamp_us) override;

  // The host's publications (call from the loop's sink).
  void contacts(const host::ContactArray& contacts);
  void status(const host::PatchStatusArray& status);

  // Writes the summary and closes the file; the first error of the recording, if any.
  Status close();
  // The first error so far (Ok while recording works).
  const Status& error() const { return error_; }
  RecorderStats stats() const;

 private:
  Recorder() = default;
  void write(uint16_t channel, uint64_t log_us, uint64_t publish_us, const Status& encoded);
  uint64_t log_time_us(uint64_t stamp_us) const;

  std::unique_ptr<McapWriter> writer_;
  std::vector<std::string> bus_names_;
  const body_map::RobotModel* robot_ = nullptr;
  RecorderOptions options_;
  uint16_t contacts_ = 0, status_ = 0, diagnostics_ = 0, samples_ = 0, can_ = 0, joints_ = 0;
  uint64_t latest_rx_us_ = 0;
  std::vector<uint8_t> buf_;
  JointStateMsg joint_msg_;
  PatchSampleMsg sample_msg_;
  CanFrameMsg frame_msg_;
  Status error_;
  uint64_t dropped_ = 0;
};

// Joint states from a recording (its /joint_states channel) for a host replaying the same
// recording's frames (skinbus-mcap candump FILE | skinbus-host --replay - --joints FILE): each
// state at its own stamp moved by (run start - the recording's first frame time), fed as the run
// passes it. The states are read when made: O(states x joints) memory.
class McapJointInput : public host::JointInput {
 public:
  // kNotFound / kParse naming the file; kNotFound when it has no /joint_states or /skin/can.
  static Result<std::unique_ptr<McapJointInput>> load(const std::string& path);
  void update(host::Aggregator& agg, uint64_t now_us, uint64_t run_start_us) override;
  std::size_t states() const { return states_.size(); }

 private:
  McapJointInput() = default;
  std::vector<JointStateMsg> states_;
  uint64_t first_frame_us_ = 0;
  std::size_t next_ = 0;
};

}  // namespace skinbus::record
