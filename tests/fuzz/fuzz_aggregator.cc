// Fuzzes the host aggregator (host/aggregator.h) through its inputs: CAN frames on two buses,
// joint states, and the process() / tick() / status() calls of the host loop, over a skin map
// built here (three patches on a small robot, nodes 1..3, the shipped model
// estimators/models/nominal_seed_cnn).
//
// The input is a list of steps; each starts with an op byte whose low 3 bits choose the step:
//   0..2  a raw frame (fuzz_input.h: identifier and flags, length, data), then a time byte
//   3     a heartbeat, encoded by bus::encode from the fields that follow, then a time byte
//   4     a sample, encoded likewise (its 48 field values raw, zero, or the node's previous
//         ones scaled), then a time byte
//   5     a step of the host loop (host_loop.h): process(), and tick() / status() when the
//         loop's cadence (100 ms, 1 s of host time) says they are due
//   6     tick() and status() at once
//   7     by the next byte: a joint state (names from the robot's, unknown or empty, positions
//         small, or any double: NaN, Inf, huge), an info or ack message, or a host frame
// Bit 3 of the op byte picks the bus (0 or 1); op bytes 0xF8..0xFA feed a raw frame to bus 2,
// which does not exist. Encoded messages are sent as FD or classic frames, a part optionally
// dropped, two parts swapped or the last one repeated. A time byte moves host time on by
// microseconds to seconds, or back by up to 0.8 s. Patch clocks follow host time with jitter
// unless a sample gives its timestamp raw. Missing bytes read as zero.
//
// Invariants beyond "does not crash" (ASan, UBSan):
// - after each publication (the loop's sink checks it): every contact's numbers are finite, its
//   normal is a unit vector, its uncertainty positive, its track ID not 0 and unique in the
//   array, its hardware UID one of the skin map's, its link that UID's link, its node a patch
//   node heard on some bus. (A patch is placed by the UID its heartbeats name, so a mapped UID
//   heard on another node ID gives contacts with that node: the node is checked against the nodes
//   heard, the placement against the UID.)
// - after each status() (the loop's, or op 6's): no more patches than (bus, node) pairs that
//   were sent frames, each of them one of those, in (bus, node) order, with finite clock
//   estimates.
//
// One aggregator serves every run: create() reads and compiles the model in about 100 ms under
// the sanitizers (printed at start-up), against 1 to 10 ms for a run, so it is built once. Each run
// starts by moving host time on by an hour and calling tick(), process() and status(), which
// ends held contacts, tracks and partial messages and drains the events; what carries over is
// the registry (UIDs, duplicate IDs, reboot counts, clock aligners). A crash that only
// reproduces after earlier runs therefore needs them: rerun the corpus in order
// (`fuzz_aggregator -runs=1 <corpus files...> <crash file>`), not only the crash file.
//
// The seeds (corpus/aggregator/) were written once by a small program from presses of the patch
// simulator (sim::SimulatedPatch, tared, quantised to the wire's 0.1 uT) in the format above.
#include <algorithm>
#include <array>
#include <bitset>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "fuzz_input.h"
#include "skinbus/body_map/robot_model.h"
#include "skinbus/body_map/skin_map.h"
#include "skinbus/bus/codec.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/host_loop.h"

#ifndef SKINBUS_SOURCE_DIR
#define SKINBUS_SOURCE_DIR "."
#endif

using namespace skinbus;
using namespace skinbus::host;

namespace {

constexpr int kBuses = 2;
constexpr std::array<uint64_t, 3> kUids = {0x5EED000000000001ull, 0x5EED000000000002ull,
                                           0x5EED000000000003ull};
constexpr std::array<const char*, 3> kLinks = {"upper_arm", "upper_arm", "forearm"};
constexpr uint64_t kUnknownUid = 0xBAD0000000000BADull;

// base -> shoulder (revolute, z) -> upper_arm -> slide (prismatic, x) -> forearm
//      -> wrist (continuous, y) -> hand
const char* kUrdf = R"(<?xml version="1.0"?>
<robot name="fuzz_arm">
  <link name="base_link"/>
  <link name="upper_arm"/>
  <link name="forearm"/>
  <link name="hand"/>
  <joint name="shoulder" type="revolute">
    <parent link="base_link"/><child link="upper_arm"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="slide" type="prismatic">
    <parent link="upper_arm"/><child link="forearm"/>
    <origin xyz="0.3 0 0" rpy="0 0.5 0"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.2" effort="1" velocity="1"/>
  </joint>
  <joint name="wrist" type="continuous">
    <parent link="forearm"/><child link="hand"/>
    <origin xyz="0.25 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>
  </joint>
</robot>)";

