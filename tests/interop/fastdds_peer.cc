// fastdds_peer: a second DDS implementation (eProsima Fast DDS, ROS 2's default middleware) as
// the project's peer. Its types are written here by hand from the ROS 2 message files
// (dds/msg/ros2/skin_msgs/msg/*.msg and ROS 2's std_msgs, builtin_interfaces, geometry_msgs,
// sensor_msgs definitions), serialized with Fast CDR: nothing of the project's IDL or code.
//
//   fastdds_peer listen DOMAIN COUNT TIMEOUT_S
//       subscribes to rt/skin/contacts, rt/skin/patch_status (reliable; the status transient
//       local) and rt/diagnostics, and prints each sample as one JSON line (SI units as on the
//       wire); exits 0 after COUNT contact arrays, one patch status and one diagnostic array, 1
//       on timeout.
//   fastdds_peer joints DOMAIN SECONDS NAME=POSITION...
//       publishes sensor_msgs/JointState on rt/joint_states at 50 Hz for SECONDS, stamped with
//       CLOCK_REALTIME.
//
// Transport: UDPv4 on 127.0.0.1 only, with 127.0.0.1 as the initial peer (unicast discovery, as
// the tests configure Cyclone DDS).
#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <string>
#include <thread>
#include <vector>

namespace fdds = eprosima::fastdds::dds;
namespace frtps = eprosima::fastrtps::rtps;
using eprosima::fastcdr::Cdr;
using eprosima::fastcdr::FastBuffer;

