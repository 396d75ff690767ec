#include "skinbus/record/ros2_messages.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <sstream>

#include "ros2_definitions.h"
#include "skinbus/record/cdr.h"

namespace skinbus::record {

namespace {

constexpr double kMmPerM = 1000.0;
constexpr double kUsPerS = 1e6;

// ---- schemas ---------------------------------------------------------------------------------

const std::string* definition_of(const std::string& type) {
  static const std::map<std::string, std::string> table = [] {
    std::map<std::string, std::string> t;
    for (std::size_t i = 0; i < kRos2DefinitionCount; ++i) {
      t.emplace(kRos2Definitions[i].type, kRos2Definitions[i].text);
    }
    return t;
  }();
  auto it = table.find(type);
  return it == table.end() ? nullptr : &it->second;
}

// "pkg/msg/Name" -> "pkg/Name" (the form a .msg file names types in), and back.
std::string short_name(const std::string& type) {
  const std::size_t a = type.find('/'), b = type.rfind('/');
  return a == b ? type : type.substr(0, a) + type.substr(b);
}
std::string long_name(const std::string& type) {
  const std::size_t a = type.find('/');
  return type.substr(0, a) + "/msg" + type.substr(a);
}

// The message types (long names) a definition's fields use, in order of first use.
std::vector<std::string> used_types(const std::string& text, const std::string& package) {
  static const std::set<std::string> kPrimitive = {
      "bool",   "byte",  "char",   "float32", "float64", "int8",   "uint8",  "int16",
      "uint16", "int32", "uint32", "int64",   "uint64",  "string", "wstring"};
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (const std::size_t hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    std::istringstream words(line);
    std::string type;
    if (!(words >> type)) continue;
    if (const std::size_t bracket = type.find('['); bracket != std::string::npos) {
      type.erase(bracket);
    }
    if (kPrimitive.count(type) != 0 || type.starts_with("string<")) continue;
    if (type == "Header") type = "std_msgs/Header";
    if (type.find('/') == std::string::npos) type = package + "/" + type;
    type = long_name(type);
    if (std::find(out.begin(), out.end(), type) == out.end()) out.push_back(type);
  }
  return out;
}

// ---- encoding helpers ------------------------------------------------------------------------

// Collects the first bad value of a message, naming it.
class Check {
 public:
  explicit Check(std::string what) : what_(std::move(what)) {}
  // `v`, checked; the field's name ("field", "field[index]" or "field[index].member") is made
  // only when it is not finite.
  double finite(double v, const char* field, std::size_t index = kNoIndex,
                const char* member = nullptr) {
    if (!std::isfinite(v) && bad_.ok()) {
      bad_ = make_error(ErrorCode::kInvalidArgument, what_ + ": " + name(field, index, member) +
                                                         " is " + (std::isnan(v) ? "nan" : "inf"));
    }
    return v;
  }
  static constexpr std::size_t kNoIndex = static_cast<std::size_t>(-1);
  void time(CdrWriter& w, uint64_t us, const char* field, std::size_t index = kNoIndex,
            const char* member = nullptr) {
    const uint64_t sec = us / 1000000u;
    if (sec > static_cast<uint64_t>(std::numeric_limits<int32_t>::max()) && bad_.ok()) {
      bad_ = make_error(ErrorCode::kOutOfRange,
                        what_ + ": " + name(field, index, member) + " " + std::to_string(us) +
                            " us is beyond builtin_interfaces/Time (int32 seconds)");
    }
    w.i32(static_cast<int32_t>(sec));
    w.u32(static_cast<uint32_t>((us % 1000000u) * 1000u));
  }
  Status status() const { return bad_; }

 private:
  // "field", "field[index]" or "field[index].member".
  static std::string name(const char* field, std::size_t index, const char* member) {
    std::string n = field;
    if (index != kNoIndex) n += "[" + std::to_string(index) + "]";
    if (member != nullptr) n += std::string(".") + member;
    return n;
  }

