// The patch node end to end on a manual clock: emulated chips fed by the physics, every frame
// it sends decoded with the bus library, every command of the protocol.
#include "skinbus/patch_fw/node.h"

#include <gtest/gtest.h>

#include <algorithm>

#include "skinbus/bus/reassembler.h"
#include "skinbus/patch_fw/config.h"
#include "skinbus/patch_sim/sim_source.h"

namespace skinbus::patch_fw {
namespace {

using patch_sim::SimulatedBoard;

class VectorSink final : public FrameSink {
 public:
  std::vector<std::pair<uint64_t, bus::CanFrame>> frames;
  Clock* clock = nullptr;
  Status send(const bus::CanFrame& f) override {
    frames.emplace_back(clock->now_us(), f);
    return Status::Ok();
  }
};

struct Harness {
  explicit Harness(const std::string& yaml, const std::string& contacts = "") {
    settings = default_settings();
    settings.sim.enabled = true;
    settings.node.node_id = 7;
    settings.node.hardware_uid = 0xABCDEF;
    EXPECT_TRUE(load_settings_text(yaml, &settings).ok());
    EXPECT_TRUE(validate_settings(&settings).ok());
    if (!contacts.empty()) {
      contacts_path = ::testing::TempDir() + "/node_test_contacts.csv";
      std::FILE* f = std::fopen(contacts_path.c_str(), "w");
      std::fputs(contacts.c_str(), f);
      std::fclose(f);
      settings.sim.contacts_file = contacts_path;
    }
    auto b = SimulatedBoard::create(settings, &clock);
    EXPECT_TRUE(b.ok());
    board = std::move(b).value();
    mux = std::make_unique<Tca9546a>(board->bus.get(), 0x70, nullptr, &clock);
    array = std::make_unique<SensorArray>(board->bus.get(), mux.get(), &clock, settings.array);
    EXPECT_TRUE(array->init().ok());
    auto l = board->gpio->request_output({4, false, false}, "identify");
    EXPECT_TRUE(l.ok());
    led = std::move(l).value();
    sink.clock = &clock;
    node = std::make_unique<PatchNode>(settings.node, settings.gate, array.get(), &clock, &sink,
                                       led.get());
  }
  // Runs the node until `t_s` seconds after the start.
  void run_until(double t_s) {
    const uint64_t end = start_us + static_cast<uint64_t>(t_s * 1e6);
    while (clock.now_us() < end) {
      const uint64_t next = node->poll();
      clock.sleep_until_us(std::min(next, end));
    }
  }
  // Every complete message sent since `from` (frame index), in order.
  std::vector<bus::Message> messages(std::size_t from = 0) {
    bus::Reassembler r;
    std::vector<bus::Message> out;
    for (std::size_t i = from; i < sink.frames.size(); ++i) {
      const bus::FeedResult fr = r.feed(sink.frames[i].second, sink.frames[i].first);
      EXPECT_NE(fr.status, bus::FeedStatus::kRejected);
      EXPECT_NE(fr.status, bus::FeedStatus::kIntegrityFailure);
      if (fr.status == bus::FeedStatus::kMessage) out.push_back(*fr.message);
    }
    return out;
  }
  template <typename T>
  std::vector<T> of(const std::vector<bus::Message>& ms) {
    std::vector<T> out;
    for (const bus::Message& m : ms)
      if (const T* p = std::get_if<T>(&m.body)) out.push_back(*p);
    return out;
  }
  void command(const bus::Command& c, uint8_t to = 7, uint8_t seq = 1) {
    std::array<bus::CanFrame, 1> f;
    ASSERT_EQ(bus::encode(bus::Message{to, seq, bus::FrameKind::kFd, c}, f).frames, 1u);
    node->on_frame(f[0]);
  }
  bus::Command cmd(bus::Opcode op, std::initializer_list<uint8_t> arg = {}) {
    bus::Command c;
    c.opcode = op;
    std::copy(arg.begin(), arg.end(), c.arg.begin());
    return c;
  }

