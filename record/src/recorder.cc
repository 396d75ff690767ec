#include "skinbus/record/recorder.h"

#include <algorithm>

#include "skinbus/bus/protocol.h"
#include "skinbus/common/text_file.h"
#include "skinbus/host/diagnostics.h"

namespace skinbus::record {

namespace {

constexpr uint64_t kNsPerUs = 1000;
constexpr double kMmPerM = 1000.0;

// The offered QoS rosbag2 stores per channel, as the DDS topics use it (docs/dds.md).
std::map<std::string, std::string> qos_metadata(bool transient_local) {
  const std::string durability = transient_local ? "transient_local" : "volatile";
  return {
      {"offered_qos_profiles",
       "- history: keep_last\n  depth: 1\n  reliability: reliable\n  durability: " + durability +
           "\n  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
           "  liveliness: automatic\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
           "  avoid_ros_namespace_conventions: false\n"}};
}

}  // namespace

Result<std::unique_ptr<Recorder>> Recorder::create(const std::string& path,
                                                   std::vector<std::string> bus_names,
                                                   const body_map::RobotModel* robot,
                                                   RecorderOptions options) {
  // The attachments first: a file that cannot be read leaves no recording behind.
  std::vector<std::pair<std::string, std::string>> files;
  for (const auto& [name, file] : options.attachments) {
    auto text = read_text_file(file, "attachment");
    if (!text.ok()) return text.error();
    files.emplace_back(name, std::move(*text));
  }
  McapWriterOptions wo;
  wo.chunk_bytes = options.chunk_bytes;
  auto w = McapWriter::create(path, wo);
  if (!w.ok()) return w.error();
  std::unique_ptr<Recorder> r(new Recorder());
  r->writer_ = std::move(*w);
  r->bus_names_ = std::move(bus_names);
  r->robot_ = robot;
  r->options_ = std::move(options);
  McapWriter& mw = *r->writer_;
  auto channel = [&](const char* type, const char* topic,
                     bool transient_local) -> Result<uint16_t> {
    auto schema = ros2_schema(type);
    if (!schema.ok()) return schema.error();
    const uint16_t id = mw.add_schema(
        type, "ros2msg",
        std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(schema->data()), schema->size()));
    return mw.add_channel(id, topic, "cdr", qos_metadata(transient_local));
  };
  struct Want {
    const char* type;
    const char* topic;
    bool transient_local;
    bool on;
    uint16_t* id;
  };
  const Want wants[] = {
      {"skin_msgs/msg/ContactArray", kContactsTopic, false, true, &r->contacts_},
      {"skin_msgs/msg/PatchStatusArray", kPatchStatusTopic, true, true, &r->status_},
      {"diagnostic_msgs/msg/DiagnosticArray", kDiagnosticsTopic, false, r->options_.diagnostics,
       &r->diagnostics_},
      {"skin_msgs/msg/PatchSample", kSamplesTopic, false, r->options_.samples, &r->samples_},
      {"skin_msgs/msg/CanFrame", kCanTopic, false, r->options_.frames, &r->can_},
      {"sensor_msgs/msg/JointState", kJointStatesTopic, false, robot != nullptr, &r->joints_},
  };
  for (const Want& want : wants) {
    if (!want.on) continue;
    auto id = channel(want.type, want.topic, want.transient_local);
    if (!id.ok()) return id.error();
    *want.id = *id;
  }
  for (const auto& [name, text] : files) {
    const std::string media = name.ends_with(".urdf")   ? "application/xml"
                              : name.ends_with(".json") ? "application/json"
                                                        : "application/yaml";
    if (Status st = mw.write_attachment(
            name, media,
            std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()), 0,
            0);
        !st.ok()) {
      return st.error();
    }
  }
  if (!r->options_.metadata.empty()) {
    if (Status st = mw.write_metadata("skinbus", r->options_.metadata); !st.ok()) {
      return st.error();
    }
  }
  if (robot != nullptr) {
    for (int j = 0; j < robot->joint_count(); ++j) {
      r->joint_msg_.names.push_back(robot->joint_name(j));
    }
  }
  return r;
}

Recorder::~Recorder() = default;

uint64_t Recorder::log_time_us(uint64_t stamp_us) const {
  return std::max(stamp_us, latest_rx_us_);
}

void Recorder::write(uint16_t channel, uint64_t log_us, uint64_t publish_us,
                     const Status& encoded) {
  if (channel == 0) return;
  if (!error_.ok() || !encoded.ok()) {
    if (error_.ok()) error_ = encoded;  // an encoder's refusal: reported, the recording goes on
    ++dropped_;
    return;
  }
  Status st = writer_->write_message(channel, log_us * kNsPerUs, publish_us * kNsPerUs, buf_);
  if (!st.ok()) {
    error_ = st;
    ++dropped_;
  }
}

