// skinbus/dds/dds.h: the aggregator's DDS topics, over Eclipse Cyclone DDS, in C++ values.
//
// The host publishes what it computes (contacts.h) on two DDS topics and reads the robot's
// joint states from a third, all named and typed as ROS 2 puts them on the wire, so a ROS 2
// node subscribes (or publishes joint states) with no bridge in between:
//
//   topic                  DDS type                                   ROS 2 name and type
//   rt/skin/contacts       skin_msgs::msg::dds_::ContactArray_        /skin/contacts
//                                                                     skin_msgs/msg/ContactArray
//   rt/skin/patch_status   skin_msgs::msg::dds_::PatchStatusArray_    /skin/patch_status
//                                                                     skin_msgs/msg/PatchStatusArray
//   rt/joint_states        sensor_msgs::msg::dds_::JointState_        /joint_states
//                                                                     sensor_msgs/msg/JointState
//
// The types are in dds/msg/*.idl (the ROS 2 package dds/msg/ros2/skin_msgs has the same
// messages as .msg files). On the wire everything is in ROS 2 units: metres, seconds, newtons,
// and times as builtin_interfaces/Time {int32 sec; uint32 nanosec} of CLOCK_REALTIME. The C++
// side keeps the units of contacts.h (millimetres, microseconds); the classes below convert both
// ways. Nothing non-finite is ever published: publish() refuses such a value with an error,
// and the subscribers refuse received samples that would give one.
//
// QoS (the same as the defaults of a ROS 2 publisher and subscription, so that a default ROS 2
// subscription matches every skinbus writer and a default ROS 2 publisher every skinbus reader):
//   rt/skin/contacts       reliable, volatile, keep-last `history_depth` (10).
//                          A late subscriber gets the contacts from then on; old contacts are
//                          of no use to it.
//   rt/skin/patch_status   reliable, TRANSIENT-LOCAL, keep-last `history_depth` (10).
//                          The writer keeps its newest `history_depth` publications for late
//                          joiners: a subscriber asking for transient-local (as SkinSubscriber
//                          does, or `ros2 topic echo --qos-durability transient_local`) gets the
//                          current status at once instead of waiting for the next change. A
//                          default (volatile) ROS 2 subscription still matches: a writer may
//                          offer more durability than a reader requests.
//   rt/joint_states        reliable, volatile, keep-last `history_depth` (10), as
//                          joint_state_broadcaster and robot_state_publisher use it. (A reliable
//                          reader does not match a best-effort joint-state publisher.)
//   Writers send plain CDR (XCDR1), as ROS 2's rmw_cyclonedds_cpp and rmw_fastrtps_cpp do.
//   A reliable writer blocks in publish() at most `max_blocking_ms` when a slow subscriber has
//   not acknowledged enough data; then publish() gives kUnavailable and the sample is dropped.
//
// Each object owns one DDS domain participant (and, through it, its topics, readers, writers
// and waitsets); the destructor deletes them. The network configuration is Cyclone DDS's:
// CYCLONEDDS_URI (e.g. interfaces, peers; see docs/dds.md). ROS_DOMAIN_ID is not read.
// Objects are not thread-safe unless a method says so: use each from one thread at a time.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/host/contacts.h"
#include "skinbus/host/diagnostics.h"