const std::array<std::string, 6> kJointNames = {"shoulder", "slide", "wrist", "elbow", "", "hand"};

class CheckingSink;

struct World {
  body_map::SkinMap map;
  std::unique_ptr<body_map::RobotModel> robot;
  std::unique_ptr<Aggregator> agg;
  std::unique_ptr<CheckingSink> sink;
  std::unique_ptr<HostLoop> loop;  // the host loop's cadence over agg, publishing to sink
  uint64_t now_us = 1'700'000'000'000'000ull;  // CLOCK_REALTIME-like
  std::bitset<kBuses * 128> sent;              // (bus, node) pairs sent a frame, ever
  bool verbose = false;                        // SKINBUS_FUZZ_VERBOSE set: print what happens
};

World* world = nullptr;

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_aggregator: %s\n", what);
  std::abort();
}

// Three patches: two flat ones side by side on the upper arm (their edges 4 mm apart, so a
// press between them is seen by both), a cylinder on the forearm.
body_map::SkinMap make_map() {
  body_map::SkinMap map;
  for (int i = 0; i < 3; ++i) {
    body_map::PatchPlacement p;
    p.node_id = i + 1;
    p.hardware_uid = kUids[static_cast<std::size_t>(i)];
    p.link = kLinks[static_cast<std::size_t>(i)];
    p.pose_on_link.translation_mm = {144.0 * (i == 1), 0, 40};
    if (i == 2) {
      p.geometry.kind = body_map::SurfaceKind::kCylinder;
      p.geometry.radius_mm = 45;
      p.geometry.size_u_mm = 140;
      p.pose_on_link.rotation = body_map::rotation_from_rpy(0, 0, 1.2);
    }
    p.model = "estimators/models/nominal_seed_cnn";
    map.patches.push_back(p);
  }
  return map;
}

// Reads the input; missing bytes read as zero.
struct Input {
  const uint8_t* data;
  std::size_t size;
  std::size_t pos = 0;

  bool done() const { return pos >= size; }
  uint8_t u8() { return pos < size ? data[pos++] : 0; }
  uint16_t u16() {
    const uint8_t lo = u8();
    return static_cast<uint16_t>(lo | u8() << 8);
  }
  uint32_t u32() {
    const uint16_t lo = u16();
    return lo | static_cast<uint32_t>(u16()) << 16;
  }
  uint64_t u64() {
    const uint32_t lo = u32();
    return lo | static_cast<uint64_t>(u32()) << 32;
  }
};

// The invariants of a publication (above).
void check_contacts(const World& w, const ContactArray& a) {
  std::vector<uint32_t> ids;
  for (const BodyContact& c : a.contacts) {
    bool finite = std::isfinite(c.depth_mm) && std::isfinite(c.force_n) && std::isfinite(c.u_mm) &&
                  std::isfinite(c.v_mm) && std::isfinite(c.uncertainty_mm);
    for (int k = 0; k < 3; ++k)
      finite = finite && std::isfinite(c.position_mm[k]) && std::isfinite(c.normal[k]);
    if (!finite) fail("a contact holds a non-finite number");
    const double len = std::hypot(c.normal[0], c.normal[1], c.normal[2]);
    if (std::abs(len - 1) > 1e-9) fail("a contact's normal is not a unit vector");
    if (!(c.uncertainty_mm > 0)) fail("a contact's uncertainty is not positive");
    if (c.track_id == 0) fail("a contact has track ID 0");
    if (std::find(ids.begin(), ids.end(), c.track_id) != ids.end()) {
      fail("two contacts of one publication share a track ID");
    }
    ids.push_back(c.track_id);
    if (c.patch_count == 0) fail("a contact seen by no patch");
    const auto uid = std::find(kUids.begin(), kUids.end(), c.hardware_uid);
    if (uid == kUids.end()) fail("a contact's hardware UID is not in the skin map");
    if (c.link != kLinks[static_cast<std::size_t>(uid - kUids.begin())]) {
      fail("a contact's link is not the link of its patch");
    }
    if (!bus::is_patch_node(c.node) || !(w.sent.test(c.node) || w.sent.test(128 + c.node))) {
      fail("a contact from a node that was never heard");
    }
  }
}

