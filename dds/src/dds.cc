// The DDS topics over Cyclone DDS's C API (dds.h). The C types come from dds/msg/*.idl
// through idlc; nothing of them appears in the public header.
#include "skinbus/dds/dds.h"

#include <dds/dds.h>

#include <cmath>
#include <cstdlib>
#include <limits>
#include <string_view>
#include <type_traits>

#include "ros2_common.h"
#include "skin_msgs.h"

#include "skinbus/bus/socketcan.h"

namespace skinbus::dds {

using host::BodyContact;
using host::ContactArray;
using host::DiagnosticArray;
using host::DiagnosticLevel;
using host::DiagnosticValue;
using host::kContactAmbientLarge;
using host::kContactDepthRange;
using host::kContactExtrapolated;
using host::kContactMaskedChannels;
using host::kContactMerged;
using host::kContactNoKinematics;
using host::kContactOutsidePatch;
using host::kContactShear;
using host::kContactStaleKinematics;
using host::kContactUnmapped;
using host::kContactUnrefined;
using host::PatchDiagnostic;
using host::PatchEvent;
using host::PatchEventKind;
using host::PatchLinkState;
using host::PatchStatus;
using host::PatchStatusArray;

static_assert(kDdsDomainDefault == DDS_DOMAIN_DEFAULT);
static_assert(std::is_same_v<dds_entity_t, int32_t>);

// The constants of the IDL (and so of the ROS 2 .msg files, which dds_test.cc compares with the
// IDL) are those of contacts.h.
#define SKINBUS_SAME_CONSTANT(idl_name, value) \
  static_assert((idl_name) == static_cast<uint32_t>(value), #idl_name)
SKINBUS_SAME_CONSTANT(diagnostic_msgs_msg_dds__DiagnosticStatus_Constants_OK, DiagnosticLevel::kOk);
SKINBUS_SAME_CONSTANT(diagnostic_msgs_msg_dds__DiagnosticStatus_Constants_WARN,
                      DiagnosticLevel::kWarn);
SKINBUS_SAME_CONSTANT(diagnostic_msgs_msg_dds__DiagnosticStatus_Constants_ERROR,
                      DiagnosticLevel::kError);
SKINBUS_SAME_CONSTANT(diagnostic_msgs_msg_dds__DiagnosticStatus_Constants_STALE,
                      DiagnosticLevel::kStale);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_STALE_KINEMATICS,
                      kContactStaleKinematics);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_NO_KINEMATICS,
                      kContactNoKinematics);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_MERGED, kContactMerged);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_OUTSIDE_PATCH,
                      kContactOutsidePatch);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_DEPTH_RANGE, kContactDepthRange);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_MASKED_CHANNELS,
                      kContactMaskedChannels);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_AMBIENT_LARGE,
                      kContactAmbientLarge);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_UNMAPPED, kContactUnmapped);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_UNREFINED, kContactUnrefined);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_SHEAR, kContactShear);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__Contact_Constants_FLAG_EXTRAPOLATED, kContactExtrapolated);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchStatus_Constants_STATE_DISCOVERING,
                      PatchLinkState::kDiscovering);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchStatus_Constants_STATE_ONLINE,
                      PatchLinkState::kOnline);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchStatus_Constants_STATE_DEGRADED,
                      PatchLinkState::kDegraded);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchStatus_Constants_STATE_STALE, PatchLinkState::kStale);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchStatus_Constants_STATE_OFFLINE,
                      PatchLinkState::kOffline);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_DISCOVERED,
                      PatchEventKind::kDiscovered);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_ONLINE, PatchEventKind::kOnline);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_DEGRADED,
                      PatchEventKind::kDegraded);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_STALE, PatchEventKind::kStale);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_OFFLINE,
                      PatchEventKind::kOffline);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_RETURNED,
                      PatchEventKind::kReturned);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_REBOOTED,
                      PatchEventKind::kRebooted);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_DUPLICATE_ID,
                      PatchEventKind::kDuplicateId);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_UNKNOWN_PATCH,
                      PatchEventKind::kUnknownPatch);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_NO_MODEL,
                      PatchEventKind::kNoModel);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_SEQUENCE_GAP,
                      PatchEventKind::kSequenceGap);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_BAD_FRAMES,
                      PatchEventKind::kBadFrames);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_INTERFACE_DOWN,
                      PatchEventKind::kInterfaceDown);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_INTERFACE_UP,
                      PatchEventKind::kInterfaceUp);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_KINEMATICS_STALE,
                      PatchEventKind::kKinematicsStale);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_KINEMATICS_FRESH,
                      PatchEventKind::kKinematicsFresh);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_HOST_LAGGING,
                      PatchEventKind::kHostLagging);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_HOST_CAUGHT_UP,
                      PatchEventKind::kHostCaughtUp);
SKINBUS_SAME_CONSTANT(skin_msgs_msg_dds__PatchEvent_Constants_KIND_LOG_TIME,
                      PatchEventKind::kLogTime);
#undef SKINBUS_SAME_CONSTANT