  std::string what_;
  Status bad_;
};

void header(CdrWriter& w, Check& check, uint64_t stamp_us, const std::string& frame_id) {
  check.time(w, stamp_us, "header.stamp");
  w.string(frame_id);
}

// ---- decoding helpers ------------------------------------------------------------------------

uint64_t read_time(CdrReader& r, const char* field, Status* bad) {
  const int32_t sec = r.i32(field);
  const uint32_t nanosec = r.u32(field);
  if ((sec < 0 || nanosec >= 1000000000u) && bad->ok() && r.ok()) {
    *bad = make_error(ErrorCode::kOutOfRange, std::string(field) + " {" + std::to_string(sec) +
                                                  ", " + std::to_string(nanosec) +
                                                  "} is not a time after the epoch");
  }
  if (sec < 0) return 0;
  return static_cast<uint64_t>(sec) * 1000000u + nanosec / 1000u;
}

template <typename T>
Result<T> finish(const CdrReader& r, const Status& bad, const std::string& what, T value) {
  if (Status st = r.status(); !st.ok()) return st.error();
  if (!bad.ok()) return make_error(bad.error().code, what + ": " + bad.error().message);
  return value;
}

}  // namespace

Result<std::string> ros2_schema(std::string_view type_view) {
  const std::string type(type_view);
  const std::string* text = definition_of(type);
  if (text == nullptr) {
    return make_error(ErrorCode::kNotFound, "no ROS 2 definition of " + type + " is known");
  }
  std::string out = *text;
  std::vector<std::string> queue = used_types(*text, type.substr(0, type.find('/')));
  std::set<std::string> done = {type};
  for (std::size_t i = 0; i < queue.size(); ++i) {
    const std::string dep = queue[i];
    if (!done.insert(dep).second) continue;
    const std::string* dep_text = definition_of(dep);
    if (dep_text == nullptr) {
      return make_error(ErrorCode::kNotFound,
                        type + " uses " + dep + ", whose ROS 2 definition is not known");
    }
    if (!out.ends_with("\n")) out += "\n";
    out += std::string(80, '=') + "\nMSG: " + short_name(dep) + "\n" + *dep_text;
    for (std::string& more : used_types(*dep_text, dep.substr(0, dep.find('/')))) {
      queue.push_back(std::move(more));
    }
  }
  return out;
}

Status encode(const host::ContactArray& contacts, std::vector<uint8_t>* out) {
  CdrWriter w(out);
  Check check("skin_msgs/msg/ContactArray");
  header(w, check, contacts.stamp_us, contacts.base_frame);
  w.count(contacts.contacts.size());
  for (std::size_t i = 0; i < contacts.contacts.size(); ++i) {
    const host::BodyContact& c = contacts.contacts[i];
    for (int k = 0; k < 3; ++k)
      w.f64(check.finite(c.position_mm[k] / kMmPerM, "contacts", i, "position"));
    for (int k = 0; k < 3; ++k) w.f64(check.finite(c.normal[k], "contacts", i, "normal"));
    w.f64(check.finite(c.depth_mm / kMmPerM, "contacts", i, "depth"));
    w.f64(check.finite(c.force_n, "contacts", i, "force"));
    w.u8(c.node);
    w.u64(c.hardware_uid);
    w.string(c.link);
    w.f64(check.finite(c.u_mm / kMmPerM, "contacts", i, "u"));
    w.f64(check.finite(c.v_mm / kMmPerM, "contacts", i, "v"));
    w.f64(check.finite(c.uncertainty_mm / kMmPerM, "contacts", i, "uncertainty"));
    w.u32(c.track_id);
    w.u32(c.patch_count);
    w.u32(c.flags);
    check.time(w, c.first_seen_us, "contacts", i, "first_seen");
    for (int k = 0; k < 3; ++k) w.f64(check.finite(c.shear_n[k], "contacts", i, "shear"));
    w.f64(check.finite(c.shear_uncertainty_n, "contacts", i, "shear_uncertainty"));
    double force[3], torque[3];
    host::contact_wrench(c, force, torque);
    for (int k = 0; k < 3; ++k) w.f64(check.finite(force[k], "contacts", i, "wrench.force"));
    for (int k = 0; k < 3; ++k) w.f64(check.finite(torque[k], "contacts", i, "wrench.torque"));
  }
  return check.status();
}

Status encode(const host::PatchStatusArray& status, std::vector<uint8_t>* out) {
  CdrWriter w(out);
  Check check("skin_msgs/msg/PatchStatusArray");
  header(w, check, status.stamp_us, "");
  w.count(status.patches.size());
  for (std::size_t i = 0; i < status.patches.size(); ++i) {
    const host::PatchStatus& p = status.patches[i];
    w.u8(p.node);
    w.u64(p.hardware_uid);
    w.string(p.interface);
    w.string(p.link);
    w.u8(static_cast<uint8_t>(p.state));
    w.string(std::string(host::patch_link_state_name(p.state)));
    w.u8(p.node_state);
    w.u8(p.node_mode);
    w.u16(p.fault_mask);
    w.u32(p.uptime_s);
    w.u32(p.reboots);
    w.u64(p.samples);
    w.u64(p.samples_lost);
    w.u64(p.contacts);
    w.f64(check.finite(p.clock_offset_us / kUsPerS, "patches", i, "clock_offset"));
    w.f64(check.finite(p.clock_drift_ppm, "patches", i, "clock_drift_ppm"));
    check.time(w, p.last_heard_us, "patches", i, "last_heard");
    w.boolean(p.duplicate_id);
    w.string(p.detail);
  }
  w.count(status.events.size());
  for (std::size_t i = 0; i < status.events.size(); ++i) {
    const host::PatchEvent& e = status.events[i];
    check.time(w, e.time_us, "events", i, "stamp");
    w.u8(static_cast<uint8_t>(e.kind));
    w.string(std::string(host::patch_event_name(e.kind)));
    w.u8(e.node);
    w.u64(e.hardware_uid);
    w.string(e.detail);
  }
  return check.status();
}

Status encode(const host::DiagnosticArray& diagnostics, std::vector<uint8_t>* out) {
  CdrWriter w(out);
  Check check("diagnostic_msgs/msg/DiagnosticArray");
  header(w, check, diagnostics.stamp_us, "");
  w.count(diagnostics.status.size());
  for (const host::PatchDiagnostic& d : diagnostics.status) {
    w.u8(static_cast<uint8_t>(d.level));
    w.string(d.name);
    w.string(d.message);
    w.string(d.hardware_id);
    w.count(d.values.size());
    for (const host::DiagnosticValue& v : d.values) {
      w.string(v.key);
      w.string(v.value);
    }
  }
  return check.status();
}

Status encode(const PatchSampleMsg& s, std::vector<uint8_t>* out) {
  CdrWriter w(out);
  Check check("skin_msgs/msg/PatchSample");
  header(w, check, s.stamp_us, s.link);
  w.u8(s.node);
  w.u64(s.hardware_uid);
  w.u32(s.patch_time_us);
  w.u16(s.flags);
  w.u16(s.fault_mask);
  w.u16(s.saturation_mask);
  w.count(s.field_ut.size());
  for (std::size_t i = 0; i < s.field_ut.size(); ++i) {
    w.f32(static_cast<float>(check.finite(s.field_ut[i], "field_ut", i)));
  }
  return check.status();
}

Status encode(const CanFrameMsg& m, std::vector<uint8_t>* out) {
  CdrWriter w(out);
  Check check("skin_msgs/msg/CanFrame");
  header(w, check, m.rx_us, m.interface);
  w.u32(m.frame.id);
  w.boolean(m.frame.extended);
  w.boolean(m.frame.fd);
  w.boolean(m.frame.brs);
  w.boolean(m.frame.esi);
  w.boolean(m.frame.rtr);
  w.boolean(m.frame.error);
  const std::size_t len = std::min<std::size_t>(m.frame.len, bus::kFdMaxLen);
  w.bytes(std::span<const uint8_t>(m.frame.data.data(), len));
  return check.status();
}

Status encode(const JointStateMsg& j, std::vector<uint8_t>* out) {
  CdrWriter w(out);
  Check check("sensor_msgs/msg/JointState");
  if (j.names.size() != j.positions.size()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "sensor_msgs/msg/JointState: " + std::to_string(j.names.size()) +
                          " names but " + std::to_string(j.positions.size()) + " positions");
  }
  header(w, check, j.stamp_us, "");
  w.count(j.names.size());
  for (const std::string& n : j.names) w.string(n);
  w.count(j.positions.size());
  for (std::size_t i = 0; i < j.positions.size(); ++i) {
    w.f64(check.finite(j.positions[i], "position", i));
  }
  w.count(0);  // velocity
  w.count(0);  // effort
  return check.status();
}