// The invariants of a status (above).
void check_status(const World& w, const PatchStatusArray& st) {
  if (st.patches.size() > w.sent.count()) fail("status lists more patches than were heard");
  std::size_t last = 0;
  for (std::size_t i = 0; i < st.patches.size(); ++i) {
    const PatchStatus& p = st.patches[i];
    const int bus = p.interface == "can0" ? 0 : p.interface == "can1" ? 1 : -1;
    if (bus < 0) fail("a patch status names an unknown interface");
    const std::size_t key = static_cast<std::size_t>(bus) * 128 + p.node;
    if (!w.sent.test(key)) fail("a patch status for a (bus, node) that was never sent a frame");
    if (i > 0 && key <= last) fail("patch statuses out of (bus, node) order or repeated");
    last = key;
    if (!std::isfinite(p.clock_offset_us) || !std::isfinite(p.clock_drift_ppm)) {
      fail("a patch status holds a non-finite clock estimate");
    }
  }
}

// The host loop's sink: checks every publication and status; prints them with
// SKINBUS_FUZZ_VERBOSE.
class CheckingSink : public HostSink {
 public:
  explicit CheckingSink(const World& w) : w_(w) {}
  void contacts(const ContactArray& out, std::span<const uint64_t>) override {
    check_contacts(w_, out);
    if (w_.verbose) {
      std::fprintf(stderr, "process(): %zu contact(s)", out.contacts.size());
      for (const BodyContact& c : out.contacts) {
        std::fprintf(stderr, " [track %u node %u %s (%.1f %.1f %.1f) depth %.2f flags 0x%x]",
                     c.track_id, c.node, c.link.c_str(), c.position_mm[0], c.position_mm[1],
                     c.position_mm[2], c.depth_mm, c.flags);
      }
      std::fprintf(stderr, "\n");
    }
  }
  void status(const PatchStatusArray& st) override {
    check_status(w_, st);
    if (w_.verbose) {
      for (const PatchEvent& e : st.events) std::fprintf(stderr, "event: %s\n", e.detail.c_str());
    }
  }

 private:
  const World& w_;
};

// Per run: what the simulated nodes remember (sequence numbers, last fields).
struct NodeState {
  uint8_t seq[bus::kMessageClassCount] = {};
  std::array<int16_t, bus::kChannelCount> field{};
};

struct Run {
  Input in;
  World& w;
  std::array<NodeState, kBuses * 128> nodes{};

  void advance(uint8_t b) {
    const uint64_t m = b & 0x3F;
    switch (b >> 6) {
      case 0:
        w.now_us += m * 10;
        break;
      case 1:
        w.now_us += m * 1000;
        break;
      case 2:
        w.now_us += m * 100'000;
        break;
      default:
        if (m < 48) {
          w.now_us += m * 1'000'000;
        } else {
          w.now_us -= (m - 47) * 50'000;  // the host clock stepped back
        }
    }
  }

  void feed(int bus, const bus::CanFrame& f, uint64_t rx_us) {
    if (bus >= 0 && bus < kBuses) w.sent.set(static_cast<std::size_t>(bus) * 128 + (f.id & 0x7F));
    w.agg->on_frame(bus, f, rx_us);
  }

  static uint8_t pick_node(uint8_t b) {
    return (b & 0x80) != 0 ? static_cast<uint8_t>(1 + (b & 0x7F) % 3) : static_cast<uint8_t>(b);
  }

  // Encodes `body` from `node` and feeds its frames, possibly mangled.
  void send(int bus, uint8_t node, const bus::MessageBody& body) {
    const uint8_t how = in.u8();
    bus::Message m;
    m.node = node;
    m.kind = (how & 1) != 0 ? bus::FrameKind::kClassic : bus::FrameKind::kFd;
    m.body = body;
    uint8_t& seq = nodes[static_cast<std::size_t>(bus) * 128 + (node & 0x7F)]
                       .seq[static_cast<std::size_t>(body.index())];
    m.seq = (how & 0x10) != 0 ? in.u8() : seq;
    seq = static_cast<uint8_t>(m.seq + 1);
    std::array<bus::CanFrame, bus::kMaxParts> frames;
    const bus::EncodeResult r = bus::encode(m, frames);
    if (r.error != bus::EncodeError::kNone || r.frames == 0) return;  // e.g. a host-only node
    std::size_t n = r.frames;
    const std::size_t pick = static_cast<std::size_t>(how >> 5) % n;
    if ((how & 2) != 0 && n > 1) {  // drop a part
      std::copy(frames.begin() + static_cast<std::ptrdiff_t>(pick + 1),
                frames.begin() + static_cast<std::ptrdiff_t>(n),
                frames.begin() + static_cast<std::ptrdiff_t>(pick));
      --n;
    }
    if ((how & 4) != 0 && n > 1) std::swap(frames[pick % n], frames[(pick + 1) % n]);
    if ((how & 8) != 0 && n < frames.size()) {
      frames[n] = frames[n - 1];
      ++n;
    }
    for (std::size_t i = 0; i < n; ++i) feed(bus, frames[i], w.now_us + i * 40);
    advance(in.u8());
  }