namespace {

using ContactMsg = skin_msgs_msg_dds__Contact_;
using ContactArrayMsg = skin_msgs_msg_dds__ContactArray_;
using PatchStatusMsg = skin_msgs_msg_dds__PatchStatus_;
using PatchEventMsg = skin_msgs_msg_dds__PatchEvent_;
using PatchStatusArrayMsg = skin_msgs_msg_dds__PatchStatusArray_;
using JointStateMsg = sensor_msgs_msg_dds__JointState_;
using TimeMsg = builtin_interfaces_msg_dds__Time_;
using KeyValueMsg = diagnostic_msgs_msg_dds__KeyValue_;
using DiagnosticStatusMsg = diagnostic_msgs_msg_dds__DiagnosticStatus_;
using DiagnosticArrayMsg = diagnostic_msgs_msg_dds__DiagnosticArray_;

constexpr uint8_t kPatchLinkStateMax = static_cast<uint8_t>(PatchLinkState::kOffline);
constexpr uint8_t kPatchEventKindMax = static_cast<uint8_t>(PatchEventKind::kLogTime);
constexpr double kMmPerM = 1000.0;
constexpr double kUsPerS = 1e6;

// ---- errors ------------------------------------------------------------------------------

ErrorCode code_for(dds_return_t rc) {
  switch (rc) {
    case DDS_RETCODE_BAD_PARAMETER:
    case DDS_RETCODE_INCONSISTENT_POLICY:
    case DDS_RETCODE_IMMUTABLE_POLICY:
    case DDS_RETCODE_PRECONDITION_NOT_MET:
    case DDS_RETCODE_ILLEGAL_OPERATION:
      return ErrorCode::kInvalidArgument;
    case DDS_RETCODE_TIMEOUT:
    case DDS_RETCODE_OUT_OF_RESOURCES:
    case DDS_RETCODE_TRY_AGAIN:
    case DDS_RETCODE_NO_DATA:
      return ErrorCode::kUnavailable;
    case DDS_RETCODE_UNSUPPORTED:
      return ErrorCode::kUnsupported;
    case DDS_RETCODE_ALREADY_DELETED:
    case DDS_RETCODE_NOT_ENABLED:
    case DDS_RETCODE_NOT_ALLOWED_BY_SECURITY:
      return ErrorCode::kInternal;
    default:
      return ErrorCode::kIo;  // DDS_RETCODE_ERROR: sockets, configuration, ...
  }
}

// "<what>: <Cyclone's text for rc>[ (<hint>)]".
Error dds_error(std::string_view what, dds_return_t rc, std::string_view hint = {}) {
  std::string msg(what);
  msg += ": ";
  msg += dds_strretcode(rc);
  if (!hint.empty()) {
    msg += " (";
    msg += hint;
    msg += ")";
  }
  return make_error(code_for(rc), std::move(msg));
}

std::string topic_what(std::string_view call, std::string_view topic) {
  std::string s(call);
  s += "(";
  s += topic;
  s += ")";
  return s;
}

// ---- QoS -----------------------------------------------------------------------------------

// Owns a dds_qos_t.
class Qos {
 public:
  Qos() : q_(dds_create_qos()) {}
  ~Qos() { dds_delete_qos(q_); }
  Qos(const Qos&) = delete;
  Qos& operator=(const Qos&) = delete;
  dds_qos_t* get() const { return q_; }

