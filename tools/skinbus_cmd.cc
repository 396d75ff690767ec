// skinbus-cmd: sends one command (or a SYNC) to a patch and prints its acknowledgement.
//
//   skinbus-cmd -i can0 --node 3 tare
//   skinbus-cmd -i can0 --node all mode stream      # broadcast: every patch answers
//   skinbus-cmd --node 3 rate 20 --print            # the frame in cansend syntax, no bus
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/format.h"
#include "skinbus/bus/reassembler.h"
#include "skinbus/bus/socketcan.h"
#include "tool_util.h"

using namespace skinbus;
using namespace skinbus::bus;

namespace {

void put_u16(std::array<uint8_t, 5>& a, uint16_t v) {
  a[0] = static_cast<uint8_t>(v);
  a[1] = static_cast<uint8_t>(v >> 8);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-cmd: sends one skinbus command to a patch (or to every patch) and prints the\n"
      "acknowledgements, as skinbus-decode prints them. Exit status 0 when every answer is ok,\n"
      "1 on a negative acknowledgement or when no answer came in time, 2 on bad arguments.\n\n"
      "Commands:\n"
      "  tare                  capture a new baseline\n"
      "  mode stream|event|off\n"
      "  rate HZ               sample rate (0.01 Hz steps)\n"
      "  sync-mode on|off      sample only on SYNC\n"
      "  identify SECONDS      blink the identify LED (0 stops)\n"
      "  reboot                restart the patch node\n"
      "  info                  ask for the Info message (printed too)\n"
      "  sync                  send one SYNC frame (no answer is due)\n\n"
      "Examples:\n"
      "  skinbus-cmd -i can0 --node 3 tare\n"
      "  skinbus-cmd -i can0 --node all mode event --timeout-ms 300\n"
      "  cansend vcan0 $(skinbus-cmd --node 3 rate 20 --print)"};
  std::string iface, node_text = "1", command, argument;
  bool classic = false, print = false;
  int seq = 0, timeout_ms = 500, sync_counter = 0;
  app.add_option("-i,--interface", iface, "SocketCAN interface to send on");
  app.add_option("-n,--node", node_text, "patch node ID 1..125, or 'all' (broadcast)")
      ->capture_default_str();
  app.add_option("command", command, "tare, mode, rate, sync-mode, identify, reboot, info, sync")
      ->required();
  app.add_option("argument", argument, "the command's argument, where it takes one");
  app.add_option("--seq", seq, "transfer sequence of the command, 0..255")
      ->check(CLI::Range(0, 255))
      ->capture_default_str();
  app.add_option("--sync-counter", sync_counter, "sync: the SYNC counter")
      ->check(CLI::Range(0, 65535));
  app.add_flag("--classic", classic, "send a classic CAN frame (commands fit in 8 bytes anyway)");
  app.add_flag("--print", print, "print the frame in cansend syntax instead of sending it");
  app.add_option("--timeout-ms", timeout_ms, "how long to wait for acknowledgements")
      ->capture_default_str()
      ->check(CLI::Range(1, 600000));
  CLI11_PARSE(app, argc, argv);

