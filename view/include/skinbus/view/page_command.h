// skinbus/view/page_command.h: the commands a page may ask skinbus-view to send to a patch
// (docs/view.md), when it was started with --allow-commands and the page is on this machine:
//
//   {"type":"command","node":3,"command":"tare"}
//   {"type":"command","node":3,"command":"mode","mode":"stream"}     (stream, event or off)
//
// and the answer the page gets, to it alone:
//
//   {"type":"command_result","ok":true,"node":3,"command":"tare","detail":"sent on can0"}
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "skinbus/bus/protocol.h"
#include "skinbus/common/result.h"

namespace skinbus::view {

struct PageCommand {
  uint8_t node = 0;      // 1..125
  std::string name;      // "tare", "mode stream", ...
  bus::Command command;  // what goes on the bus
};

// Parses a page's message. kParse (not JSON, not a command) or kInvalidArgument (a node outside
// 1..125, a command other than tare and mode, a mode other than stream, event and off); the
// message names what was wrong.
Result<PageCommand> parse_page_command(std::string_view json);

// The answer to the page; `command` may be null (the message did not parse).
std::string command_result_to_json(const PageCommand* command, bool ok, const std::string& detail);

}  // namespace skinbus::view