 private:
  dds_qos_t* q_;
};

enum class Durability { kVolatile, kTransientLocal };
enum class Side { kReader, kWriter };

// Reliable, keep-last `depth`, the given durability (see dds.h for why); writers send XCDR1.
std::unique_ptr<Qos> endpoint_qos(const DdsOptions& o, Durability d, Side side) {
  auto q = std::make_unique<Qos>();
  dds_qset_reliability(q->get(), DDS_RELIABILITY_RELIABLE, DDS_MSECS(o.max_blocking_ms));
  dds_qset_durability(q->get(), d == Durability::kTransientLocal ? DDS_DURABILITY_TRANSIENT_LOCAL
                                                                 : DDS_DURABILITY_VOLATILE);
  dds_qset_history(q->get(), DDS_HISTORY_KEEP_LAST, o.history_depth);
  if (side == Side::kWriter) {
    const dds_data_representation_id_t xcdr1 = DDS_DATA_REPRESENTATION_XCDR1;
    dds_qset_data_representation(q->get(), 1, &xcdr1);
  }
  return q;
}

Status check_options(const DdsOptions& o) {
  if (o.history_depth < 1) {
    return make_error(
        ErrorCode::kInvalidArgument,
        "DdsOptions::history_depth " + std::to_string(o.history_depth) + ": must be at least 1");
  }
  if (o.max_blocking_ms < 0) {
    return make_error(
        ErrorCode::kInvalidArgument,
        "DdsOptions::max_blocking_ms " + std::to_string(o.max_blocking_ms) + ": must be >= 0");
  }
  if (o.domain_id != kDdsDomainDefault && o.domain_id > 232) {
    return make_error(ErrorCode::kInvalidArgument,
                      "DdsOptions::domain_id " + std::to_string(o.domain_id) +
                          ": must be 0..232 (Cyclone DDS's port mapping)");
  }
  // diagnostics_topic may be empty: no diagnostics.
  for (const std::string* t : {&o.contacts_topic, &o.patch_status_topic, &o.joint_states_topic}) {
    if (t->empty()) return make_error(ErrorCode::kInvalidArgument, "DdsOptions: empty topic name");
  }
  return Status::Ok();
}

// ---- entities ------------------------------------------------------------------------------

Result<dds_entity_t> create_participant(const DdsOptions& o, const char* entity_name) {
  Qos q;
  dds_qset_entity_name(q.get(), entity_name);
  const dds_entity_t p = dds_create_participant(o.domain_id, q.get(), nullptr);
  if (p < 0) {
    const char* uri = std::getenv("CYCLONEDDS_URI");
    std::string hint = o.domain_id == kDdsDomainDefault ? std::string("default domain")
                                                        : "domain " + std::to_string(o.domain_id);
    hint += "; is another domain id configured, or is the configuration invalid? CYCLONEDDS_URI=";
    hint += uri != nullptr ? uri : "(unset)";
    return dds_error("dds_create_participant", p, hint);
  }
  return p;
}

// ---- topics ---------------------------------------------------------------------------------

enum class TopicId { kContacts, kPatchStatus, kJointStates, kDiagnostics };

// What a topic is: its type, where DdsOptions names it, the durability of its endpoints.
struct TopicSpec {
  const dds_topic_descriptor_t* type;
  std::string DdsOptions::*name;
  Durability durability;
};

// Indexed by TopicId. The patch status is transient-local: a late subscriber gets the last one.
constexpr TopicSpec kTopics[] = {
    {&skin_msgs_msg_dds__ContactArray__desc, &DdsOptions::contacts_topic, Durability::kVolatile},
    {&skin_msgs_msg_dds__PatchStatusArray__desc, &DdsOptions::patch_status_topic,
     Durability::kTransientLocal},
    {&sensor_msgs_msg_dds__JointState__desc, &DdsOptions::joint_states_topic,
     Durability::kVolatile},
    {&diagnostic_msgs_msg_dds__DiagnosticArray__desc, &DdsOptions::diagnostics_topic,
     Durability::kVolatile},
};

// Creates topic `id` (named as `o` says) on `participant` and one reader or writer of it with the
// topic's QoS (endpoint_qos); `listener` only for a reader.
Result<dds_entity_t> create_endpoint(dds_entity_t participant, const DdsOptions& o, TopicId id,
                                     Side side, const dds_listener_t* listener = nullptr) {
  const TopicSpec& spec = kTopics[static_cast<int>(id)];
  const std::string& name = o.*spec.name;
  const dds_entity_t t = dds_create_topic(participant, spec.type, name.c_str(), nullptr, nullptr);
  if (t < 0) {
    return dds_error(topic_what("dds_create_topic", name), t,
                     std::string("type ") + spec.type->m_typename +
                         "; is the name used with another type in this process?");
  }
  const std::unique_ptr<Qos> qos = endpoint_qos(o, spec.durability, side);
  if (side == Side::kWriter) {
    const dds_entity_t w = dds_create_writer(participant, t, qos->get(), nullptr);
    if (w < 0) return dds_error(topic_what("dds_create_writer", name), w);
    return w;
  }
  const dds_entity_t r = dds_create_reader(participant, t, qos->get(), listener);
  if (r < 0) return dds_error(topic_what("dds_create_reader", name), r);
  return r;
}

// What asking for rt/diagnostics gives when DdsOptions::diagnostics_topic is empty.
Error diagnostics_off() {
  return make_error(ErrorCode::kUnsupported, "diagnostics are off (empty diagnostics_topic)");
}

Result<dds_entity_t> create_waitset(dds_entity_t participant) {
  const dds_entity_t ws = dds_create_waitset(participant);
  if (ws < 0) return dds_error("dds_create_waitset", ws);
  return ws;
}

// Attaches a new read condition (any sample state) of `reader` to `waitset`.
Status attach_read_condition(dds_entity_t waitset, dds_entity_t reader, const std::string& name) {
  const dds_entity_t cond = dds_create_readcondition(reader, DDS_ANY_STATE);
  if (cond < 0) return dds_error(topic_what("dds_create_readcondition", name), cond);
  if (const dds_return_t rc = dds_waitset_attach(waitset, cond, 0); rc < 0)
    return dds_error(topic_what("dds_waitset_attach", name), rc);
  return Status::Ok();
}

// Makes `reader`'s status condition trigger on subscription-matched only and attaches it.
Status attach_match_status(dds_entity_t waitset, dds_entity_t reader, const std::string& name) {
  if (const dds_return_t rc = dds_set_status_mask(reader, DDS_SUBSCRIPTION_MATCHED_STATUS); rc < 0)
    return dds_error(topic_what("dds_set_status_mask", name), rc);
  if (const dds_return_t rc = dds_waitset_attach(waitset, reader, reader); rc < 0)
    return dds_error(topic_what("dds_waitset_attach", name), rc);
  return Status::Ok();
}

dds_duration_t to_duration(int timeout_ms) {
  return timeout_ms < 0 ? DDS_INFINITY : DDS_MSECS(timeout_ms);
}

// Waits on `waitset` until `deadline` (absolute, DDS clock; DDS_NEVER: forever).
Status wait_until(dds_entity_t waitset, dds_time_t deadline) {
  const dds_return_t rc = dds_waitset_wait_until(waitset, nullptr, 0, deadline);
  if (rc < 0) return dds_error("dds_waitset_wait_until", rc);
  return Status::Ok();
}

dds_time_t deadline_after(int timeout_ms) {
  return timeout_ms < 0 ? DDS_NEVER : dds_time() + to_duration(timeout_ms);
}

// Waits until `reader` has matched a writer: true, or false at the deadline.
Result<bool> wait_matched(dds_entity_t waitset, dds_entity_t reader, int timeout_ms,
                          const std::string& name) {
  const dds_time_t deadline = deadline_after(timeout_ms);
  while (true) {
    dds_subscription_matched_status_t st{};
    // Reading the status resets its trigger, so a match after this wakes the wait below.
    if (const dds_return_t rc = dds_get_subscription_matched_status(reader, &st); rc < 0)
      return dds_error(topic_what("dds_get_subscription_matched_status", name), rc);
    if (st.current_count > 0) return true;
    if (deadline != DDS_NEVER && dds_time() >= deadline) return false;
    if (Status s = wait_until(waitset, deadline); !s.ok()) return s.error();
  }
}

Result<uint32_t> matched_readers(dds_entity_t writer, const std::string& name) {
  dds_publication_matched_status_t st{};
  if (const dds_return_t rc = dds_get_publication_matched_status(writer, &st); rc < 0)
    return dds_error(topic_what("dds_get_publication_matched_status", name), rc);
  return st.current_count;
}

Status write(dds_entity_t writer, const void* sample, const std::string& name) {
  const dds_return_t rc = dds_write(writer, sample);
  if (rc == DDS_RETCODE_TIMEOUT) {
    return make_error(ErrorCode::kUnavailable,
                      topic_what("dds_write", name) +
                          ": timeout (a reliable subscriber is not keeping up; sample dropped)");
  }
  if (rc < 0) return dds_error(topic_what("dds_write", name), rc);
  return Status::Ok();
}

// Takes the loaned samples of one dds_take and returns the loan on destruction.
class Loan {
 public:
  Loan(dds_entity_t reader, int max)
      : reader_(reader),
        buf_(static_cast<std::size_t>(max)),
        info_(static_cast<std::size_t>(max)) {}
  ~Loan() {
    // Fails only on a bad reader or buffer (a bug); nothing to report it to from here.
    if (n_ > 0) dds_return_loan(reader_, buf_.data(), n_);
  }
  Loan(const Loan&) = delete;
  Loan& operator=(const Loan&) = delete;

  // dds_take: the number of samples (0: none), or a negative DDS return code.
  int32_t take() {
    n_ = dds_take(reader_, buf_.data(), info_.data(), buf_.size(),
                  static_cast<uint32_t>(buf_.size()));
    return n_;
  }
  const void* sample(int i) const { return buf_[static_cast<std::size_t>(i)]; }
  bool valid(int i) const { return info_[static_cast<std::size_t>(i)].valid_data; }

 private:
  dds_entity_t reader_;
  std::vector<void*> buf_;  // all nullptr: dds_take loans
  std::vector<dds_sample_info_t> info_;
  int32_t n_ = 0;
};

// ---- conversions: to the wire --------------------------------------------------------------

// Non-const char* into a string the writer only reads (the C types have no const).
char* c_str(const std::string& s) {
  return const_cast<char*>(s.c_str());
}

// A sequence over `v`'s elements, which the writer only reads (as c_str: no const in C types).
template <typename Seq, typename T>
void set_sequence(Seq* seq, const std::vector<T>& v) {
  seq->_maximum = static_cast<uint32_t>(v.size());
  seq->_length = static_cast<uint32_t>(v.size());
  seq->_buffer = v.empty() ? nullptr : const_cast<T*>(v.data());
  seq->_release = false;
}

// "field[index].member".
std::string field_name(std::string_view field, std::size_t index, std::string_view member) {
  return std::string(field) + "[" + std::to_string(index) + "]." + std::string(member);
}

// Collects the first non-finite value of a publication, naming it.
class FiniteCheck {
 public:
  explicit FiniteCheck(std::string_view what) : what_(what) {}
  // `name()` gives the value's name; called only when `v` is not finite.
  template <typename Name>
  void operator()(double v, const Name& name) {
    if (std::isfinite(v) || !bad_.empty()) return;
    bad_ = name() + " is " + (std::isnan(v) ? "nan" : "inf");
  }
  Status status() const {
    if (bad_.empty()) return Status::Ok();
    return make_error(ErrorCode::kInvalidArgument, what_ + ": " + bad_ + " (nothing published)");
  }