  void heartbeat(int bus) {
    const uint8_t node = pick_node(in.u8());
    bus::Heartbeat hb;
    const uint8_t u = in.u8();
    switch (u % 8) {
      case 3:
        hb.hardware_uid = kUnknownUid;
        break;
      case 4:
        hb.hardware_uid = 0;
        break;
      case 5:
        hb.hardware_uid = in.u64();
        break;
      default:
        hb.hardware_uid = kUids[static_cast<std::size_t>((u >> 3) % 3)];
    }
    const uint8_t s = in.u8();
    hb.state = static_cast<bus::PatchState>((s & 3) == 3 ? 1 : s & 3);  // mostly running
    if ((s & 0x80) != 0) hb.state = bus::PatchState::kFault;
    hb.mode = static_cast<bus::PatchMode>((s >> 2) % bus::kPatchModeCount);
    hb.status = static_cast<uint8_t>((s >> 4) & 0x7);
    hb.rate_chz = 4170;
    hb.uptime_s = in.u16();
    const uint8_t f = in.u8();
    hb.fault_mask = (f & 0x10) != 0 ? static_cast<uint16_t>(1u << (f & 0xF)) : 0;
    hb.temperature_cdeg = 2500;
    send(bus, node, hb);
  }

  void sample(int bus) {
    const uint8_t node = pick_node(in.u8());
    NodeState& ns = nodes[static_cast<std::size_t>(bus) * 128 + (node & 0x7F)];
    bus::Sample s;
    const uint8_t fl = in.u8();
    s.flags = (fl & 0x80) != 0
                  ? static_cast<uint16_t>(bus::sample_flags::kContact | bus::sample_flags::kTared |
                                          (fl & bus::sample_flags::kSaturated) |
                                          (fl & bus::sample_flags::kSensorFault))
                  : static_cast<uint16_t>(fl);
    const uint8_t ts = in.u8();
    if (ts == 0xFF) {
      s.timestamp_us = in.u32();
    } else {  // a patch clock: host time minus a per-node offset, with jitter
      s.timestamp_us = static_cast<uint32_t>(w.now_us - node * 1'000'003ull + ts * 13u);
    }
    const uint8_t masks = in.u8();
    s.fault_mask = (masks & 0x80) != 0 ? static_cast<uint16_t>(1u << (masks & 0xF)) : 0;
    s.saturation_mask = (masks & 0x40) != 0 ? static_cast<uint16_t>(1u << ((masks + 7) & 0xF)) : 0;
    const uint8_t fm = in.u8();
    if (fm == 0) {
      for (int16_t& v : ns.field) v = static_cast<int16_t>(in.u16());
    } else if (fm == 1) {
      ns.field.fill(0);
    } else {  // the previous press, scaled (fm = 128: the same)
      for (int16_t& v : ns.field) {
        const long x = static_cast<long>(v) * fm / 128;
        v = static_cast<int16_t>(std::clamp(x, -32767L, 32767L));
      }
    }
    s.field_lsb = ns.field;
    send(bus, node, s);
  }

  void joint_state(uint8_t sub) {
    const std::size_t n = ((sub >> 2) & 7) % 5;
    std::vector<std::string> names;
    std::vector<double> q;
    for (std::size_t i = 0; i < n; ++i) {
      names.push_back(kJointNames[in.u8() % kJointNames.size()]);
      const uint8_t v = in.u8();
      double x = (static_cast<double>(v) - 128) * 0.05;
      if (v == 0xFF) {
        const uint64_t bits = in.u64();
        std::memcpy(&x, &bits, sizeof x);
      }
      q.push_back(x);
    }
    if ((sub & 0x20) != 0 && !q.empty()) q.pop_back();  // fewer positions than names
    const uint64_t stamp = w.now_us - static_cast<uint64_t>(in.u8()) * 10'000;
    w.agg->set_joint_state(names, q, stamp, (sub & 0x40) != 0);
  }

