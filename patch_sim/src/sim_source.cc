#include "skinbus/patch_sim/sim_source.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include "skinbus/common/csv.h"
#include "skinbus/common/text_file.h"
#include "skinbus/sim/rng.h"

namespace skinbus::patch_sim {

Result<std::vector<sim::SceneContact>> parse_contact_script(const std::string& text, uint8_t node) {
  std::vector<sim::SceneContact> out;
  std::istringstream in(text);
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const std::size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    if (is_csv_comment_or_blank(line)) continue;
    if (line.rfind("t_start", 0) == 0) continue;  // header
    double v[10] = {0, 0, 0, 0, 0, 8.0, 0, 0, 0, 0};
    const std::vector<std::string_view> fields = split_csv_fields(line);
    int n = 0;
    for (std::string_view field : fields) {
      if (n >= 10 || !parse_csv_number(field, &v[n])) {
        return make_error(ErrorCode::kParse,
                          "contact script line " + std::to_string(line_no) + ": field " +
                              std::to_string(n + 1) + " '" + std::string(field) +
                              "' (expected t_start_s,t_end_s,u_mm,v_mm,depth_mm"
                              "[,tip_radius_mm[,node[,u_end_mm,v_end_mm[,friction]]]])");
      }
      ++n;
    }
    if (n < 5 || n == 8) {
      return make_error(ErrorCode::kParse, "contact script line " + std::to_string(line_no) + ": " +
                                               std::to_string(n) +
                                               " fields (5 to 7, or 9 or 10 for a slide)");
    }
    sim::SceneContact c;
    c.t_start_s = v[0];
    c.t_end_s = v[1];
    c.u_mm = v[2];
    c.v_mm = v[3];
    c.depth_mm = v[4];
    c.tip_radius_mm = v[5];
    if (n >= 9) {
      c.u_end_mm = v[7];
      c.v_end_mm = v[8];
      c.friction = v[9];
    }
    const int for_node = static_cast<int>(v[6]);
    if (!(c.t_end_s > c.t_start_s) || c.t_start_s < 0 || !(c.depth_mm >= 0) ||
        !(c.tip_radius_mm >= 0) || for_node < 0 || for_node > bus::kNodeMax ||
        !(c.friction >= 0 && c.friction <= 2)) {
      return make_error(ErrorCode::kOutOfRange,
                        "contact script line " + std::to_string(line_no) +
                            ": needs t_end_s > t_start_s >= 0, depth_mm >= 0, tip_radius_mm >= 0, "
                            "node 0..125, friction 0..2");
    }
    c.ramp_s = std::min(0.15, 0.5 * (c.t_end_s - c.t_start_s));
    if (for_node == 0 || for_node == node) out.push_back(c);
  }
  return out;
}

Result<std::vector<sim::SceneContact>> load_contact_script(const std::string& path, uint8_t node) {
  Result<std::string> text = read_text_file(path, "contact script", 64u << 20);
  if (!text.ok()) return text.error();
  Result<std::vector<sim::SceneContact>> r = parse_contact_script(text.value(), node);
  if (!r.ok()) return make_error(r.error().code, path + ": " + r.error().message);
  return r;
}

std::vector<sim::SceneContact> random_presses(uint64_t seed, double per_min, double duration_s) {
  std::vector<sim::SceneContact> out;
  if (!(per_min > 0)) return out;
  sim::Rng rng(seed);
  double t = 0;
  const double half = 70.0 - 10.0;
  while (true) {
    t += -std::log(1.0 - rng.uniform()) * 60.0 / per_min;
    if (t >= duration_s) break;
    sim::SceneContact c;
    c.t_start_s = t;
    c.t_end_s = t + 0.3 + 1.7 * rng.uniform();
    c.u_mm = -half + 2 * half * rng.uniform();
    c.v_mm = -half + 2 * half * rng.uniform();
    c.depth_mm = 0.5 + 2.5 * rng.uniform();
    out.push_back(c);
    t = c.t_end_s;  // one press at a time
  }
  return out;
}

Result<std::unique_ptr<PatchPhysicsSource>> PatchPhysicsSource::create(
    uint64_t hardware_uid, const std::vector<sim::SceneContact>& contacts,
    const patch_fw::SimSettings& settings, uint64_t start_us) {
  std::unique_ptr<PatchPhysicsSource> p(new PatchPhysicsSource());
  p->start_us_ = start_us;
  sim::LimbMotion limb;
  limb.amplitude_rad = settings.limb_swing_deg * M_PI / 180.0;
  limb.period_s = settings.limb_period_s;
  Result<int> idx = p->scene_.add_patch(hardware_uid, sim::PatchDesign{}, limb);
  if (!idx.ok()) return idx.error();
  for (sim::SceneContact c : contacts) {
    c.patch = *idx;
    if (Status st = p->scene_.add_contact(c); !st.ok()) return st.error();
  }
  p->field_.assign(p->scene_.patch(0).channel_count(), 0.0);
  return p;
}

sim::Vec3<double> PatchPhysicsSource::field_ut(int sensor, uint64_t time_us) {
  if (!have_ || time_us > last_us_ + kRoundUs) {
    const double t_s = static_cast<double>(time_us - std::min(time_us, start_us_)) * 1e-6;
    scene_.measure(0, t_s, field_);
    last_us_ = time_us;
    have_ = true;
    ++measurements_;
  }
  const std::size_t i = static_cast<std::size_t>(sensor) * 3;
  if (sensor < 0 || i + 3 > field_.size()) return {};
  return {field_[i], field_[i + 1], field_[i + 2]};
}

double PatchPhysicsSource::temperature_c(int, uint64_t time_us) {
  const double t_s = static_cast<double>(time_us - std::min(time_us, start_us_)) * 1e-6;
  return scene_.environment(0, t_s).temperature_c;
}

Result<std::unique_ptr<SimulatedBoard>> SimulatedBoard::create(const patch_fw::PatchNodeSettings& s,
                                                               patch_fw::Clock* clock) {
  std::vector<sim::SceneContact> contacts;
  if (!s.sim.contacts_file.empty()) {
    auto script = load_contact_script(s.sim.contacts_file, s.node.node_id);
    if (!script.ok())
      return make_error(script.error().code, "sim.contacts: " + script.error().message);
    contacts = std::move(script).value();
  }
  // Random presses over the next 24 hours (one per node: the seed is mixed with the node ID).
  for (const sim::SceneContact& c :
       random_presses(s.sim.seed * 131 + s.node.node_id, s.sim.random_presses_per_min, 86400.0))
    contacts.push_back(c);
  auto board = std::make_unique<SimulatedBoard>();
  auto physics = PatchPhysicsSource::create(s.node.hardware_uid, contacts, s.sim, clock->now_us());
  if (!physics.ok()) return physics.error();
  board->physics = std::move(physics).value();
  board->bus = std::make_unique<EmulatedI2cBus>(clock, board->physics.get());
  board->gpio = std::make_unique<FakeGpioChip>("sim-gpiochip", 64);
  if (s.mux_address) {
    if (Status st = board->bus->add_mux(*s.mux_address); !st.ok()) return st.error();
  }
  for (std::size_t i = 0; i < s.array.slots.size(); ++i) {
    const patch_fw::SensorSlot& slot = s.array.slots[i];
    if (Status st = board->bus->add_mlx90393(slot.channel, slot.address, static_cast<int>(i));
        !st.ok())
      return st.error();
  }
  return board;
}

}  // namespace skinbus::patch_sim