 private:
  std::string what_;
  std::string bad_;
};

Result<TimeMsg> to_time(uint64_t us, std::string_view what) {
  const uint64_t sec = us / 1000000u;
  if (sec > static_cast<uint64_t>(std::numeric_limits<int32_t>::max())) {
    return make_error(ErrorCode::kOutOfRange,
                      std::string(what) + " " + std::to_string(us) +
                          " us is beyond builtin_interfaces/Time (int32 seconds: 2038-01-19)");
  }
  TimeMsg t{};
  t.sec = static_cast<int32_t>(sec);
  t.nanosec = static_cast<uint32_t>((us % 1000000u) * 1000u);
  return t;
}

// ---- conversions: from the wire ------------------------------------------------------------

Result<uint64_t> from_time(const TimeMsg& t, std::string_view what) {
  if (t.sec < 0 || t.nanosec >= 1000000000u) {
    return make_error(ErrorCode::kOutOfRange, std::string(what) + " {sec " + std::to_string(t.sec) +
                                                  ", nanosec " + std::to_string(t.nanosec) +
                                                  "} is not a time after the epoch");
  }
  return static_cast<uint64_t>(t.sec) * 1000000u + t.nanosec / 1000u;
}

std::string from_c_str(const char* s) {
  return s != nullptr ? std::string(s) : std::string();
}

// Scales `v` and checks the result is finite (a foreign publisher may send anything).
class ScaledCheck {
 public:
  explicit ScaledCheck(std::string_view what) : what_(what) {}
  double operator()(double v, double scale, std::string_view field, std::size_t index,
                    std::string_view member) {
    const double out = v * scale;
    if (!std::isfinite(out) && bad_.empty()) {
      bad_ = field_name(field, index, member) + " is not finite (" + std::to_string(v) + ")";
    }
    return out;
  }
  Status status() const {
    if (bad_.empty()) return Status::Ok();
    return make_error(ErrorCode::kOutOfRange, what_ + ": " + bad_ + " (sample dropped)");
  }