  try {
    int node = 0;
    if (node_text == "all") {
      node = kNodeBroadcast;
    } else {
      node = tools::parse_id_list(node_text, kNodeMin, kNodeMax).at(0);
    }
    Message msg;
    msg.node = static_cast<uint8_t>(node);
    msg.seq = static_cast<uint8_t>(seq);
    msg.kind = classic ? FrameKind::kClassic : FrameKind::kFd;
    auto need_arg = [&](const char* what) {
      if (argument.empty()) throw std::invalid_argument(command + " needs " + what);
    };
    if (command == "sync") {
      msg.node = kNodeBroadcast;
      msg.body =
          Sync{static_cast<uint32_t>(realtime_now_us()), static_cast<uint16_t>(sync_counter)};
    } else {
      Command c;
      if (command == "tare") {
        c.opcode = Opcode::kTare;
      } else if (command == "mode") {
        need_arg("stream, event or off");
        c.opcode = Opcode::kSetMode;
        if (argument == "off")
          c.arg[0] = static_cast<uint8_t>(PatchMode::kOff);
        else if (argument == "stream")
          c.arg[0] = static_cast<uint8_t>(PatchMode::kStream);
        else if (argument == "event")
          c.arg[0] = static_cast<uint8_t>(PatchMode::kEvent);
        else
          throw std::invalid_argument("mode '" + argument + "': stream, event or off");
      } else if (command == "rate") {
        need_arg("a rate in Hz");
        const double hz = std::stod(argument);
        if (!(hz > 0 && hz <= 655.35))
          throw std::invalid_argument("rate " + argument + ": 0.01..655.35 Hz");
        c.opcode = Opcode::kSetRate;
        put_u16(c.arg, static_cast<uint16_t>(std::lround(hz * 100)));
      } else if (command == "sync-mode") {
        need_arg("on or off");
        if (argument != "on" && argument != "off")
          throw std::invalid_argument("sync-mode: on or off");
        c.opcode = Opcode::kSyncMode;
        c.arg[0] = argument == "on" ? 1 : 0;
      } else if (command == "identify") {
        need_arg("seconds");
        const int s = std::stoi(argument);
        if (s < 0 || s > 255) throw std::invalid_argument("identify " + argument + ": 0..255 s");
        c.opcode = Opcode::kIdentify;
        c.arg[0] = static_cast<uint8_t>(s);
      } else if (command == "reboot") {
        c.opcode = Opcode::kReboot;
        for (int k = 0; k < 4; ++k) c.arg[k] = static_cast<uint8_t>(kRebootMagic >> (8 * k));
      } else if (command == "info") {
        c.opcode = Opcode::kGetInfo;
      } else {
        throw std::invalid_argument("unknown command '" + command + "' (see --help)");
      }
      msg.body = c;
    }
    std::array<CanFrame, 1> frame;
    if (encode(msg, frame).frames != 1) throw std::invalid_argument("cannot encode the command");
    if (print) {
      char text[160];
      const std::size_t n = format_frame_text(frame[0], text);
      std::printf("%.*s\n", static_cast<int>(n), text);
      return 0;
    }
    if (iface.empty()) throw std::invalid_argument("give -i INTERFACE, or --print");

    SocketCanOptions opts;
    opts.fd = true;
    opts.error_frames = false;
    opts.filters = {filter_for_class(MessageClass::kAck), filter_for_class(MessageClass::kInfo)};
    auto port = SocketCanPort::open(iface, opts);
    if (!port.ok()) throw std::runtime_error(port.error().message);
    if (Status st = (*port)->send_blocking(frame[0], 1000); !st.ok())
      throw std::runtime_error("send: " + st.error().message);
    if (command == "sync") return 0;

    // Collect answers: one ack per addressed node (broadcast: until the timeout).
    Reassembler infos;
    const uint64_t end_us = monotonic_now_us() + static_cast<uint64_t>(timeout_ms) * 1000;
    int acks = 0, nacks = 0, infos_seen = 0;
    const bool want_info = command == "info";
    CanPoller poller;
    if (Status st = poller.add(port->get()); !st.ok()) throw std::runtime_error(st.error().message);
    while (true) {
      const uint64_t now = monotonic_now_us();
      if (now >= end_us) break;
      bool done = false;
      auto r = poller.poll(
          static_cast<int>((end_us - now) / 1000) + 1,
          [&](SocketCanPort&, const CanFrame& f, const RxMeta&) {
            const uint8_t from = can_id_node(f.id);
            if (node != kNodeBroadcast && from != node) return;
            if (can_id_class(f.id) == static_cast<uint8_t>(MessageClass::kAck)) {
              Message m;
              if (decode_single(f, &m) != DecodeError::kNone) return;
              const Ack& a = std::get<Ack>(m.body);
              if (a.command_seq != seq || a.opcode != frame[0].data[2]) return;
              std::printf("%s\n", format_message(m).c_str());
              ++acks;
              if (a.status != AckStatus::kOk) ++nacks;
            } else {
              const FeedResult fr = infos.feed(f, monotonic_now_us());
              if (fr.status == FeedStatus::kMessage) {
                std::printf("%s\n", format_message(*fr.message).c_str());
                ++infos_seen;
              }
            }
            if (node != kNodeBroadcast && acks > 0 && (!want_info || infos_seen > 0)) done = true;
          },
          [](SocketCanPort&, const Error& e) {
            std::fprintf(stderr, "skinbus-cmd: %s\n", e.message.c_str());
          });
      if (!r.ok()) throw std::runtime_error(r.error().message);
      if (done) break;
    }
    std::fflush(stdout);
    if (acks == 0) {
      return skinbus::tools::fail(
          "skinbus-cmd", "no acknowledgement within " + std::to_string(timeout_ms) + " ms", 1);
    }
    return nacks == 0 ? 0 : 1;
  } catch (const std::invalid_argument& e) {
    return skinbus::tools::fail("skinbus-cmd", e.what(), 2);
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-cmd", e.what(), 1);
  }
}