namespace skinbus::dds {

// The domain id meaning "the one CYCLONEDDS_URI configures, else 0" (Cyclone's
// DDS_DOMAIN_DEFAULT).
inline constexpr uint32_t kDdsDomainDefault = 0xFFFFFFFFu;

struct DdsOptions {
  // DDS domain, 0..232 (the range Cyclone's default port mapping allows), or kDdsDomainDefault.
  // ROS 2 uses ROS_DOMAIN_ID here (0 when unset); pass it explicitly to share a ROS 2 domain.
  uint32_t domain_id = kDdsDomainDefault;
  // DDS topic names (ROS 2 name /x/y is DDS topic rt/x/y).
  std::string contacts_topic = "rt/skin/contacts";
  std::string patch_status_topic = "rt/skin/patch_status";
  std::string joint_states_topic = "rt/joint_states";
  // Each patch's health as diagnostic_msgs/DiagnosticArray (host/diagnostics.h), written with
  // every patch status; ROS 2 tools read /diagnostics. Empty: not published.
  std::string diagnostics_topic = "rt/diagnostics";
  // Keep-last depth of every reader and writer (ROS 2's default is 10). >= 1.
  int history_depth = 10;
  // How long publish() may block on a reliable subscriber that lags, ms (>= 0).
  int max_blocking_ms = 10;
};

// Puts the skin topics under a ROS 2 namespace: "arm_left" gives rt/arm_left/skin/contacts and
// rt/arm_left/skin/patch_status (ROS 2: /arm_left/skin/...), so several hosts share a domain
// (docs/guides/scaling.md). rt/joint_states and rt/diagnostics are left alone: every host reads
// the robot's joint states, and ROS 2 gathers diagnostics on one topic (names tell the patches).
// The namespace is one or more names of [A-Za-z][A-Za-z0-9_]* separated by '/'; a leading or
// trailing '/' is ignored; empty leaves the options unchanged. kInvalidArgument otherwise.
Status apply_namespace(DdsOptions* options, std::string_view ns);

// The topics SkinPublisher writes and SkinSubscriber reads.
enum class SkinTopic { kContacts, kPatchStatus, kDiagnostics };

// Writes rt/skin/contacts, rt/skin/patch_status and rt/diagnostics.
class SkinPublisher {
 public:
  // Creates the participant, topics and writers. Errors name the DDS call that failed.
  static Result<std::unique_ptr<SkinPublisher>> create(const DdsOptions& options);
  ~SkinPublisher();
  SkinPublisher(const SkinPublisher&) = delete;
  SkinPublisher& operator=(const SkinPublisher&) = delete;

  // Publishes one array on rt/skin/contacts: lengths mm -> m, stamp_us -> Time, base_frame ->
  // header.frame_id, first_seen_us -> first_seen (Time).
  // kInvalidArgument (nothing published) when a number is not finite, naming it; kOutOfRange
  // when stamp_us does not fit builtin_interfaces/Time (after 2038-01-19); kUnavailable when a
  // reliable subscriber lagged for max_blocking_ms.
  Status publish(const host::ContactArray& contacts);
  // Publishes on rt/skin/patch_status (transient-local: late joiners get it too): us -> s for
  // clock_offset_us, times -> Time, state and event kind as number and name. Errors as above.
  // Then, unless diagnostics_topic is empty, the same patches' health (host::diagnose) on
  // rt/diagnostics as diagnostic_msgs/DiagnosticArray (volatile, as ROS 2's diagnostics).
  Status publish(const host::PatchStatusArray& status);

  // Readers currently matched on `topic` (local and remote).
  Result<uint32_t> matched_subscribers(SkinTopic topic) const;

 private:
  SkinPublisher() = default;
  DdsOptions options_;
  int32_t participant_ = 0;  // dds_entity_t; owns everything below
  int32_t contacts_writer_ = 0;
  int32_t status_writer_ = 0;
  int32_t diagnostics_writer_ = 0;  // 0 when diagnostics_topic is empty
};

// Reads rt/skin/contacts and rt/skin/patch_status and converts back to contacts.h units
// (skinbus-listen and the tests; the aggregator itself only publishes).
class SkinSubscriber {
 public:
  static Result<std::unique_ptr<SkinSubscriber>> create(const DdsOptions& options);
  ~SkinSubscriber();
  SkinSubscriber(const SkinSubscriber&) = delete;
  SkinSubscriber& operator=(const SkinSubscriber&) = delete;

  // Waits up to `timeout_ms` (0: do not wait; < 0: forever) for the oldest contact array not
  // yet taken and moves it into *out: true when one was taken, false on timeout (*out
  // untouched). Samples come in the order they were published; when the caller falls
  // `history_depth` arrays behind, the oldest are lost. kParse / kOutOfRange: the sample taken
  // was malformed (e.g. a non-finite number, an unknown state from a foreign publisher) and is
  // dropped; the next call goes on with the next one. Other codes: DDS failed.
  Result<bool> wait_contacts(host::ContactArray* out, int timeout_ms);
  // The same for rt/skin/patch_status (transient-local: right after create() this may return
  // publications made before this subscriber existed).
  Result<bool> wait_patch_status(host::PatchStatusArray* out, int timeout_ms);
  // The same for rt/diagnostics (kUnsupported when diagnostics_topic is empty). A level outside
  // OK..STALE from a foreign publisher is kParse.
  Result<bool> wait_diagnostics(host::DiagnosticArray* out, int timeout_ms);
  // Waits up to `timeout_ms` until either topic has a sample to take: true if one has.
  Result<bool> wait_any(int timeout_ms);

  // Waits up to `timeout_ms` (< 0: forever) until at least one writer of `topic` is matched:
  // true if one is, false on timeout.
  Result<bool> wait_for_publisher(SkinTopic topic, int timeout_ms);