 private:
  std::string what_;
  std::string bad_;
};

Result<ContactArray> from_msg(const ContactArrayMsg& m, const std::string& topic) {
  const std::string what = "received " + topic;
  ContactArray out;
  auto stamp = from_time(m.header.stamp, what + ": header.stamp");
  if (!stamp.ok()) return stamp.error();
  out.stamp_us = *stamp;
  out.base_frame = from_c_str(m.header.frame_id);
  out.contacts.resize(m.contacts._length);
  ScaledCheck s(what);
  for (uint32_t i = 0; i < m.contacts._length; ++i) {
    const ContactMsg& c = m.contacts._buffer[i];
    BodyContact& b = out.contacts[i];
    b.position_mm[0] = s(c.position.x, kMmPerM, "contacts", i, "position.x");
    b.position_mm[1] = s(c.position.y, kMmPerM, "contacts", i, "position.y");
    b.position_mm[2] = s(c.position.z, kMmPerM, "contacts", i, "position.z");
    b.normal[0] = s(c.normal.x, 1.0, "contacts", i, "normal.x");
    b.normal[1] = s(c.normal.y, 1.0, "contacts", i, "normal.y");
    b.normal[2] = s(c.normal.z, 1.0, "contacts", i, "normal.z");
    b.depth_mm = s(c.depth, kMmPerM, "contacts", i, "depth");
    b.force_n = s(c.force, 1.0, "contacts", i, "force");
    b.u_mm = s(c.u, kMmPerM, "contacts", i, "u");
    b.v_mm = s(c.v, kMmPerM, "contacts", i, "v");
    b.uncertainty_mm = s(c.uncertainty, kMmPerM, "contacts", i, "uncertainty");
    b.node = c.patch_id;
    b.hardware_uid = c.hardware_uid;
    b.link = from_c_str(c.link_name);
    b.track_id = c.track_id;
    b.patch_count = c.patch_count;
    b.flags = c.flags;
    auto first_seen = from_time(c.first_seen, {});  // the name only on an error
    if (!first_seen.ok()) {
      return make_error(
          first_seen.error().code,
          what + ": " + field_name("contacts", i, "first_seen") + first_seen.error().message);
    }
    b.first_seen_us = *first_seen;
    b.shear_n[0] = s(c.shear.x, 1.0, "contacts", i, "shear.x");
    b.shear_n[1] = s(c.shear.y, 1.0, "contacts", i, "shear.y");
    b.shear_n[2] = s(c.shear.z, 1.0, "contacts", i, "shear.z");
    b.shear_uncertainty_n = s(c.shear_uncertainty, 1.0, "contacts", i, "shear_uncertainty");
  }
  if (Status st = s.status(); !st.ok()) return st.error();
  return out;
}

Result<PatchStatusArray> from_msg(const PatchStatusArrayMsg& m, const std::string& topic) {
  const std::string what = "received " + topic;
  PatchStatusArray out;
  auto stamp = from_time(m.header.stamp, what + ": header.stamp");
  if (!stamp.ok()) return stamp.error();
  out.stamp_us = *stamp;
  out.patches.resize(m.patches._length);
  ScaledCheck s(what);
  for (uint32_t i = 0; i < m.patches._length; ++i) {
    const PatchStatusMsg& p = m.patches._buffer[i];
    PatchStatus& o = out.patches[i];
    if (p.state > kPatchLinkStateMax) {
      return make_error(ErrorCode::kParse, what + ": patches[" + std::to_string(i) + "].state " +
                                               std::to_string(p.state) + " is unknown");
    }
    o.node = p.node;
    o.hardware_uid = p.hardware_uid;
    o.interface = from_c_str(p.can_interface);
    o.link = from_c_str(p.link_name);
    o.state = static_cast<PatchLinkState>(p.state);
    o.node_state = p.node_state;
    o.node_mode = p.node_mode;
    o.fault_mask = p.fault_mask;
    o.uptime_s = p.uptime;
    o.reboots = p.reboots;
    o.samples = p.samples;
    o.samples_lost = p.samples_lost;
    o.contacts = p.contacts;
    o.clock_offset_us = s(p.clock_offset, kUsPerS, "patches", i, "clock_offset");
    o.clock_drift_ppm = s(p.clock_drift_ppm, 1.0, "patches", i, "clock_drift_ppm");
    auto heard = from_time(p.last_heard, what + ": patches[" + std::to_string(i) + "].last_heard");
    if (!heard.ok()) return heard.error();
    o.last_heard_us = *heard;
    o.duplicate_id = p.duplicate_id;
    o.detail = from_c_str(p.detail);
  }
  if (Status st = s.status(); !st.ok()) return st.error();
  out.events.resize(m.events._length);
  for (uint32_t i = 0; i < m.events._length; ++i) {
    const PatchEventMsg& e = m.events._buffer[i];
    PatchEvent& o = out.events[i];
    if (e.kind > kPatchEventKindMax) {
      return make_error(ErrorCode::kParse, what + ": events[" + std::to_string(i) + "].kind " +
                                               std::to_string(e.kind) + " is unknown");
    }
    auto t = from_time(e.stamp, what + ": events[" + std::to_string(i) + "].stamp");
    if (!t.ok()) return t.error();
    o.time_us = *t;
    o.kind = static_cast<PatchEventKind>(e.kind);
    o.node = e.node;
    o.hardware_uid = e.hardware_uid;
    o.detail = from_c_str(e.detail);
  }
  return out;
}

Result<DiagnosticArray> from_msg(const DiagnosticArrayMsg& m, const std::string& topic) {
  const std::string what = "received " + topic;
  DiagnosticArray out;
  auto stamp = from_time(m.header.stamp, what + ": header.stamp");
  if (!stamp.ok()) return stamp.error();
  out.stamp_us = *stamp;
  out.status.resize(m.status._length);
  for (uint32_t i = 0; i < m.status._length; ++i) {
    const DiagnosticStatusMsg& d = m.status._buffer[i];
    PatchDiagnostic& o = out.status[i];
    if (d.level > static_cast<uint8_t>(DiagnosticLevel::kStale)) {
      return make_error(ErrorCode::kParse, what + ": status[" + std::to_string(i) + "].level " +
                                               std::to_string(d.level) + " is unknown");
    }
    o.level = static_cast<DiagnosticLevel>(d.level);
    o.name = from_c_str(d.name);
    o.message = from_c_str(d.message);
    o.hardware_id = from_c_str(d.hardware_id);
    o.values.resize(d.values._length);
    for (uint32_t k = 0; k < d.values._length; ++k) {
      o.values[k] = {from_c_str(d.values._buffer[k].key), from_c_str(d.values._buffer[k].value)};
    }
  }
  return out;
}

// Takes the oldest valid sample of `reader` and converts it with from_msg: true if one was
// taken, false if the reader holds none (samples without data, e.g. "no writers", are skipped).
template <typename Msg, typename Out>
Result<bool> take_one(dds_entity_t reader, const std::string& topic, Out* out) {
  while (true) {
    Loan loan(reader, 1);
    const int32_t n = loan.take();
    if (n < 0) return dds_error(topic_what("dds_take", topic), n);
    if (n == 0) return false;
    if (!loan.valid(0)) continue;
    auto r = from_msg(*static_cast<const Msg*>(loan.sample(0)), topic);
    if (!r.ok()) return r.error();
    *out = std::move(*r);
    return true;
  }
}

// take_one, waiting on `waitset` (the reader's read condition) up to `timeout_ms`.
template <typename Msg, typename Out>
Result<bool> wait_take(dds_entity_t reader, dds_entity_t waitset, const std::string& topic,
                       Out* out, int timeout_ms) {
  const dds_time_t deadline = deadline_after(timeout_ms);
  while (true) {
    auto r = take_one<Msg>(reader, topic, out);
    if (!r.ok() || *r) return r;
    if (deadline != DDS_NEVER && dds_time() >= deadline) return false;
    if (Status s = wait_until(waitset, deadline); !s.ok()) return s.error();
  }
}

}  // namespace

// ---- SkinPublisher ---------------------------------------------------------------------------

Status apply_namespace(DdsOptions* options, std::string_view ns) {
  while (!ns.empty() && ns.front() == '/') ns.remove_prefix(1);
  while (!ns.empty() && ns.back() == '/') ns.remove_suffix(1);
  if (ns.empty()) return Status::Ok();
  bool start = true;
  for (char c : ns) {
    const bool alpha = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z');
    const bool ok = start ? alpha : (alpha || (c >= '0' && c <= '9') || c == '_' || c == '/');
    if (!ok) {
      return make_error(ErrorCode::kInvalidArgument,
                        "namespace '" + std::string(ns) +
                            "': names start with a letter and hold letters, digits and '_', "
                            "separated by '/'");
    }
    start = c == '/';
  }
  options->contacts_topic = "rt/" + std::string(ns) + "/skin/contacts";
  options->patch_status_topic = "rt/" + std::string(ns) + "/skin/patch_status";
  return Status::Ok();
}

Result<std::unique_ptr<SkinPublisher>> SkinPublisher::create(const DdsOptions& options) {
  if (Status s = check_options(options); !s.ok()) return s.error();
  std::unique_ptr<SkinPublisher> p(new SkinPublisher());
  p->options_ = options;
  auto participant = create_participant(options, "skinbus publisher");
  if (!participant.ok()) return participant.error();
  p->participant_ = *participant;

  auto contacts_writer =
      create_endpoint(p->participant_, options, TopicId::kContacts, Side::kWriter);
  if (!contacts_writer.ok()) return contacts_writer.error();
  p->contacts_writer_ = *contacts_writer;
  auto status_writer =
      create_endpoint(p->participant_, options, TopicId::kPatchStatus, Side::kWriter);
  if (!status_writer.ok()) return status_writer.error();
  p->status_writer_ = *status_writer;
  if (!options.diagnostics_topic.empty()) {
    auto w = create_endpoint(p->participant_, options, TopicId::kDiagnostics, Side::kWriter);
    if (!w.ok()) return w.error();
    p->diagnostics_writer_ = *w;
  }
  return p;
}

SkinPublisher::~SkinPublisher() {
  // Deletes everything the participant owns. A failure (only on a bad handle) has no one to go to.
  if (participant_ > 0) dds_delete(participant_);
}