  ManualClock clock{1000000};
  uint64_t start_us = 1000000;
  PatchNodeSettings settings;
  std::string contacts_path;
  std::unique_ptr<SimulatedBoard> board;
  std::unique_ptr<Tca9546a> mux;
  std::unique_ptr<SensorArray> array;
  std::unique_ptr<GpioOutput> led;
  VectorSink sink;
  std::unique_ptr<PatchNode> node;
};

TEST(NodeTest, StreamModeSendsEverySampleAtTheRate) {
  Harness h("mode: stream\n");
  h.run_until(10.0);
  const auto ms = h.messages();
  const auto samples = h.of<bus::Sample>(ms);
  const auto beats = h.of<bus::Heartbeat>(ms);
  EXPECT_NEAR(static_cast<double>(samples.size()), 417, 2);
  EXPECT_NEAR(static_cast<double>(beats.size()), 10, 1);
  EXPECT_EQ(h.node->stats().samples_sent, samples.size());
  // Timestamps one period apart; sequences consecutive (wrapping).
  for (std::size_t i = 1; i < samples.size(); ++i) {
    EXPECT_NEAR(static_cast<double>(samples[i].timestamp_us - samples[i - 1].timestamp_us),
                1e6 / 41.7, 2.0);
  }
  uint8_t seq = 0;
  for (const bus::Message& m : ms) {
    if (m.message_class() != bus::MessageClass::kSample) continue;
    EXPECT_EQ(m.seq, seq++);
    EXPECT_EQ(m.node, 7);
  }
  // After the tare the values are baseline-subtracted and small; nothing is touched.
  const bus::Sample& last = samples.back();
  EXPECT_TRUE(last.flags & bus::sample_flags::kTared);
  EXPECT_FALSE(last.flags & bus::sample_flags::kContact);
  for (int16_t v : last.field_lsb) EXPECT_LT(std::abs(v), 80) << "more than 8 uT at rest";
  EXPECT_TRUE(samples.front().flags & bus::sample_flags::kTareActive);
  const bus::Heartbeat& hb = beats.back();
  // The die temperature of a sensor, measured between samples (the timestamps above stay one
  // period apart): the simulated environment's, to the chip's 1/45.2 degC step.
  const double want_c = h.board->physics->temperature_c(0, h.clock.now_us());
  EXPECT_NEAR(hb.temperature_cdeg, want_c * 100.0, 3.0) << want_c;
  EXPECT_EQ(beats.front().temperature_cdeg, 0) << "the first heartbeat precedes any measurement";
  EXPECT_EQ(h.node->stats().temperature_errors, 0u);
  EXPECT_EQ(hb.state, bus::PatchState::kRunning);
  EXPECT_EQ(hb.mode, bus::PatchMode::kStream);
  EXPECT_EQ(hb.rate_chz, 4170);
  EXPECT_EQ(hb.hardware_uid, 0xABCDEFu);
  EXPECT_TRUE(hb.status & bus::heartbeat_status::kSimulated);
  EXPECT_TRUE(hb.status & bus::heartbeat_status::kTared);
  EXPECT_EQ(hb.uptime_s, 9u);
}

TEST(NodeTest, EventModeIsSilentWhenIdleAndSendsPressesWithATail) {
  // A 1 mm press from 4 s to 6 s.
  Harness h("mode: event\nevent_tail_ms: 250\n", "4,6,10,-20,1.0\n");
  h.run_until(3.9);
  const std::size_t idle_frames = h.sink.frames.size();
  EXPECT_TRUE(h.of<bus::Sample>(h.messages()).empty()) << "an untouched patch sends no samples";
  EXPECT_LE(idle_frames, 4u);  // heartbeats at 0, 1, 2, 3 s
  h.run_until(8.0);
  const auto samples = h.of<bus::Sample>(h.messages(idle_frames));
  int contact = 0, tail = 0;
  for (const bus::Sample& s : samples) {
    if (s.flags & bus::sample_flags::kContact) {
      ++contact;
      EXPECT_FALSE(s.flags & bus::sample_flags::kEventTail);
    } else {
      ++tail;
      EXPECT_TRUE(s.flags & bus::sample_flags::kEventTail);
    }
  }
  // The press is 2 s long, ramps included: about 75 samples above the threshold.
  EXPECT_GT(contact, 60);
  EXPECT_LT(contact, 90);
  EXPECT_NEAR(tail, 10, 2);  // 250 ms at 41.7 Hz
  // Idle traffic is a heartbeat a second; touched, a sample every period (2 frames each).
  const double idle_fps = static_cast<double>(idle_frames) / 3.9;
  const double touched_fps = 2 * 41.7 + 1;
  EXPECT_GT(touched_fps / idle_fps, 20.0);
}

TEST(NodeTest, OffModeSendsOnlyHeartbeats) {
  Harness h("mode: off\n");
  h.run_until(5.0);
  const auto ms = h.messages();
  EXPECT_TRUE(h.of<bus::Sample>(ms).empty());
  EXPECT_EQ(h.of<bus::Heartbeat>(ms).size(), 5u);
  EXPECT_EQ(h.node->stats().samples_taken, 0u);
  // Without samples the temperature is measured at each heartbeat, for the next one.
  const double want_c = h.board->physics->temperature_c(0, h.clock.now_us());
  EXPECT_NEAR(h.of<bus::Heartbeat>(ms).back().temperature_cdeg, want_c * 100.0, 3.0);
}

TEST(NodeTest, EveryCommandIsAcknowledgedAndTakesEffect) {
  Harness h("mode: event\n");
  h.run_until(1.0);
  std::size_t mark = h.sink.frames.size();
  // set_mode stream: samples start flowing while idle.
  h.command(h.cmd(bus::Opcode::kSetMode, {1}), 7, 10);
  h.run_until(2.0);
  auto ms = h.messages(mark);
  auto acks = h.of<bus::Ack>(ms);
  ASSERT_EQ(acks.size(), 1u);
  EXPECT_EQ(acks[0].status, bus::AckStatus::kOk);
  EXPECT_EQ(acks[0].command_seq, 10);
  EXPECT_EQ(acks[0].value, 1);
  EXPECT_NEAR(static_cast<double>(h.of<bus::Sample>(ms).size()), 42, 2);
  // set_rate 20 Hz: the spacing doubles.
  mark = h.sink.frames.size();
  h.command(h.cmd(bus::Opcode::kSetRate, {0xD0, 0x07}), 7, 11);  // 2000 cHz
  h.run_until(3.0);
  ms = h.messages(mark);
  auto samples = h.of<bus::Sample>(ms);
  EXPECT_NEAR(static_cast<double>(samples.size()), 20, 1);
  EXPECT_NEAR(static_cast<double>(samples[2].timestamp_us - samples[1].timestamp_us), 50000, 2);
  EXPECT_EQ(h.of<bus::Ack>(ms).at(0).value, 2000);
  // tare: the next samples carry tare_active, then tared again.
  mark = h.sink.frames.size();
  h.command(h.cmd(bus::Opcode::kTare), 7, 12);
  h.run_until(4.0);
  samples = h.of<bus::Sample>(h.messages(mark));
  ASSERT_GT(samples.size(), 17u);
  EXPECT_TRUE(samples[0].flags & bus::sample_flags::kTareActive);
  EXPECT_FALSE(samples.back().flags & bus::sample_flags::kTareActive);
  // sync mode: nothing until a SYNC; one sample per SYNC (CAN frame or line edge), flagged.
  mark = h.sink.frames.size();
  h.command(h.cmd(bus::Opcode::kSyncMode, {1}), 7, 13);
  h.run_until(4.5);
  EXPECT_TRUE(h.of<bus::Sample>(h.messages(mark)).empty());
  std::array<bus::CanFrame, 1> sync;
  ASSERT_EQ(bus::encode(
                bus::Message{bus::kNodeBroadcast, 0, bus::FrameKind::kFd, bus::Sync{123, 1}}, sync)
                .frames,
            1u);
  for (int k = 0; k < 3; ++k) {
    h.node->on_frame(sync[0]);
    h.run_until(4.6 + 0.1 * k);
  }
  h.node->on_sync_edge();
  h.run_until(5.0);
  samples = h.of<bus::Sample>(h.messages(mark));
  ASSERT_EQ(samples.size(), 4u);
  for (const bus::Sample& s : samples) EXPECT_TRUE(s.flags & bus::sample_flags::kSynced);
  auto beats = h.of<bus::Heartbeat>(h.messages(mark));
  EXPECT_TRUE(beats.back().status & bus::heartbeat_status::kSyncMode);
  h.command(h.cmd(bus::Opcode::kSyncMode, {0}), 7, 14);
  // identify 2 s: the LED blinks at 2 Hz, the heartbeat says so, then it stops.
  const int before = h.board->gpio->transitions(4);
  h.command(h.cmd(bus::Opcode::kIdentify, {2}), 7, 15);
  h.run_until(5.9);
  EXPECT_TRUE(h.node->identify_active());
  h.run_until(7.5);
  EXPECT_FALSE(h.node->identify_active());
  EXPECT_FALSE(h.board->gpio->level(4));
  EXPECT_GE(h.board->gpio->transitions(4) - before, 7);
  // get_info: an ack, then the Info message.
  mark = h.sink.frames.size();
  h.command(h.cmd(bus::Opcode::kGetInfo), 7, 16);
  ms = h.messages(mark);
  auto infos = h.of<bus::Info>(ms);
  ASSERT_EQ(infos.size(), 1u);
  EXPECT_EQ(infos[0].rate_chz, 2000);
  EXPECT_EQ(infos[0].hardware_uid, 0xABCDEFu);
  EXPECT_EQ(infos[0].gain_sel, 7);
  EXPECT_GT(infos[0].max_rate_chz, 4170);
  EXPECT_EQ(infos[0].conversion_time_us, 2505);
  // reboot with the magic: acknowledged, then requested.
  EXPECT_FALSE(h.node->reboot_requested());
  h.command(h.cmd(bus::Opcode::kReboot, {0x52, 0x42, 0x4F, 0x54}), 7, 17);
  EXPECT_TRUE(h.node->reboot_requested());
}

TEST(NodeTest, BadBroadcastAndForeignCommands) {
  Harness h("mode: event\n");
  h.run_until(1.0);
  std::size_t mark = h.sink.frames.size();
  h.command(h.cmd(bus::Opcode::kSetMode, {9}), 7, 20);           // no mode 9
  h.command(h.cmd(bus::Opcode::kSetRate, {0x10, 0x27}), 7, 21);  // 100 Hz: above the maximum
  h.command(h.cmd(bus::Opcode::kReboot, {1, 2, 3, 4}), 7, 22);   // wrong magic
  h.command(h.cmd(bus::Opcode::kTare), 8, 23);                   // another node's
  h.command(h.cmd(bus::Opcode::kSetMode, {0}), bus::kNodeBroadcast, 24);
  auto acks = h.of<bus::Ack>(h.messages(mark));
  ASSERT_EQ(acks.size(), 4u);
  EXPECT_EQ(acks[0].status, bus::AckStatus::kBadArgument);
  EXPECT_EQ(acks[1].status, bus::AckStatus::kBadArgument);
  EXPECT_EQ(acks[2].status, bus::AckStatus::kNotPermitted);
  EXPECT_EQ(acks[3].status, bus::AckStatus::kOk);
  EXPECT_TRUE(acks[3].broadcast);
  EXPECT_EQ(acks[3].command_seq, 24);
  EXPECT_FALSE(h.node->reboot_requested());
  EXPECT_EQ(h.node->config().mode, bus::PatchMode::kOff);
  EXPECT_EQ(h.node->config().rate_chz, 4170);
  // Ack sequences count up per acknowledgement, so a lost one shows as a gap.
  const auto ms = h.messages(mark);
  std::vector<uint8_t> seqs;
  for (const auto& m : ms)
    if (m.message_class() == bus::MessageClass::kAck) seqs.push_back(m.seq);
  EXPECT_EQ(seqs, (std::vector<uint8_t>{0, 1, 2, 3}));
}

TEST(NodeTest, FaultySensorIsFlaggedWhileTheOthersKeepPublishing) {
  Harness h("mode: stream\nhealth: {retry_interval_samples: 20}\n");
  h.run_until(1.0);
  h.board->bus->faults(10).nak = true;
  std::size_t mark = h.sink.frames.size();
  h.run_until(2.5);
  auto ms = h.messages(mark);
  auto samples = h.of<bus::Sample>(ms);
  ASSERT_GT(samples.size(), 50u);
  const bus::Sample& s = samples.back();
  EXPECT_EQ(s.fault_mask, 1u << 10);
  EXPECT_TRUE(s.flags & bus::sample_flags::kSensorFault);
  EXPECT_EQ(s.field_lsb[30], 0);
  auto beats = h.of<bus::Heartbeat>(ms);
  ASSERT_FALSE(beats.empty());
  EXPECT_EQ(beats.back().state, bus::PatchState::kDegraded);
  EXPECT_EQ(beats.back().fault_mask, 1u << 10);
  EXPECT_GE(beats.back().i2c_errors, 3u);
  // It comes back: flagged no more, and its values are tared again (small at rest).
  h.board->bus->faults(10).nak = false;
  mark = h.sink.frames.size();
  h.run_until(4.0);
  ms = h.messages(mark);
  samples = h.of<bus::Sample>(ms);
  EXPECT_EQ(samples.back().fault_mask, 0);
  EXPECT_LT(std::abs(samples.back().field_lsb[30]), 80);
  EXPECT_EQ(h.of<bus::Heartbeat>(ms).back().state, bus::PatchState::kRunning);
}

TEST(NodeTest, ClassicFramesCarryTheSameSamples) {
  Harness h("mode: stream\ncan: {fd: false}\n");
  h.run_until(1.0);
  for (const auto& [t, f] : h.sink.frames) {
    EXPECT_FALSE(f.fd);
    EXPECT_LE(f.len, 8);
  }
  EXPECT_NEAR(static_cast<double>(h.of<bus::Sample>(h.messages()).size()), 42, 1);
}

}  // namespace
}  // namespace skinbus::patch_fw