 private:
  SkinSubscriber() = default;
  DdsOptions options_;
  int32_t participant_ = 0;
  int32_t contacts_reader_ = 0;
  int32_t status_reader_ = 0;
  int32_t diagnostics_reader_ = 0;   // 0 when diagnostics_topic is empty
  int32_t diagnostics_waitset_ = 0;  // diagnostics_reader_'s read condition
  int32_t diagnostics_match_waitset_ = 0;
  int32_t contacts_waitset_ = 0;        // contacts_reader_'s read condition
  int32_t status_waitset_ = 0;          // status_reader_'s read condition
  int32_t any_waitset_ = 0;             // both
  int32_t contacts_match_waitset_ = 0;  // contacts_reader_'s subscription-matched status
  int32_t status_match_waitset_ = 0;    // status_reader_'s
};

// One sensor_msgs/JointState, as JointStateSubscriber keeps it.
struct JointStateSample {
  uint64_t stamp_us = 0;     // header.stamp (CLOCK_REALTIME of the publisher, us)
  uint64_t received_us = 0;  // host CLOCK_REALTIME when it arrived here, us
  std::vector<std::string> names;
  std::vector<double> positions;  // rad or m, one per name
};

// Reads rt/joint_states in the background (a Cyclone DDS listener) and queues what arrives, up to
// kQueueMax samples (the oldest are dropped beyond that, counted).
class JointStateSubscriber {
 public:
  static constexpr std::size_t kQueueMax = 1024;  // 10 s of 100 Hz, 1 s of 1 kHz

  static Result<std::unique_ptr<JointStateSubscriber>> create(const DdsOptions& options);
  // Deletes the reader first (waiting for a running listener callback to end).
  ~JointStateSubscriber();
  JointStateSubscriber(const JointStateSubscriber&) = delete;
  JointStateSubscriber& operator=(const JointStateSubscriber&) = delete;

  // Non-blocking: moves the newest sample that arrived since the previous successful call into
  // *out and returns true; returns false (*out untouched) when none arrived since. Samples that
  // arrived in between are skipped. Thread-safe against the listener (and other callers).
  bool take_latest(JointStateSample* out);

  // Non-blocking: moves every sample that arrived since the previous take, in arrival order,
  // into *out (cleared first; its capacity is reused) and returns how many. For a consumer that
  // keeps a history of the states (skinbus-host). Thread-safe, as take_latest.
  std::size_t take_all(std::vector<JointStateSample>* out);

  // Samples dropped because kQueueMax were waiting (nobody took them in time). Thread-safe.
  uint64_t overflowed_samples() const;

  // Samples refused since create(): name and position counts differ, a position is not
  // finite, or the stamp is negative or malformed. Thread-safe.
  uint64_t rejected_samples() const;

  // Waits up to `timeout_ms` (< 0: forever) until a joint-state writer is matched.
  Result<bool> wait_for_publisher(int timeout_ms);

 private:
  JointStateSubscriber() = default;
  static void on_data_available(int32_t reader, void* self);
  void drain(int32_t reader);

  DdsOptions options_;
  int32_t participant_ = 0;
  int32_t reader_ = 0;
  int32_t match_waitset_ = 0;
  mutable std::mutex mutex_;  // guards the members below (the listener runs on DDS threads)
  std::deque<JointStateSample> queue_;  // arrived, not yet taken, oldest first
  uint64_t rejected_ = 0, overflowed_ = 0;
};

// Writes rt/joint_states (simulated scenes, tests).
class JointStatePublisher {
 public:
  static Result<std::unique_ptr<JointStatePublisher>> create(const DdsOptions& options);
  ~JointStatePublisher();
  JointStatePublisher(const JointStatePublisher&) = delete;
  JointStatePublisher& operator=(const JointStatePublisher&) = delete;

  // Publishes names and positions (rad or m; velocity and effort empty, frame_id empty) stamped
  // `stamp_us` (CLOCK_REALTIME, us). kInvalidArgument when the counts differ or a position is
  // not finite; kOutOfRange when the stamp does not fit builtin_interfaces/Time.
  Status publish(const std::vector<std::string>& names, const std::vector<double>& positions,
                 uint64_t stamp_us);

  Result<uint32_t> matched_subscribers() const;

 private:
  JointStatePublisher() = default;
  DdsOptions options_;
  int32_t participant_ = 0;
  int32_t writer_ = 0;
};

}  // namespace skinbus::dds