Status SkinPublisher::publish(const ContactArray& contacts) {
  const std::string what = "publish(ContactArray) on " + options_.contacts_topic;
  FiniteCheck finite(what);
  for (std::size_t i = 0; i < contacts.contacts.size(); ++i) {
    const BodyContact& c = contacts.contacts[i];
    auto name = [i](const char* member, int k = -1) {
      return [=] {
        return field_name("contacts", i, member) + (k >= 0 ? "[" + std::to_string(k) + "]" : "");
      };
    };
    for (int k = 0; k < 3; ++k) {
      finite(c.position_mm[k], name("position_mm", k));
      finite(c.normal[k], name("normal", k));
    }
    finite(c.depth_mm, name("depth_mm"));
    finite(c.force_n, name("force_n"));
    finite(c.u_mm, name("u_mm"));
    finite(c.v_mm, name("v_mm"));
    finite(c.uncertainty_mm, name("uncertainty_mm"));
    for (int k = 0; k < 3; ++k) finite(c.shear_n[k], name("shear_n", k));
    finite(c.shear_uncertainty_n, name("shear_uncertainty_n"));
  }
  if (Status s = finite.status(); !s.ok()) return s;
  auto stamp = to_time(contacts.stamp_us, what + ": stamp_us");
  if (!stamp.ok()) return stamp.error();

  std::vector<ContactMsg> items(contacts.contacts.size());
  for (std::size_t i = 0; i < items.size(); ++i) {
    const BodyContact& c = contacts.contacts[i];
    ContactMsg& m = items[i];
    m.position = {c.position_mm[0] / kMmPerM, c.position_mm[1] / kMmPerM,
                  c.position_mm[2] / kMmPerM};
    m.normal = {c.normal[0], c.normal[1], c.normal[2]};
    m.depth = c.depth_mm / kMmPerM;
    m.force = c.force_n;
    m.patch_id = c.node;
    m.hardware_uid = c.hardware_uid;
    m.link_name = c_str(c.link);
    m.u = c.u_mm / kMmPerM;
    m.v = c.v_mm / kMmPerM;
    m.uncertainty = c.uncertainty_mm / kMmPerM;
    m.track_id = c.track_id;
    m.patch_count = c.patch_count;
    m.flags = c.flags;
    auto first_seen = to_time(c.first_seen_us, {});  // the name only on an error
    if (!first_seen.ok()) {
      return make_error(
          first_seen.error().code,
          what + ": " + field_name("contacts", i, "first_seen_us") + first_seen.error().message);
    }
    m.first_seen = *first_seen;
    m.shear = {c.shear_n[0], c.shear_n[1], c.shear_n[2]};
    m.shear_uncertainty = c.shear_uncertainty_n;
    double force[3], torque[3];
    contact_wrench(c, force, torque);
    m.wrench.force = {force[0], force[1], force[2]};
    m.wrench.torque = {torque[0], torque[1], torque[2]};
  }
  ContactArrayMsg msg{};
  msg.header.stamp = *stamp;
  msg.header.frame_id = c_str(contacts.base_frame);
  set_sequence(&msg.contacts, items);
  return write(contacts_writer_, &msg, options_.contacts_topic);
}

Status SkinPublisher::publish(const PatchStatusArray& status) {
  const std::string what = "publish(PatchStatusArray) on " + options_.patch_status_topic;
  FiniteCheck finite(what);
  for (std::size_t i = 0; i < status.patches.size(); ++i) {
    finite(status.patches[i].clock_offset_us,
           [i] { return field_name("patches", i, "clock_offset_us"); });
    finite(status.patches[i].clock_drift_ppm,
           [i] { return field_name("patches", i, "clock_drift_ppm"); });
  }
  if (Status s = finite.status(); !s.ok()) return s;
  auto stamp = to_time(status.stamp_us, what + ": stamp_us");
  if (!stamp.ok()) return stamp.error();

  // The names must outlive the write: keep them here.
  std::vector<std::string> names;
  names.reserve(status.patches.size() + status.events.size());
  std::vector<PatchStatusMsg> patches(status.patches.size());
  for (std::size_t i = 0; i < patches.size(); ++i) {
    const PatchStatus& p = status.patches[i];
    PatchStatusMsg& m = patches[i];
    auto heard =
        to_time(p.last_heard_us, what + ": patches[" + std::to_string(i) + "].last_heard_us");
    if (!heard.ok()) return heard.error();
    names.emplace_back(patch_link_state_name(p.state));
    m.node = p.node;
    m.hardware_uid = p.hardware_uid;
    m.can_interface = c_str(p.interface);
    m.link_name = c_str(p.link);
    m.state = static_cast<uint8_t>(p.state);
    m.state_name = c_str(names.back());
    m.node_state = p.node_state;
    m.node_mode = p.node_mode;
    m.fault_mask = p.fault_mask;
    m.uptime = p.uptime_s;
    m.reboots = p.reboots;
    m.samples = p.samples;
    m.samples_lost = p.samples_lost;
    m.contacts = p.contacts;
    m.clock_offset = p.clock_offset_us / kUsPerS;
    m.clock_drift_ppm = p.clock_drift_ppm;
    m.last_heard = *heard;
    m.duplicate_id = p.duplicate_id;
    m.detail = c_str(p.detail);
  }
  std::vector<PatchEventMsg> events(status.events.size());
  for (std::size_t i = 0; i < events.size(); ++i) {
    const PatchEvent& e = status.events[i];
    PatchEventMsg& m = events[i];
    auto t = to_time(e.time_us, what + ": events[" + std::to_string(i) + "].time_us");
    if (!t.ok()) return t.error();
    names.emplace_back(patch_event_name(e.kind));
    m.stamp = *t;
    m.kind = static_cast<uint8_t>(e.kind);
    m.kind_name = c_str(names.back());
    m.node = e.node;
    m.hardware_uid = e.hardware_uid;
    m.detail = c_str(e.detail);
  }
  static const std::string kEmpty;
  PatchStatusArrayMsg msg{};
  msg.header.stamp = *stamp;
  msg.header.frame_id = c_str(kEmpty);
  set_sequence(&msg.patches, patches);
  set_sequence(&msg.events, events);
  if (Status st = write(status_writer_, &msg, options_.patch_status_topic); !st.ok()) return st;
  if (diagnostics_writer_ == 0) return Status::Ok();

  // The patches' health: the strings live in `health` until the write returns.
  const DiagnosticArray health = diagnose(status);
  std::vector<std::vector<KeyValueMsg>> values(health.status.size());
  std::vector<DiagnosticStatusMsg> items(health.status.size());
  for (std::size_t i = 0; i < items.size(); ++i) {
    const PatchDiagnostic& d = health.status[i];
    for (const DiagnosticValue& v : d.values) values[i].push_back({c_str(v.key), c_str(v.value)});
    items[i].level = static_cast<uint8_t>(d.level);
    items[i].name = c_str(d.name);
    items[i].message = c_str(d.message);
    items[i].hardware_id = c_str(d.hardware_id);
    set_sequence(&items[i].values, values[i]);
  }
  DiagnosticArrayMsg diag{};
  diag.header.stamp = *stamp;
  diag.header.frame_id = c_str(kEmpty);
  set_sequence(&diag.status, items);
  return write(diagnostics_writer_, &diag, options_.diagnostics_topic);
}