  void other(int bus) {
    const uint8_t sub = in.u8();
    switch (sub & 3) {
      case 0:
        joint_state(sub);
        break;
      case 1: {
        bus::Info info;
        info.hardware_uid = kUids[(sub >> 2) % 3];
        info.rate_chz = 4170;
        send(bus, pick_node(in.u8()), info);
        break;
      }
      case 2: {
        bus::Ack ack;
        ack.opcode = static_cast<uint8_t>(bus::Opcode::kSetMode);
        ack.value = sub;
        send(bus, pick_node(in.u8()), ack);
        break;
      }
      default: {  // what the host itself sends: SYNC to everyone, a command to one patch
        if ((sub & 4) != 0) {
          bus::Sync sync;
          sync.host_time_us = static_cast<uint32_t>(w.now_us);
          send(bus, bus::kNodeBroadcast, sync);
        } else {
          send(bus, pick_node(in.u8()), bus::Command{});
        }
      }
    }
  }

  void process() { w.loop->step(w.now_us); }

  // Out of the loop's cadence: tick() and status() now.
  void tick_and_status() {
    w.agg->tick(w.now_us);
    PatchStatusArray st;
    w.agg->status(w.now_us, &st);
    w.sink->status(st);
  }

  void step() {
    const uint8_t op = in.u8();
    const int bus = (op & 8) != 0 ? 1 : 0;
    switch (op & 7) {
      case 0:
      case 1:
      case 2: {
        bus::CanFrame f;
        if (!bus::fuzz::next_frame(in.data, in.size, &in.pos, &f)) {
          in.pos = in.size;
          return;
        }
        feed(op >= 0xF8 ? 2 : bus, f, w.now_us);
        advance(in.u8());
        break;
      }
      case 3:
        heartbeat(bus);
        break;
      case 4:
        sample(bus);
        break;
      case 5:
        process();
        break;
      case 6:
        tick_and_status();
        break;
      default:
        other(bus);
    }
  }
};

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  world = new World;
  world->verbose = std::getenv("SKINBUS_FUZZ_VERBOSE") != nullptr;
  world->map = make_map();
  if (Status st = body_map::validate_skin_map(world->map); !st.ok())
    fail("the skin map is invalid");
  auto robot = body_map::RobotModel::from_urdf_string(kUrdf);
  if (!robot.ok()) fail("the robot model does not load");
  world->robot = std::make_unique<body_map::RobotModel>(std::move(*robot));
  const char* env = std::getenv("SKINBUS_SOURCE_DIR");
  const std::string dir = env != nullptr ? env : SKINBUS_SOURCE_DIR;
  // The network runs on oneDNN, which is not instrumented: about five times the executions a
  // second of the project's own kernels under the sanitizers (which have their own tests and
  // benchmarks). Without oneDNN, the default backend.
  const auto t0 = std::chrono::steady_clock::now();
  AggregatorOptions options;
  options.runtime.backend = estimators::RuntimeBackend::kOneDnn;
  for (int attempt = 0; attempt < 2 && world->agg == nullptr; ++attempt) {
    if (attempt == 1) options.runtime.backend = estimators::RuntimeBackend::kAuto;
    auto agg = Aggregator::create(&world->map, dir, world->robot.get(), {"can0", "can1"}, options);
    if (!agg.ok()) fail(("create() failed: " + agg.error().to_string()).c_str());
    if ((*agg)->model_descriptions().size() == 1) world->agg = std::move(*agg);
  }
  const auto t1 = std::chrono::steady_clock::now();
  if (world->agg == nullptr) {
    fail("the shipped model did not load (set SKINBUS_SOURCE_DIR to the repository)");
  }
  world->sink = std::make_unique<CheckingSink>(*world);
  world->loop = std::make_unique<HostLoop>(*world->agg, *world->sink);
  world->loop->start(world->now_us);
  std::fprintf(stderr, "fuzz_aggregator: create() took %.1f ms; model %s\n",
               std::chrono::duration<double, std::milli>(t1 - t0).count(),
               world->agg->model_descriptions()[0].c_str());
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  World& w = *world;
  // What the previous run left: held contacts and tracks end, partial messages expire, events
  // are drained.
  w.now_us += 3'600'000'000ull;
  {
    Run flush{{nullptr, 0}, w};
    flush.tick_and_status();
    flush.process();
  }
  Run run{{data, size}, w};
  while (!run.in.done()) run.step();
  if (w.verbose) {
    const AggregatorStats& s = w.agg->stats();
    std::fprintf(
        stderr,
        "stats: frames %llu samples %llu estimated %llu rejected %llu no_contact %llu "
        "unattributed %llu publications %llu\n",
        static_cast<unsigned long long>(s.frames), static_cast<unsigned long long>(s.samples),
        static_cast<unsigned long long>(s.estimated), static_cast<unsigned long long>(s.rejected),
        static_cast<unsigned long long>(s.no_contact),
        static_cast<unsigned long long>(s.unattributed),
        static_cast<unsigned long long>(s.publications));
  }
  return 0;
}