namespace {

// ---- the messages, from their ROS 2 definitions ------------------------------------------

struct Time {  // builtin_interfaces/Time
  int32_t sec = 0;
  uint32_t nanosec = 0;
};
struct Header {  // std_msgs/Header
  Time stamp;
  std::string frame_id;
};
struct Contact {                   // skin_msgs/Contact
  double position[3] = {0, 0, 0};  // geometry_msgs/Point
  double normal[3] = {0, 0, 0};    // geometry_msgs/Vector3
  double depth = 0, force = 0;
  uint8_t patch_id = 0;
  uint64_t hardware_uid = 0;
  std::string link_name;
  double u = 0, v = 0, uncertainty = 0;
  uint32_t track_id = 0, patch_count = 0, flags = 0;
  Time first_seen;
  double shear[3] = {0, 0, 0};  // geometry_msgs/Vector3
  double shear_uncertainty = 0;
  double wrench_force[3] = {0, 0, 0}, wrench_torque[3] = {0, 0, 0};  // geometry_msgs/Wrench
};
struct ContactArray {  // skin_msgs/ContactArray
  Header header;
  std::vector<Contact> contacts;
};
struct PatchStatus {  // skin_msgs/PatchStatus
  uint8_t node = 0;
  uint64_t hardware_uid = 0;
  std::string can_interface, link_name;
  uint8_t state = 0;
  std::string state_name;
  uint8_t node_state = 0, node_mode = 0;
  uint16_t fault_mask = 0;
  uint32_t uptime = 0, reboots = 0;
  uint64_t samples = 0, samples_lost = 0, contacts = 0;
  double clock_offset = 0, clock_drift_ppm = 0;
  Time last_heard;
  bool duplicate_id = false;
  std::string detail;
};
struct PatchEvent {  // skin_msgs/PatchEvent
  Time stamp;
  uint8_t kind = 0;
  std::string kind_name;
  uint8_t node = 0;
  uint64_t hardware_uid = 0;
  std::string detail;
};
struct PatchStatusArray {  // skin_msgs/PatchStatusArray
  Header header;
  std::vector<PatchStatus> patches;
  std::vector<PatchEvent> events;
};
struct KeyValue {  // diagnostic_msgs/KeyValue
  std::string key, value;
};
struct DiagnosticStatus {  // diagnostic_msgs/DiagnosticStatus
  uint8_t level = 0;       // byte
  std::string name, message, hardware_id;
  std::vector<KeyValue> values;
};
struct DiagnosticArray {  // diagnostic_msgs/DiagnosticArray
  Header header;
  std::vector<DiagnosticStatus> status;
};
struct JointState {  // sensor_msgs/JointState
  Header header;
  std::vector<std::string> name;
  std::vector<double> position, velocity, effort;
};

void read(Cdr& c, Time& t) {
  c >> t.sec >> t.nanosec;
}
void read(Cdr& c, Header& h) {
  read(c, h.stamp);
  c >> h.frame_id;
}
void read(Cdr& c, Contact& m) {
  for (double& x : m.position) c >> x;
  for (double& x : m.normal) c >> x;
  c >> m.depth >> m.force >> m.patch_id >> m.hardware_uid >> m.link_name >> m.u >> m.v >>
      m.uncertainty >> m.track_id >> m.patch_count >> m.flags;
  read(c, m.first_seen);
  for (double& x : m.shear) c >> x;
  c >> m.shear_uncertainty;
  for (double& x : m.wrench_force) c >> x;
  for (double& x : m.wrench_torque) c >> x;
}
void read(Cdr& c, PatchStatus& m) {
  c >> m.node >> m.hardware_uid >> m.can_interface >> m.link_name >> m.state >> m.state_name >>
      m.node_state >> m.node_mode >> m.fault_mask >> m.uptime >> m.reboots >> m.samples >>
      m.samples_lost >> m.contacts >> m.clock_offset >> m.clock_drift_ppm;
  read(c, m.last_heard);
  c >> m.duplicate_id >> m.detail;
}
void read(Cdr& c, PatchEvent& m) {
  read(c, m.stamp);
  c >> m.kind >> m.kind_name >> m.node >> m.hardware_uid >> m.detail;
}
template <typename T>
void read_sequence(Cdr& c, std::vector<T>& v) {
  uint32_t n = 0;
  c >> n;
  v.resize(n);
  for (T& x : v) read(c, x);
}
void read(Cdr& c, KeyValue& m) {
  c >> m.key >> m.value;
}
void read(Cdr& c, DiagnosticStatus& m) {
  c >> m.level >> m.name >> m.message >> m.hardware_id;
  read_sequence(c, m.values);
}
void read(Cdr& c, DiagnosticArray& m) {
  read(c, m.header);
  read_sequence(c, m.status);
}
void read(Cdr& c, ContactArray& m) {
  read(c, m.header);
  read_sequence(c, m.contacts);
}
void read(Cdr& c, PatchStatusArray& m) {
  read(c, m.header);
  read_sequence(c, m.patches);
  read_sequence(c, m.events);
}
void write(Cdr& c, const JointState& m) {
  c << m.header.stamp.sec << m.header.stamp.nanosec << m.header.frame_id;
  c << static_cast<uint32_t>(m.name.size());
  for (const std::string& s : m.name) c << s;
  for (const std::vector<double>* v : {&m.position, &m.velocity, &m.effort}) {
    c << static_cast<uint32_t>(v->size());
    for (double x : *v) c << x;
  }
}

// A TopicDataType over one of the structs above: plain CDR with its encapsulation header, as
// ROS 2 puts final types on the wire. Unkeyed.
template <typename T>
class Type : public fdds::TopicDataType {
 public:
  explicit Type(const char* name) {
    setName(name);
    m_typeSize = 1 << 20;  // an upper bound for these tests' samples
    m_isGetKeyDefined = false;
  }
  bool serialize(void* data, frtps::SerializedPayload_t* payload) override {
    if constexpr (std::is_same_v<T, JointState>) {
      FastBuffer buffer(reinterpret_cast<char*>(payload->data), payload->max_size);
      Cdr c(buffer, Cdr::DEFAULT_ENDIAN, Cdr::DDS_CDR);
      payload->encapsulation = c.endianness() == Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
      try {
        c.serialize_encapsulation();
        write(c, *static_cast<const JointState*>(data));
      } catch (const std::exception&) {
        return false;
      }
      payload->length = static_cast<uint32_t>(c.getSerializedDataLength());
      return true;
    } else {
      (void)data;
      (void)payload;
      return false;  // only read here
    }
  }
  bool deserialize(frtps::SerializedPayload_t* payload, void* data) override {
    FastBuffer buffer(reinterpret_cast<char*>(payload->data), payload->length);
    Cdr c(buffer, Cdr::DEFAULT_ENDIAN, Cdr::DDS_CDR);
    try {
      c.read_encapsulation();
      payload->encapsulation = c.endianness() == Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
      if constexpr (!std::is_same_v<T, JointState>) read(c, *static_cast<T*>(data));
    } catch (const std::exception&) {
      return false;
    }
    return true;
  }
  std::function<uint32_t()> getSerializedSizeProvider(void*) override {
    return [] { return static_cast<uint32_t>(1 << 20); };
  }
  void* createData() override { return new T(); }
  void deleteData(void* data) override { delete static_cast<T*>(data); }
  bool getKey(void*, frtps::InstanceHandle_t*, bool) override { return false; }
};

// ---- JSON lines, SI units as on the wire ---------------------------------------------------

std::string quoted(const std::string& s) {
  std::string o = "\"";
  for (char ch : s) {
    if (ch == '"' || ch == '\\') o += '\\';
    o += ch;
  }
  return o + "\"";
}
std::string num(double x) {
  char b[40];
  std::snprintf(b, sizeof b, "%.17g", x);
  return b;
}
std::string time_json(const Time& t) {
  return "{\"sec\":" + std::to_string(t.sec) + ",\"nanosec\":" + std::to_string(t.nanosec) + "}";
}
std::string to_json(const ContactArray& a) {
  std::string o = "{\"type\":\"contacts\",\"stamp\":" + time_json(a.header.stamp) +
                  ",\"frame_id\":" + quoted(a.header.frame_id) + ",\"contacts\":[";
  for (std::size_t i = 0; i < a.contacts.size(); ++i) {
    const Contact& c = a.contacts[i];
    o += std::string(i ? "," : "") + "{\"position\":[" + num(c.position[0]) + "," +
         num(c.position[1]) + "," + num(c.position[2]) + "],\"normal\":[" + num(c.normal[0]) + "," +
         num(c.normal[1]) + "," + num(c.normal[2]) + "],\"depth\":" + num(c.depth) +
         ",\"force\":" + num(c.force) + ",\"patch_id\":" + std::to_string(c.patch_id) +
         ",\"hardware_uid\":" + std::to_string(c.hardware_uid) +
         ",\"link_name\":" + quoted(c.link_name) + ",\"u\":" + num(c.u) + ",\"v\":" + num(c.v) +
         ",\"uncertainty\":" + num(c.uncertainty) + ",\"track_id\":" + std::to_string(c.track_id) +
         ",\"patch_count\":" + std::to_string(c.patch_count) +
         ",\"flags\":" + std::to_string(c.flags) + ",\"first_seen\":" + time_json(c.first_seen) +
         ",\"shear\":[" + num(c.shear[0]) + "," + num(c.shear[1]) + "," + num(c.shear[2]) +
         "],\"shear_uncertainty\":" + num(c.shear_uncertainty) + ",\"wrench\":{\"force\":[" +
         num(c.wrench_force[0]) + "," + num(c.wrench_force[1]) + "," + num(c.wrench_force[2]) +
         "],\"torque\":[" + num(c.wrench_torque[0]) + "," + num(c.wrench_torque[1]) + "," +
         num(c.wrench_torque[2]) + "]}}";
  }
  return o + "]}";
}
std::string to_json(const PatchStatusArray& a) {
  std::string o =
      "{\"type\":\"patch_status\",\"stamp\":" + time_json(a.header.stamp) + ",\"patches\":[";
  for (std::size_t i = 0; i < a.patches.size(); ++i) {
    const PatchStatus& p = a.patches[i];
    o += std::string(i ? "," : "") + "{\"node\":" + std::to_string(p.node) +
         ",\"hardware_uid\":" + std::to_string(p.hardware_uid) +
         ",\"can_interface\":" + quoted(p.can_interface) + ",\"link_name\":" + quoted(p.link_name) +
         ",\"state\":" + std::to_string(p.state) + ",\"state_name\":" + quoted(p.state_name) +
         ",\"fault_mask\":" + std::to_string(p.fault_mask) +
         ",\"uptime\":" + std::to_string(p.uptime) + ",\"reboots\":" + std::to_string(p.reboots) +
         ",\"samples\":" + std::to_string(p.samples) +
         ",\"samples_lost\":" + std::to_string(p.samples_lost) +
         ",\"contacts\":" + std::to_string(p.contacts) +
         ",\"clock_offset\":" + num(p.clock_offset) +
         ",\"clock_drift_ppm\":" + num(p.clock_drift_ppm) +
         ",\"last_heard\":" + time_json(p.last_heard) +
         ",\"duplicate_id\":" + (p.duplicate_id ? "true" : "false") +
         ",\"detail\":" + quoted(p.detail) + "}";
  }
  o += "],\"events\":[";
  for (std::size_t i = 0; i < a.events.size(); ++i) {
    const PatchEvent& e = a.events[i];
    o += std::string(i ? "," : "") + "{\"stamp\":" + time_json(e.stamp) +
         ",\"kind\":" + std::to_string(e.kind) + ",\"kind_name\":" + quoted(e.kind_name) +
         ",\"node\":" + std::to_string(e.node) +
         ",\"hardware_uid\":" + std::to_string(e.hardware_uid) + ",\"detail\":" + quoted(e.detail) +
         "}";
  }
  return o + "]}";
}

std::string to_json(const DiagnosticArray& a) {
  std::string o =
      "{\"type\":\"diagnostics\",\"stamp\":" + time_json(a.header.stamp) + ",\"status\":[";
  for (std::size_t i = 0; i < a.status.size(); ++i) {
    const DiagnosticStatus& d = a.status[i];
    o += std::string(i ? "," : "") + "{\"level\":" + std::to_string(d.level) +
         ",\"name\":" + quoted(d.name) + ",\"message\":" + quoted(d.message) +
         ",\"hardware_id\":" + quoted(d.hardware_id) + ",\"values\":{";
    for (std::size_t k = 0; k < d.values.size(); ++k) {
      o += std::string(k ? "," : "") + quoted(d.values[k].key) + ":" + quoted(d.values[k].value);
    }
    o += "}}";
  }
  return o + "]}";
}

// ---- the participant ------------------------------------------------------------------------

fdds::DomainParticipant* make_participant(uint32_t domain) {
  fdds::DomainParticipantQos qos;
  qos.name("skinbus interop peer (Fast DDS)");
  auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
  udp->interfaceWhiteList.push_back("127.0.0.1");
  // Cyclone's participants take indices 0..30 on the test's loopback configuration: announce to
  // the ports of that many participants on the initial peer.
  udp->maxInitialPeersRange = 40;
  qos.transport().use_builtin_transports = false;
  qos.transport().user_transports.push_back(udp);
  frtps::Locator_t peer;
  frtps::IPLocator::setIPv4(peer, 127, 0, 0, 1);
  qos.wire_protocol().builtin.initialPeersList.push_back(peer);
  qos.wire_protocol().builtin.discovery_config.initial_announcements.count = 5;
  return fdds::DomainParticipantFactory::get_instance()->create_participant(domain, qos);
}

int64_t now_ns() {
  timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

int listen(uint32_t domain, int count, double timeout_s) {
  fdds::DomainParticipant* p = make_participant(domain);
  if (p == nullptr) return 3;
  fdds::TypeSupport contacts_type(new Type<ContactArray>("skin_msgs::msg::dds_::ContactArray_"));
  fdds::TypeSupport status_type(
      new Type<PatchStatusArray>("skin_msgs::msg::dds_::PatchStatusArray_"));
  fdds::TypeSupport diagnostics_type(
      new Type<DiagnosticArray>("diagnostic_msgs::msg::dds_::DiagnosticArray_"));
  contacts_type.register_type(p);
  status_type.register_type(p);
  diagnostics_type.register_type(p);
  fdds::Topic* dt =
      p->create_topic("rt/diagnostics", diagnostics_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Topic* ct =
      p->create_topic("rt/skin/contacts", contacts_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Topic* st =
      p->create_topic("rt/skin/patch_status", status_type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Subscriber* sub = p->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  fdds::DataReaderQos cq = fdds::DATAREADER_QOS_DEFAULT;
  cq.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  cq.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
  cq.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  cq.history().depth = 10;
  fdds::DataReaderQos sq = cq;
  sq.durability().kind = fdds::TRANSIENT_LOCAL_DURABILITY_QOS;
  fdds::DataReader* cr = sub->create_datareader(ct, cq);
  fdds::DataReader* sr = sub->create_datareader(st, sq);
  fdds::DataReader* dr = dt != nullptr ? sub->create_datareader(dt, cq) : nullptr;
  if (ct == nullptr || st == nullptr || cr == nullptr || sr == nullptr || dr == nullptr) return 3;
  std::fprintf(stderr, "fastdds_peer: listening on domain %u\n", domain);

  int contacts_seen = 0, status_seen = 0, diagnostics_seen = 0;
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    ContactArray a;
    fdds::SampleInfo info;
    while (cr->take_next_sample(&a, &info) == ReturnCode_t::RETCODE_OK) {
      if (!info.valid_data) continue;
      std::printf("%s\n", to_json(a).c_str());
      ++contacts_seen;
    }
    PatchStatusArray s;
    while (sr->take_next_sample(&s, &info) == ReturnCode_t::RETCODE_OK) {
      if (!info.valid_data) continue;
      std::printf("%s\n", to_json(s).c_str());
      ++status_seen;
    }
    DiagnosticArray d;
    while (dr->take_next_sample(&d, &info) == ReturnCode_t::RETCODE_OK) {
      if (!info.valid_data) continue;
      std::printf("%s\n", to_json(d).c_str());
      ++diagnostics_seen;
    }
    std::fflush(stdout);
    if (contacts_seen >= count && status_seen > 0 && diagnostics_seen > 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  p->delete_contained_entities();
  fdds::DomainParticipantFactory::get_instance()->delete_participant(p);
  return contacts_seen >= count && status_seen > 0 && diagnostics_seen > 0 ? 0 : 1;
}

int joints(uint32_t domain, double seconds, const std::vector<std::string>& pairs) {
  JointState js;
  for (const std::string& kv : pairs) {
    const std::size_t eq = kv.find('=');
    if (eq == std::string::npos) return 2;
    js.name.push_back(kv.substr(0, eq));
    js.position.push_back(std::strtod(kv.c_str() + eq + 1, nullptr));
  }
  fdds::DomainParticipant* p = make_participant(domain);
  if (p == nullptr) return 3;
  fdds::TypeSupport type(new Type<JointState>("sensor_msgs::msg::dds_::JointState_"));
  type.register_type(p);
  fdds::Topic* t =
      p->create_topic("rt/joint_states", type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
  fdds::Publisher* pub = p->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  fdds::DataWriterQos wq = fdds::DATAWRITER_QOS_DEFAULT;
  wq.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
  wq.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
  wq.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
  wq.history().depth = 10;
  fdds::DataWriter* w = t != nullptr ? pub->create_datawriter(t, wq) : nullptr;
  if (w == nullptr) return 3;
  js.header.frame_id = "";
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    const int64_t ns = now_ns();
    js.header.stamp.sec = static_cast<int32_t>(ns / 1'000'000'000);
    js.header.stamp.nanosec = static_cast<uint32_t>(ns % 1'000'000'000);
    w->write(&js);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  p->delete_contained_entities();
  fdds::DomainParticipantFactory::get_instance()->delete_participant(p);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "";
  if (mode == "listen" && argc == 5) {
    return listen(static_cast<uint32_t>(std::atoi(argv[2])), std::atoi(argv[3]),
                  std::atof(argv[4]));
  }
  if (mode == "joints" && argc >= 5) {
    return joints(static_cast<uint32_t>(std::atoi(argv[2])), std::atof(argv[3]),
                  std::vector<std::string>(argv + 4, argv + argc));
  }
  std::fprintf(stderr,
               "usage: fastdds_peer listen DOMAIN COUNT TIMEOUT_S\n"
               "       fastdds_peer joints DOMAIN SECONDS NAME=POSITION...\n");
  return 2;
}