Result<uint32_t> SkinPublisher::matched_subscribers(SkinTopic topic) const {
  switch (topic) {
    case SkinTopic::kContacts:
      return matched_readers(contacts_writer_, options_.contacts_topic);
    case SkinTopic::kPatchStatus:
      return matched_readers(status_writer_, options_.patch_status_topic);
    case SkinTopic::kDiagnostics:
      break;
  }
  if (diagnostics_writer_ == 0) {
    return diagnostics_off();
  }
  return matched_readers(diagnostics_writer_, options_.diagnostics_topic);
}

// ---- SkinSubscriber --------------------------------------------------------------------------

Result<std::unique_ptr<SkinSubscriber>> SkinSubscriber::create(const DdsOptions& options) {
  if (Status s = check_options(options); !s.ok()) return s.error();
  std::unique_ptr<SkinSubscriber> p(new SkinSubscriber());
  p->options_ = options;
  auto participant = create_participant(options, "skinbus subscriber");
  if (!participant.ok()) return participant.error();
  p->participant_ = *participant;

  auto contacts_reader =
      create_endpoint(p->participant_, options, TopicId::kContacts, Side::kReader);
  if (!contacts_reader.ok()) return contacts_reader.error();
  p->contacts_reader_ = *contacts_reader;
  auto status_reader =
      create_endpoint(p->participant_, options, TopicId::kPatchStatus, Side::kReader);
  if (!status_reader.ok()) return status_reader.error();
  p->status_reader_ = *status_reader;

  for (int32_t* ws : {&p->contacts_waitset_, &p->status_waitset_, &p->any_waitset_,
                      &p->contacts_match_waitset_, &p->status_match_waitset_}) {
    auto w = create_waitset(p->participant_);
    if (!w.ok()) return w.error();
    *ws = *w;
  }
  for (Status s :
       {attach_read_condition(p->contacts_waitset_, p->contacts_reader_, options.contacts_topic),
        attach_read_condition(p->status_waitset_, p->status_reader_, options.patch_status_topic),
        attach_read_condition(p->any_waitset_, p->contacts_reader_, options.contacts_topic),
        attach_read_condition(p->any_waitset_, p->status_reader_, options.patch_status_topic),
        attach_match_status(p->contacts_match_waitset_, p->contacts_reader_,
                            options.contacts_topic),
        attach_match_status(p->status_match_waitset_, p->status_reader_,
                            options.patch_status_topic)}) {
    if (!s.ok()) return s.error();
  }
  if (!options.diagnostics_topic.empty()) {
    auto r = create_endpoint(p->participant_, options, TopicId::kDiagnostics, Side::kReader);
    if (!r.ok()) return r.error();
    p->diagnostics_reader_ = *r;
    for (int32_t* ws : {&p->diagnostics_waitset_, &p->diagnostics_match_waitset_}) {
      auto w = create_waitset(p->participant_);
      if (!w.ok()) return w.error();
      *ws = *w;
    }
    for (Status s : {attach_read_condition(p->diagnostics_waitset_, p->diagnostics_reader_,
                                           options.diagnostics_topic),
                     attach_match_status(p->diagnostics_match_waitset_, p->diagnostics_reader_,
                                         options.diagnostics_topic)}) {
      if (!s.ok()) return s.error();
    }
  }
  return p;
}

SkinSubscriber::~SkinSubscriber() {
  // Deletes everything the participant owns. A failure (only on a bad handle) has no one to go to.
  if (participant_ > 0) dds_delete(participant_);
}

Result<bool> SkinSubscriber::wait_contacts(ContactArray* out, int timeout_ms) {
  return wait_take<ContactArrayMsg>(contacts_reader_, contacts_waitset_, options_.contacts_topic,
                                    out, timeout_ms);
}

Result<bool> SkinSubscriber::wait_patch_status(PatchStatusArray* out, int timeout_ms) {
  return wait_take<PatchStatusArrayMsg>(status_reader_, status_waitset_,
                                        options_.patch_status_topic, out, timeout_ms);
}

Result<bool> SkinSubscriber::wait_diagnostics(DiagnosticArray* out, int timeout_ms) {
  if (diagnostics_reader_ == 0) {
    return diagnostics_off();
  }
  return wait_take<DiagnosticArrayMsg>(diagnostics_reader_, diagnostics_waitset_,
                                       options_.diagnostics_topic, out, timeout_ms);
}

Result<bool> SkinSubscriber::wait_any(int timeout_ms) {
  const dds_return_t rc = dds_waitset_wait(any_waitset_, nullptr, 0, to_duration(timeout_ms));
  if (rc < 0) return dds_error("dds_waitset_wait", rc);
  return rc > 0;
}

Result<bool> SkinSubscriber::wait_for_publisher(SkinTopic topic, int timeout_ms) {
  switch (topic) {
    case SkinTopic::kContacts:
      return wait_matched(contacts_match_waitset_, contacts_reader_, timeout_ms,
                          options_.contacts_topic);
    case SkinTopic::kPatchStatus:
      return wait_matched(status_match_waitset_, status_reader_, timeout_ms,
                          options_.patch_status_topic);
    case SkinTopic::kDiagnostics:
      break;
  }
  if (diagnostics_reader_ == 0) {
    return diagnostics_off();
  }
  return wait_matched(diagnostics_match_waitset_, diagnostics_reader_, timeout_ms,
                      options_.diagnostics_topic);
}

// ---- JointStateSubscriber --------------------------------------------------------------------

