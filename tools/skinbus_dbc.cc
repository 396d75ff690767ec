// skinbus-dbc: write a DBC file of the skinbus protocol for CAN tools (SavvyCAN, cantools, ...).
//
//   skinbus-dbc --nodes 1-16 -o skinbus_fd.dbc
//   skinbus-dbc --classic --nodes 1-8 > skinbus_classic.dbc
#include <CLI/CLI.hpp>

#include <cstdio>
#include <string>

#include "skinbus/bus/dbc.h"
#include "tool_util.h"

int main(int argc, char** argv) {
  using namespace skinbus;
  CLI::App app{
      "skinbus-dbc: generate a DBC file describing skinbus frames, from the protocol tables.\n\n"
      "Multi-part messages are multiplexed on the part index; a field that spans two parts\n"
      "(only some 32/64-bit fields of classic frames) is named in a comment instead.\n"};
  std::string nodes = "1-16", out_path;
  bool classic = false;
  app.add_option("--nodes", nodes, "patch node IDs to describe, a range N-M")
      ->capture_default_str();
  app.add_flag("--classic", classic, "describe classic CAN (8-byte) frames instead of CAN FD");
  app.add_option("-o,--output", out_path, "output file (default: standard output)");
  CLI11_PARSE(app, argc, argv);
  try {
    const auto ids = tools::parse_id_list(nodes, bus::kNodeMin, bus::kNodeMax);
    for (std::size_t i = 1; i < ids.size(); ++i) {
      if (ids[i] != ids[i - 1] + 1) throw std::invalid_argument("--nodes must be one range N-M");
    }
    const std::string dbc =
        bus::generate_dbc(classic ? bus::FrameKind::kClassic : bus::FrameKind::kFd,
                          static_cast<uint8_t>(ids.front()), static_cast<uint8_t>(ids.back()));
    tools::write_output(out_path.empty() ? "-" : out_path, dbc, "DBC file");
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-dbc", e.what(), 1);
  }
  return 0;
}
