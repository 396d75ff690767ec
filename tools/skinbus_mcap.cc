// skinbus-mcap: read a recording (skinbus-host --record, MCAP).
//
//   skinbus-mcap info session.mcap
//   skinbus-mcap candump s.mcap | skinbus-host --map skin.yaml --replay - --fast
//       --joints s.mcap --json --no-dds      (one line: estimates the session again)
//   skinbus-mcap contacts session.mcap > recorded.jsonl
//   skinbus-mcap extract session.mcap -o session/
#include <CLI/CLI.hpp>

#include <cinttypes>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>

#include "skinbus/bus/candump.h"
#include "skinbus/host/contacts_json.h"
#include "skinbus/record/mcap.h"
#include "skinbus/record/recorder.h"
#include "skinbus/record/ros2_messages.h"
#include "tool_util.h"

namespace {

using namespace skinbus;
constexpr const char* kTool = "skinbus-mcap";

// Calls `each(topic, message)` for every message of the file, in file order.
template <typename Each>
Status for_each_message(const std::string& path, Each each,
                        std::unique_ptr<record::McapReader>* keep = nullptr) {
  auto reader = record::McapReader::open(path);
  if (!reader.ok()) return reader.error();
  record::McapMessage m;
  for (;;) {
    auto more = (*reader)->next(&m);
    if (!more.ok()) return more.error();
    if (!*more) break;
    if (Status st = each((*reader)->channels().at(m.channel_id), m); !st.ok()) return st;
  }
  if (keep != nullptr) *keep = std::move(*reader);
  return Status::Ok();
}

Status where(const std::string& path, const record::McapMessage& m, const Error& e) {
  return make_error(e.code, path + ": message " + std::to_string(m.sequence) + " at " +
                                std::to_string(m.log_time_ns) + " ns: " + e.message);
}

Status info(const std::string& path) {
  struct Count {
    uint64_t n = 0, bytes = 0, first_ns = 0, last_ns = 0;
  };
  std::map<uint16_t, Count> counts;
  std::unique_ptr<record::McapReader> reader;
  Status st = for_each_message(
      path,
      [&](const record::McapChannel& ch, const record::McapMessage& m) {
        Count& c = counts[ch.id];
        if (c.n++ == 0) c.first_ns = m.log_time_ns;
        c.last_ns = std::max(c.last_ns, m.log_time_ns);
        c.bytes += m.data.size();
        return Status::Ok();
      },
      &reader);
  if (!st.ok()) return st;
  uint64_t first = UINT64_MAX, last = 0, total = 0;
  for (const auto& [id, c] : counts) {
    first = std::min(first, c.first_ns);
    last = std::max(last, c.last_ns);
    total += c.n;
  }
  const double span_s = total > 0 ? static_cast<double>(last - first) * 1e-9 : 0;
  tools::out_printf(kTool, "%s: profile %s, %" PRIu64 " messages over %.3f s, %" PRIuMAX " bytes\n",
                    path.c_str(), reader->profile().c_str(), total, span_s,
                    static_cast<uintmax_t>(std::filesystem::file_size(path)));
  tools::out_printf(kTool, "%-20s %-38s %10s %12s %9s\n", "topic", "type", "messages", "bytes",
                    "rate/s");
  for (const auto& [id, ch] : reader->channels()) {
    const Count c = counts.count(id) ? counts.at(id) : Count{};
    const std::string type =
        reader->schemas().count(ch.schema_id) ? reader->schemas().at(ch.schema_id).name : "";
    tools::out_printf(kTool, "%-20s %-38s %10" PRIu64 " %12" PRIu64 " %9.1f\n", ch.topic.c_str(),
                      type.c_str(), c.n, c.bytes,
                      span_s > 0 ? static_cast<double>(c.n) / span_s : 0.0);
  }
  for (const record::McapAttachment& a : reader->attachments()) {
    tools::out_printf(kTool, "attachment %s (%s, %zu bytes)\n", a.name.c_str(),
                      a.media_type.c_str(), a.data.size());
  }
  for (const auto& [name, map] : reader->metadata()) {
    tools::out_printf(kTool, "metadata %s:\n", name.c_str());
    for (const auto& [k, v] : map) tools::out_printf(kTool, "  %s: %s\n", k.c_str(), v.c_str());
  }
  return Status::Ok();
}

Status candump(const std::string& path) {
  uint64_t frames = 0;
  Status st = for_each_message(
      path, [&](const record::McapChannel& ch, const record::McapMessage& m) -> Status {
        if (ch.topic != record::kCanTopic) return Status::Ok();
        auto f = record::decode_can_frame(m.data);
        if (!f.ok()) return where(path, m, f.error());
        const std::string line = bus::format_candump_line(f->frame, f->rx_us, f->interface);
        std::fputs(line.c_str(), stdout);
        std::fputc('\n', stdout);
        tools::check_stdout(kTool);
        ++frames;
        return Status::Ok();
      });
  if (!st.ok()) return st;
  tools::check_stdout(kTool, /*flush=*/true);
  if (frames == 0) {
    return make_error(ErrorCode::kNotFound, path + ": no " + std::string(record::kCanTopic) +
                                                " messages (recorded with --record-no-frames?)");
  }
  return Status::Ok();
}

Status contacts(const std::string& path) {
  Status st = for_each_message(
      path, [&](const record::McapChannel& ch, const record::McapMessage& m) -> Status {
        if (ch.topic != record::kContactsTopic) return Status::Ok();
        auto c = record::decode_contacts(m.data);
        if (!c.ok()) return where(path, m, c.error());
        std::fputs(host::contacts_to_json(*c).c_str(), stdout);
        std::fputc('\n', stdout);
        tools::check_stdout(kTool);
        return Status::Ok();
      });
  tools::check_stdout(kTool, /*flush=*/true);
  return st;
}

Status extract(const std::string& path, const std::string& dir) {
  std::unique_ptr<record::McapReader> reader;
  Status st = for_each_message(
      path, [](const record::McapChannel&, const record::McapMessage&) { return Status::Ok(); },
      &reader);
  if (!st.ok()) return st;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return make_error(ErrorCode::kIo, dir + ": " + ec.message());
  for (const record::McapAttachment& a : reader->attachments()) {
    const std::filesystem::path name = std::filesystem::path(a.name).filename();
    if (name.empty() || name != std::filesystem::path(a.name)) {
      return make_error(ErrorCode::kInvalidArgument,
                        path + ": attachment name '" + a.name + "' is not a plain file name");
    }
    const std::string out = (std::filesystem::path(dir) / name).string();
    std::ofstream f(out, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(a.data.data()),
            static_cast<std::streamsize>(a.data.size()));
    if (!f) return make_error(ErrorCode::kIo, out + ": write failed");
    std::fprintf(stderr, "%s: %s\n", kTool, out.c_str());
  }
  return Status::Ok();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app(
      "skinbus-mcap: read a recording made by skinbus-host --record (MCAP, the container rosbag2\n"
      "writes; docs/recording.md). It holds the host's topics as ROS 2 messages in CDR:\n"
      "/skin/contacts, /skin/patch_status, /diagnostics, /skin/samples (each patch's tared\n"
      "field), /skin/can (every CAN frame the host was fed), /joint_states, and the skin map,\n"
      "URDF, design and unit files as attachments; written as rosbag2 writes MCAP, for\n"
      "Foxglove, Lichtblick and ros2 bag with skin_msgs built (the tests read it with\n"
      "@mcap/core and @foxglove/rosmsg2-serialization; the applications were not run).\n\n"
      "  info      channels, message counts and rates, attachments, metadata\n"
      "  candump   the CAN frames as candump -L lines: the host's input, to replay\n"
      "  contacts  the recorded contacts as the host's JSON lines (skinbus-host --json)\n"
      "  extract   the attachments (skin map, URDF, design and unit files) into a folder\n\n"
      "Estimating a recorded session again, with another model or options:\n"
      "  skinbus-mcap extract s.mcap -o s/    (then point s/skin.yaml's model at the new one)\n"
      "  skinbus-mcap candump s.mcap | skinbus-host --map s/skin.yaml --replay - --fast \\\n"
      "      --joints s.mcap --json --no-dds\n\n"
      "Exit status: 0 done, 1 a file could not be read or written, 2 bad arguments or a\n"
      "malformed recording (the message names the file and byte).");
  app.require_subcommand(1);
  std::string path, dir;
  auto* i = app.add_subcommand("info", "channels, counts, rates, attachments, metadata");
  i->add_option("file", path, "recording (MCAP)")->required();
  auto* c = app.add_subcommand("candump", "the CAN frames as candump -L lines on stdout");
  c->add_option("file", path, "recording (MCAP)")->required();
  auto* k = app.add_subcommand("contacts", "the recorded contacts as JSON lines on stdout");
  k->add_option("file", path, "recording (MCAP)")->required();
  auto* e = app.add_subcommand("extract", "the attachments into a folder");
  e->add_option("file", path, "recording (MCAP)")->required();
  e->add_option("-o,--output", dir, "folder (created)")->required();
  CLI11_PARSE(app, argc, argv);
  Status st = i->parsed()   ? info(path)
              : c->parsed() ? candump(path)
              : k->parsed() ? contacts(path)
                            : extract(path, dir);
  if (!st.ok()) return tools::report_error(kTool, st.error());
  return 0;
}