namespace {

// A listener owned here; Cyclone copies it into the reader.
class Listener {
 public:
  explicit Listener(void* arg) : l_(dds_create_listener(arg)) {}
  ~Listener() { dds_delete_listener(l_); }
  Listener(const Listener&) = delete;
  Listener& operator=(const Listener&) = delete;
  dds_listener_t* get() const { return l_; }

 private:
  dds_listener_t* l_;
};

}  // namespace

Result<std::unique_ptr<JointStateSubscriber>> JointStateSubscriber::create(
    const DdsOptions& options) {
  if (Status s = check_options(options); !s.ok()) return s.error();
  std::unique_ptr<JointStateSubscriber> p(new JointStateSubscriber());
  p->options_ = options;
  auto participant = create_participant(options, "skinbus joint states");
  if (!participant.ok()) return participant.error();
  p->participant_ = *participant;

  Listener listener(p.get());  // the object outlives the reader (the destructor deletes it)
  dds_lset_data_available(listener.get(), &JointStateSubscriber::on_data_available);
  auto reader = create_endpoint(p->participant_, options, TopicId::kJointStates, Side::kReader,
                                listener.get());
  if (!reader.ok()) return reader.error();
  p->reader_ = *reader;
  auto ws = create_waitset(p->participant_);
  if (!ws.ok()) return ws.error();
  p->match_waitset_ = *ws;
  if (Status s = attach_match_status(p->match_waitset_, p->reader_, options.joint_states_topic);
      !s.ok())
    return s.error();
  return p;
}

JointStateSubscriber::~JointStateSubscriber() {
  // dds_delete waits for a listener callback in progress, so `this` stays valid for it.
  if (participant_ > 0) dds_delete(participant_);
}

void JointStateSubscriber::on_data_available(int32_t reader, void* self) {
  static_cast<JointStateSubscriber*>(self)->drain(reader);
}

void JointStateSubscriber::drain(int32_t reader) {
  const uint64_t now_us = bus::realtime_now_us();
  std::vector<JointStateSample> got;
  uint64_t rejected = 0;
  while (true) {
    Loan loan(reader, 16);
    const int32_t n = loan.take();
    if (n <= 0) break;  // nothing left (a failing take cannot be reported from here)
    for (int i = 0; i < n; ++i) {
      if (!loan.valid(i)) continue;
      const auto& m = *static_cast<const JointStateMsg*>(loan.sample(i));
      auto stamp = from_time(m.header.stamp, "joint state");
      bool ok = stamp.ok() && m.name._length == m.position._length;
      for (uint32_t k = 0; ok && k < m.position._length; ++k)
        ok = std::isfinite(m.position._buffer[k]);
      if (!ok) {
        ++rejected;
        continue;
      }
      JointStateSample& js = got.emplace_back();
      js.stamp_us = *stamp;
      js.received_us = now_us;
      js.names.resize(m.name._length);
      for (uint32_t k = 0; k < m.name._length; ++k) js.names[k] = from_c_str(m.name._buffer[k]);
      js.positions.assign(m.position._buffer, m.position._buffer + m.position._length);
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  rejected_ += rejected;
  for (JointStateSample& js : got) {
    if (queue_.size() >= kQueueMax) {
      queue_.pop_front();
      ++overflowed_;
    }
    queue_.push_back(std::move(js));
  }
}

bool JointStateSubscriber::take_latest(JointStateSample* out) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (queue_.empty()) return false;
  *out = std::move(queue_.back());
  queue_.clear();
  return true;
}

std::size_t JointStateSubscriber::take_all(std::vector<JointStateSample>* out) {
  out->clear();
  std::lock_guard<std::mutex> lock(mutex_);
  for (JointStateSample& js : queue_) out->push_back(std::move(js));
  queue_.clear();
  return out->size();
}

uint64_t JointStateSubscriber::overflowed_samples() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return overflowed_;
}

uint64_t JointStateSubscriber::rejected_samples() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return rejected_;
}

Result<bool> JointStateSubscriber::wait_for_publisher(int timeout_ms) {
  return wait_matched(match_waitset_, reader_, timeout_ms, options_.joint_states_topic);
}

// ---- JointStatePublisher ---------------------------------------------------------------------

Result<std::unique_ptr<JointStatePublisher>> JointStatePublisher::create(
    const DdsOptions& options) {
  if (Status s = check_options(options); !s.ok()) return s.error();
  std::unique_ptr<JointStatePublisher> p(new JointStatePublisher());
  p->options_ = options;
  auto participant = create_participant(options, "skinbus joint state publisher");
  if (!participant.ok()) return participant.error();
  p->participant_ = *participant;
  auto writer = create_endpoint(p->participant_, options, TopicId::kJointStates, Side::kWriter);
  if (!writer.ok()) return writer.error();
  p->writer_ = *writer;
  return p;
}

JointStatePublisher::~JointStatePublisher() {
  // Deletes everything the participant owns. A failure (only on a bad handle) has no one to go to.
  if (participant_ > 0) dds_delete(participant_);
}

Status JointStatePublisher::publish(const std::vector<std::string>& names,
                                    const std::vector<double>& positions, uint64_t stamp_us) {
  const std::string what = "publish(JointState) on " + options_.joint_states_topic;
  if (names.size() != positions.size()) {
    return make_error(ErrorCode::kInvalidArgument,
                      what + ": " + std::to_string(names.size()) + " names but " +
                          std::to_string(positions.size()) + " positions");
  }
  FiniteCheck finite(what);
  for (std::size_t i = 0; i < positions.size(); ++i) {
    finite(positions[i], [&] { return "position[" + std::to_string(i) + "] (" + names[i] + ")"; });
  }
  if (Status s = finite.status(); !s.ok()) return s;
  auto stamp = to_time(stamp_us, what + ": stamp_us");
  if (!stamp.ok()) return stamp.error();

  std::vector<char*> name_ptrs(names.size());
  for (std::size_t i = 0; i < names.size(); ++i) name_ptrs[i] = c_str(names[i]);
  std::vector<double> none;
  static const std::string kEmpty;
  JointStateMsg msg{};
  msg.header.stamp = *stamp;
  msg.header.frame_id = c_str(kEmpty);
  set_sequence(&msg.name, name_ptrs);
  set_sequence(&msg.position, positions);
  set_sequence(&msg.velocity, none);
  set_sequence(&msg.effort, none);
  return write(writer_, &msg, options_.joint_states_topic);
}

Result<uint32_t> JointStatePublisher::matched_subscribers() const {
  return matched_readers(writer_, options_.joint_states_topic);
}

}  // namespace skinbus::dds