Result<host::ContactArray> decode_contacts(std::span<const uint8_t> cdr) {
  const std::string what = "skin_msgs/msg/ContactArray";
  CdrReader r(cdr, what);
  Status bad;
  host::ContactArray out;
  out.stamp_us = read_time(r, "header.stamp", &bad);
  out.base_frame = r.string("header.frame_id");
  // A contact is at least 8 x 8 + 1 + 8 + 4 + 3 x 8 + 3 x 4 + 8 + 10 x 8 bytes.
  const uint32_t n = r.count("contacts", 200);
  out.contacts.resize(n);
  for (host::BodyContact& c : out.contacts) {
    for (double& p : c.position_mm) p = r.f64("contacts[].position") * kMmPerM;
    for (double& v : c.normal) v = r.f64("contacts[].normal");
    c.depth_mm = r.f64("contacts[].depth") * kMmPerM;
    c.force_n = r.f64("contacts[].force");
    c.node = r.u8("contacts[].patch_id");
    c.hardware_uid = r.u64("contacts[].hardware_uid");
    c.link = r.string("contacts[].link_name");
    c.u_mm = r.f64("contacts[].u") * kMmPerM;
    c.v_mm = r.f64("contacts[].v") * kMmPerM;
    c.uncertainty_mm = r.f64("contacts[].uncertainty") * kMmPerM;
    c.track_id = r.u32("contacts[].track_id");
    c.patch_count = r.u32("contacts[].patch_count");
    c.flags = r.u32("contacts[].flags");
    c.first_seen_us = read_time(r, "contacts[].first_seen", &bad);
    for (double& s : c.shear_n) s = r.f64("contacts[].shear");
    c.shear_uncertainty_n = r.f64("contacts[].shear_uncertainty");
    for (int k = 0; k < 6; ++k) r.f64("contacts[].wrench");  // derived from the fields above
  }
  return finish(r, bad, what, std::move(out));
}