void Recorder::frame(int bus, const bus::CanFrame& frame, uint64_t rx_us) {
  latest_rx_us_ = std::max(latest_rx_us_, rx_us);
  if (can_ == 0) return;
  frame_msg_.rx_us = rx_us;
  frame_msg_.interface =
      bus >= 0 && static_cast<std::size_t>(bus) < bus_names_.size() ? bus_names_[bus] : "can0";
  frame_msg_.frame = frame;
  write(can_, rx_us, rx_us, encode(frame_msg_, &buf_));
}

void Recorder::sample(const host::PatchEntry& patch, const bus::Sample& sample, uint64_t rx_us,
                      uint64_t time_us) {
  latest_rx_us_ = std::max(latest_rx_us_, rx_us);
  if (samples_ == 0) return;
  PatchSampleMsg& m = sample_msg_;
  m.stamp_us = time_us;
  m.link = patch.placement != nullptr ? patch.placement->link : std::string();
  m.node = patch.node;
  m.hardware_uid = patch.hardware_uid;
  m.patch_time_us = sample.timestamp_us;
  m.flags = sample.flags;
  m.fault_mask = sample.fault_mask;
  m.saturation_mask = sample.saturation_mask;
  m.field_ut.resize(sample.field_lsb.size());
  for (std::size_t i = 0; i < sample.field_lsb.size(); ++i) {
    m.field_ut[i] = static_cast<float>(sample.field_lsb[i] * bus::kFieldUtPerLsb);
  }
  write(samples_, rx_us, time_us, encode(m, &buf_));
}

void Recorder::joint_state(std::span<const double> q, uint64_t stamp_us) {
  if (joints_ == 0 || robot_ == nullptr) return;
  JointStateMsg& m = joint_msg_;
  m.stamp_us = stamp_us;
  m.positions.resize(m.names.size());
  for (std::size_t j = 0; j < m.names.size() && j < q.size(); ++j) {
    const bool prismatic = robot_->joint_is_prismatic(static_cast<int>(j));
    m.positions[j] = prismatic ? q[j] / kMmPerM : q[j];
  }
  write(joints_, log_time_us(stamp_us), stamp_us, encode(m, &buf_));
}

void Recorder::contacts(const host::ContactArray& contacts) {
  write(contacts_, log_time_us(contacts.stamp_us), contacts.stamp_us, encode(contacts, &buf_));
}

void Recorder::status(const host::PatchStatusArray& status) {
  const uint64_t log_us = log_time_us(status.stamp_us);
  write(status_, log_us, status.stamp_us, encode(status, &buf_));
  if (diagnostics_ != 0) {
    write(diagnostics_, log_us, status.stamp_us, encode(host::diagnose(status), &buf_));
  }
}

Status Recorder::close() {
  if (!writer_) return error_;
  Status st = writer_->close();
  if (error_.ok() && !st.ok()) error_ = st;
  return error_;
}

RecorderStats Recorder::stats() const {
  RecorderStats s;
  s.messages = writer_ ? writer_->message_count() : 0;
  s.dropped = dropped_;
  s.bytes = writer_ ? writer_->bytes_written() : 0;
  return s;
}

// ---- McapJointInput --------------------------------------------------------------------------

Result<std::unique_ptr<McapJointInput>> McapJointInput::load(const std::string& path) {
  auto reader = McapReader::open(path);
  if (!reader.ok()) return reader.error();
  std::unique_ptr<McapJointInput> in(new McapJointInput());
  McapMessage m;
  bool have_frame = false;
  for (;;) {
    auto more = (*reader)->next(&m);
    if (!more.ok()) return more.error();
    if (!*more) break;
    const std::string& topic = (*reader)->channels().at(m.channel_id).topic;
    if (topic == kCanTopic && !have_frame) {
      auto f = decode_can_frame(m.data);
      if (!f.ok()) return make_error(f.error().code, path + ": " + f.error().message);
      in->first_frame_us_ = f->rx_us;
      have_frame = true;
    } else if (topic == kJointStatesTopic) {
      auto j = decode_joint_state(m.data);
      if (!j.ok()) return make_error(j.error().code, path + ": " + j.error().message);
      in->states_.push_back(std::move(*j));
    }
  }
  if (!have_frame || in->states_.empty()) {
    return make_error(ErrorCode::kNotFound,
                      path + ": no " + std::string(have_frame ? kJointStatesTopic : kCanTopic) +
                          " messages (recorded without a robot, or without frames)");
  }
  return in;
}

void McapJointInput::update(host::Aggregator& agg, uint64_t now_us, uint64_t run_start_us) {
  // Recorded time t runs as run_start + (t - first frame).
  for (; next_ < states_.size(); ++next_) {
    const JointStateMsg& s = states_[next_];
    const int64_t shifted =
        static_cast<int64_t>(run_start_us) +
        (static_cast<int64_t>(s.stamp_us) - static_cast<int64_t>(first_frame_us_));
    if (shifted > static_cast<int64_t>(now_us)) break;
    if (shifted < 0) continue;
    agg.set_joint_state(s.names, s.positions, static_cast<uint64_t>(shifted),
                        /*prismatic_in_metres=*/true);
  }
}

}  // namespace skinbus::record
