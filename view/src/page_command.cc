#include "skinbus/view/page_command.h"

#include <nlohmann/json.hpp>

namespace skinbus::view {
namespace {

// The string at `key`, or "" when it is absent or not a string (json::value() would throw).
std::string string_field(const nlohmann::json& j, const char* key) {
  const auto it = j.find(key);
  return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

}  // namespace

Result<PageCommand> parse_page_command(std::string_view text) {
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (!j.is_object() || string_field(j, "type") != "command") {
    return make_error(ErrorCode::kParse, "a page message that is not a command");
  }
  const auto node = j.find("node");
  if (node == j.end() || !node->is_number_integer() || node->get<int64_t>() < bus::kNodeMin ||
      node->get<int64_t>() > bus::kNodeMax) {
    return make_error(ErrorCode::kInvalidArgument, "command: node must be 1..125");
  }
  PageCommand c;
  c.node = static_cast<uint8_t>(node->get<int64_t>());
  const std::string name = string_field(j, "command");
  if (name == "tare") {
    c.command.opcode = bus::Opcode::kTare;
    c.name = "tare";
  } else if (name == "mode") {
    const std::string mode = string_field(j, "mode");
    c.command.opcode = bus::Opcode::kSetMode;
    if (mode == "stream") {
      c.command.arg[0] = static_cast<uint8_t>(bus::PatchMode::kStream);
    } else if (mode == "event") {
      c.command.arg[0] = static_cast<uint8_t>(bus::PatchMode::kEvent);
    } else if (mode == "off") {
      c.command.arg[0] = static_cast<uint8_t>(bus::PatchMode::kOff);
    } else {
      return make_error(ErrorCode::kInvalidArgument, "command mode: stream, event or off");
    }
    c.name = "mode " + mode;
  } else {
    return make_error(ErrorCode::kInvalidArgument, "command: tare or mode (the page's commands)");
  }
  return c;
}

std::string command_result_to_json(const PageCommand* command, bool ok, const std::string& detail) {
  nlohmann::json j{{"type", "command_result"}, {"ok", ok}, {"detail", detail}};
  if (command != nullptr) {
    j["node"] = command->node;
    j["command"] = command->name;
  }
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace skinbus::view