Result<PatchSampleMsg> decode_patch_sample(std::span<const uint8_t> cdr) {
  const std::string what = "skin_msgs/msg/PatchSample";
  CdrReader r(cdr, what);
  Status bad;
  PatchSampleMsg s;
  s.stamp_us = read_time(r, "header.stamp", &bad);
  s.link = r.string("header.frame_id");
  s.node = r.u8("node");
  s.hardware_uid = r.u64("hardware_uid");
  s.patch_time_us = r.u32("patch_time_us");
  s.flags = r.u16("flags");
  s.fault_mask = r.u16("fault_mask");
  s.saturation_mask = r.u16("saturation_mask");
  s.field_ut.resize(r.count("field_ut", 4));
  for (float& f : s.field_ut) f = r.f32("field_ut");
  return finish(r, bad, what, std::move(s));
}

Result<CanFrameMsg> decode_can_frame(std::span<const uint8_t> cdr) {
  const std::string what = "skin_msgs/msg/CanFrame";
  CdrReader r(cdr, what);
  Status bad;
  CanFrameMsg m;
  m.rx_us = read_time(r, "header.stamp", &bad);
  m.interface = r.string("header.frame_id");
  m.frame.id = r.u32("id");
  m.frame.extended = r.boolean("is_extended");
  m.frame.fd = r.boolean("is_fd");
  m.frame.brs = r.boolean("is_brs");
  m.frame.esi = r.boolean("is_esi");
  m.frame.rtr = r.boolean("is_rtr");
  m.frame.error = r.boolean("is_error");
  const std::vector<uint8_t> data = r.bytes("data");
  const std::size_t max = m.frame.fd ? bus::kFdMaxLen : bus::kClassicMaxLen;
  if (r.ok() && bad.ok() &&
      (data.size() > max || (m.frame.fd && !bus::is_valid_fd_len(data.size())))) {
    bad = make_error(ErrorCode::kOutOfRange,
                     "data of " + std::to_string(data.size()) + " bytes is not a " +
                         (m.frame.fd ? "CAN FD" : "classic CAN") + " frame length");
  }
  if (bad.ok() && r.ok()) {
    m.frame.len = static_cast<uint8_t>(data.size());
    std::copy(data.begin(), data.end(), m.frame.data.begin());
  }
  return finish(r, bad, what, std::move(m));
}

Result<JointStateMsg> decode_joint_state(std::span<const uint8_t> cdr) {
  const std::string what = "sensor_msgs/msg/JointState";
  CdrReader r(cdr, what);
  Status bad;
  JointStateMsg j;
  j.stamp_us = read_time(r, "header.stamp", &bad);
  (void)r.string("header.frame_id");
  j.names.resize(r.count("name", 5));
  for (std::string& n : j.names) n = r.string("name");
  j.positions.resize(r.count("position", 8));
  for (double& p : j.positions) p = r.f64("position");
  // velocity and effort are not used by the host
  if (r.ok() && bad.ok() && j.names.size() != j.positions.size()) {
    bad = make_error(ErrorCode::kParse, std::to_string(j.names.size()) + " names but " +
                                            std::to_string(j.positions.size()) + " positions");
  }
  for (std::size_t i = 0; i < j.positions.size() && bad.ok(); ++i) {
    if (!std::isfinite(j.positions[i])) {
      bad = make_error(ErrorCode::kOutOfRange, "position[" + std::to_string(i) + "] is not finite");
    }
  }
  return finish(r, bad, what, std::move(j));
}

}  // namespace skinbus::record
