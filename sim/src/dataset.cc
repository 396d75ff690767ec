#include "skinbus/sim/dataset.h"

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/line_reader.h"
#include "skinbus/common/text_file.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <set>
#include <sstream>
#include <string_view>

namespace skinbus::sim {

void Dataset::append(int64_t press_id, double t, double u, double v, double depth, double force,
                     const double* f) {
  press.push_back(press_id);
  t_s.push_back(t);
  u_mm.push_back(u);
  v_mm.push_back(v);
  depth_mm.push_back(depth);
  force_n.push_back(force);
  field_ut.insert(field_ut.end(), f, f + channels());
}

std::string field_column_name(int channel) {
  char name[32];
  std::snprintf(name, sizeof name, "s%02d_b%c_ut", channel / 3, "xyz"[channel % 3]);
  return name;
}

std::vector<int> stuck_channels(const Dataset& d) {
  std::vector<int> stuck;
  const int nc = d.channels();
  for (int c = 0; c < nc; ++c) {
    std::size_t seen = 0;
    double value = 0;
    bool same = true;
    for (std::size_t r = 0; r < d.rows() && same; ++r) {
      const double x = d.field(r)[c];
      if (!std::isfinite(x)) continue;
      same = seen == 0 || x == value;
      value = x;
      ++seen;
    }
    if (same && seen >= kMinStuckRows) stuck.push_back(c);
  }
  return stuck;
}

std::string leave_out_stuck_channels(Dataset* d) {
  const std::vector<int> stuck = stuck_channels(*d);
  if (stuck.empty()) return "";
  const std::size_t nc = static_cast<std::size_t>(d->channels());
  std::string names;
  for (int c : stuck) {
    for (std::size_t r = 0; r < d->rows(); ++r) {
      d->field_ut[r * nc + static_cast<std::size_t>(c)] = std::numeric_limits<double>::quiet_NaN();
    }
    names += (names.empty() ? "" : ", ") + field_column_name(c);
  }
  return names + (stuck.size() == 1 ? " holds" : " hold") +
         " one value in every row (a stuck sensor): left out as dead";
}

std::string leave_out_rows_deeper_than(Dataset* d, double max_depth_mm) {
  const std::size_t nc = static_cast<std::size_t>(d->channels());
  const std::size_t ne = d->extra_columns.size();
  std::size_t kept = 0;
  std::set<int64_t> presses;
  for (std::size_t r = 0; r < d->rows(); ++r) {
    if (d->depth_mm[r] > max_depth_mm) {
      if (d->press[r] >= 0) presses.insert(d->press[r]);
      continue;
    }
    if (kept != r) {
      d->press[kept] = d->press[r];
      d->t_s[kept] = d->t_s[r];
      d->u_mm[kept] = d->u_mm[r];
      d->v_mm[kept] = d->v_mm[r];
      d->depth_mm[kept] = d->depth_mm[r];
      d->force_n[kept] = d->force_n[r];
      std::copy_n(d->field_ut.begin() + static_cast<std::ptrdiff_t>(r * nc), nc,
                  d->field_ut.begin() + static_cast<std::ptrdiff_t>(kept * nc));
      std::copy_n(d->extra.begin() + static_cast<std::ptrdiff_t>(r * ne), ne,
                  d->extra.begin() + static_cast<std::ptrdiff_t>(kept * ne));
    }
    ++kept;
  }
  const std::size_t left_out = d->rows() - kept;
  if (left_out == 0) return "";
  for (auto* column : {&d->t_s, &d->u_mm, &d->v_mm, &d->depth_mm, &d->force_n}) {
    column->resize(kept);
  }
  d->press.resize(kept);
  d->field_ut.resize(kept * nc);
  d->extra.resize(kept * ne);
  char text[160];
  std::snprintf(text, sizeof text, "%zu of %zu samples (%zu presses) deeper than %.2f mm: left out",
                left_out, kept + left_out, presses.size(), max_depth_mm);
  return text;
}

std::string leave_out_presses_past_the_lattice(Dataset* d, const PatchDesign& design,
                                               double depth_zero_mm) {
  const std::string note = leave_out_rows_deeper_than(d, design.deepest_press_mm() + depth_zero_mm);
  if (note.empty()) return note;
  char why[160];
  std::snprintf(why, sizeof why,
                ", 10 %% short of where the design's %g mm lattice stops a press in the model "
                "(%.2f mm, 0.6 x thickness_mm)",
                design.thickness_mm, design.max_depth_mm());
  return note + why;
}

Result<PressedArea> parse_press_area(std::string_view text, const PatchDesign& design,
                                     const std::optional<PressedArea>& unit_area) {
  if (text == "surface") {
    PressedArea a{-design.size_u_mm / 2, design.size_u_mm / 2, -design.size_v_mm / 2,
                  design.size_v_mm / 2};
    if (unit_area) {
      a = {std::fmin(a.u_min_mm, unit_area->u_min_mm), std::fmax(a.u_max_mm, unit_area->u_max_mm),
           std::fmin(a.v_min_mm, unit_area->v_min_mm), std::fmax(a.v_max_mm, unit_area->v_max_mm)};
    }
    return a;
  }
  if (text == "pressed") {
    if (unit_area) return *unit_area;
    return make_error(ErrorCode::kInvalidArgument,
                      "--area pressed needs a --unit whose file says where it was pressed "
                      "(pressed_area_mm, written by skinbus-identify)");
  }
  const std::string s(text);
  double a[4];
  char end = 0;
  if (std::sscanf(s.c_str(), "%lf,%lf,%lf,%lf%c", &a[0], &a[1], &a[2], &a[3], &end) != 4 ||
      !(a[0] < a[1] && a[2] < a[3]) || std::fabs(a[0]) > 1e4 || std::fabs(a[1]) > 1e4 ||
      std::fabs(a[2]) > 1e4 || std::fabs(a[3]) > 1e4) {
    return make_error(ErrorCode::kInvalidArgument,
                      "--area '" + s +
                          "': give U0,U1,V0,V1 in mm with U0 < U1 and V0 < V1, 'surface' or "
                          "'pressed'");
  }
  return PressedArea{a[0], a[1], a[2], a[3]};
}

std::optional<PressedArea> pressed_area(const Dataset& d) {
  std::optional<PressedArea> a;
  for (std::size_t r = 0; r < d.rows(); ++r) {
    const double u = d.u_mm[r], v = d.v_mm[r];
    if (!std::isfinite(u) || !std::isfinite(v)) continue;
    if (!a) {
      a = PressedArea{u, u, v, v};
      continue;
    }
    a->u_min_mm = std::min(a->u_min_mm, u);
    a->u_max_mm = std::max(a->u_max_mm, u);
    a->v_min_mm = std::min(a->v_min_mm, v);
    a->v_max_mm = std::max(a->v_max_mm, v);
  }
  return a;
}

std::vector<PressPoint> plan_grid(int n_u, int n_v, double pitch_mm) {
  std::vector<PressPoint> p;
  for (int j = 0; j < n_v; ++j) {
    for (int i = 0; i < n_u; ++i)
      p.push_back({(i - (n_u - 1) / 2.0) * pitch_mm, (j - (n_v - 1) / 2.0) * pitch_mm});
  }
  return p;
}

std::vector<PressPoint> plan_jittered_grid(int n_u, int n_v, double pitch_mm, double jitter,
                                           uint64_t seed) {
  Rng rng(seed);
  std::vector<PressPoint> p = plan_grid(n_u, n_v, pitch_mm);
  for (PressPoint& q : p) {
    q.u_mm += rng.uniform(-1, 1) * jitter * pitch_mm / 2;
    q.v_mm += rng.uniform(-1, 1) * jitter * pitch_mm / 2;
  }
  return p;
}

namespace {
// The point of [lo, hi] at t in [-1, 1] (the centre plus t half-widths: on a square centred on
// the patch, exactly t x the half extent).
double along(double lo, double hi, double t) {
  return (lo + hi) / 2 + t * ((hi - lo) / 2);
}

double radical_inverse(uint64_t i, unsigned base) {
  double f = 1, r = 0;
  while (i > 0) {
    f /= base;
    r += f * static_cast<double>(i % base);
    i /= base;
  }
  return r;
}
}  // namespace

std::vector<PressPoint> plan_halton(int count, const PressedArea& area, uint64_t skip) {
  std::vector<PressPoint> p;
  for (int k = 0; k < count; ++k) {
    const uint64_t i = skip + static_cast<uint64_t>(k) + 1;
    p.push_back({along(area.u_min_mm, area.u_max_mm, 2 * radical_inverse(i, 2) - 1),
                 along(area.v_min_mm, area.v_max_mm, 2 * radical_inverse(i, 3) - 1)});
  }
  return p;
}

std::vector<PressPoint> plan_random(int count, const PressedArea& area, uint64_t seed) {
  Rng rng(seed);
  std::vector<PressPoint> p;
  for (int k = 0; k < count; ++k)
    p.push_back({along(area.u_min_mm, area.u_max_mm, rng.uniform(-1, 1)),
                 along(area.v_min_mm, area.v_max_mm, rng.uniform(-1, 1))});
  return p;
}

Result<std::vector<PressPoint>> plan_from_file(const std::string& path) {
  Result<std::string> text = read_text_file(path, "press list");
  if (!text.ok()) return text.error();
  std::istringstream in(std::move(text).value());
  std::vector<PressPoint> points;
  std::string line;
  int lineno = 0;
  for (BoundedLine got; (got = getline_bounded(in, line, 4096)) != BoundedLine::kEof;) {
    ++lineno;
    if (got == BoundedLine::kTooLong) {
      return make_error(ErrorCode::kParse,
                        path + ":" + std::to_string(lineno) + ": longer than 4096 bytes");
    }
    for (char& ch : line) {
      if (ch == ',' || ch == ';' || ch == '\t' || ch == '\r') ch = ' ';
    }
    std::istringstream ls(line);
    std::string a, b, rest;
    if (!(ls >> a) || a[0] == '#') continue;  // blank or comment
    ls >> b;
    PressPoint p;
    const bool ok =
        std::from_chars(a.data(), a.data() + a.size(), p.u_mm).ptr == a.data() + a.size() &&
        std::from_chars(b.data(), b.data() + b.size(), p.v_mm).ptr == b.data() + b.size() &&
        std::isfinite(p.u_mm) && std::isfinite(p.v_mm) && !b.empty() && !(ls >> rest);
    if (!ok) {
      if (points.empty() && lineno <= 2 && (a == "u_mm" || a == "x_mm")) continue;  // a header line
      return make_error(ErrorCode::kParse, path + ":" + std::to_string(lineno) +
                                               ": expected 'u_mm,v_mm', got '" + line + "'");
    }
    points.push_back(p);
  }
  if (points.empty()) return make_error(ErrorCode::kParse, path + ": no press points");
  return points;
}

namespace {

void fill_layout(const SimulatedPatch& patch, Dataset* d) {
  const PatchModel& m = patch.model();
  d->sensors.clear();
  for (const auto& s : m.sensors()) d->sensors.push_back({s.u, s.v, s.h});
  d->sensor_layout_known = true;
  const PatchDesign& des = m.design();
  d->meta["format"] = "skinbus-dataset 1";
  d->meta["source"] = "sim";
  d->meta["geometry"] = des.surface == SurfaceKind::kFlat
                            ? "flat size_u_mm=" + std::to_string(des.size_u_mm) +
                                  " size_v_mm=" + std::to_string(des.size_v_mm)
                            : "cylinder radius_mm=" + std::to_string(des.radius_mm) +
                                  " size_u_mm=" + std::to_string(des.size_u_mm) +
                                  " size_v_mm=" + std::to_string(des.size_v_mm);
  d->meta["field"] = "tared (baseline subtracted), uT, each sensor's own frame";
  char noise[64];
  std::snprintf(noise, sizeof noise, "xy=%.3f z=%.3f", patch.noise_xy_ut(), patch.noise_z_ut());
  d->meta["noise_ut"] = noise;
}

}  // namespace

Dataset generate_ramp_dataset(SimulatedPatch& patch, const std::vector<PressPoint>& plan,
                              const RampProtocol& pr, const Environment& env) {
  Dataset d;
  fill_layout(patch, &d);
  char buf[160];
  std::snprintf(buf, sizeof buf,
                "ramp max_depth_mm=%g speed_mm_per_s=%g rate_hz=%g tip_radius_mm=%g presses=%zu",
                pr.max_depth_mm, pr.speed_mm_per_s, pr.rate_hz, pr.tip_radius_mm, plan.size());
  std::string protocol = buf;
  if (pr.hold_s > 0) {
    std::snprintf(buf, sizeof buf, " hold_s=%g", pr.hold_s);
    protocol += buf;
  }
  d.meta["protocol"] = protocol;
  const int nc = patch.channel_count();
  std::vector<double> baseline(nc), m(nc), tared(nc);
  patch.tare(env, pr.tare_samples, baseline);
  const double dt = 1.0 / pr.rate_hz;
  const double ramp_s = pr.max_depth_mm / pr.speed_mm_per_s;
  const double hold_s = std::max(0.0, pr.hold_s);
  const double press_s = 2 * ramp_s + hold_s;
  constexpr double kMoveS = 1.0;  // a second to move to the next point
  // Creep (PatchDesign::creep_fraction, creep_slow_fraction): each lagging part q of the
  // lattice's bend follows the press with its time constant; the plate bends by
  // (1 - f - f_s) d + f q + f_s q_s. Stepped at the sample rate (exactly for a depth held over
  // each step), relaxing while the indenter moves on.
  const PatchDesign& design = patch.model().design();
  struct Lag {
    double fraction, relax_step, relax_move, mm = 0;
  };
  std::array<Lag, 2> lags = {
      Lag{design.creep_fraction, 1 - std::exp(-dt / design.creep_time_s),
          std::exp(-kMoveS / design.creep_time_s)},
      Lag{design.creep_slow_fraction, 1 - std::exp(-dt / design.creep_slow_time_s),
          std::exp(-kMoveS / design.creep_slow_time_s)}};
  double t = 0;
  for (std::size_t k = 0; k < plan.size(); ++k) {
    // Down, held, then up, sampled at the rate; the sample times start half a period in.
    for (double tp = dt / 2; tp < press_s; tp += dt) {
      const double depth = tp < ramp_s            ? pr.speed_mm_per_s * tp
                           : tp < ramp_s + hold_s ? pr.max_depth_mm
                                                  : pr.speed_mm_per_s * (press_s - tp);
      double bent = depth;
      for (Lag& lag : lags) {
        lag.mm += (depth - lag.mm) * lag.relax_step;
        bent += lag.fraction * (lag.mm - depth);
      }
      if (!(depth > pr.min_depth_mm)) continue;
      const Contact c{plan[k].u_mm, plan[k].v_mm, bent, pr.tip_radius_mm};
      patch.measure(std::span<const Contact>(&c, 1), env, m);
      for (int i = 0; i < nc; ++i) tared[i] = m[i] - baseline[i];
      d.append(static_cast<int64_t>(k), t + tp, c.u_mm, c.v_mm, depth, patch.model().force_n(depth),
               tared.data());
    }
    t += press_s + kMoveS;
    for (Lag& lag : lags) lag.mm *= lag.relax_move;
  }
  return d;
}

namespace {

// One tared sample per contact `pick(k, rng)` for k < count (the test splits).
template <typename Pick>
void static_presses(SimulatedPatch& patch, const Environment& env, int tare_samples, int count,
                    uint64_t seed, Pick pick, Dataset* d) {
  const int nc = patch.channel_count();
  std::vector<double> baseline(nc), m(nc), tared(nc);
  patch.tare(env, tare_samples, baseline);
  Rng rng(seed);
  for (int k = 0; k < count; ++k) {
    const Contact c = pick(k, rng);
    patch.measure(std::span<const Contact>(&c, 1), env, m);
    for (int i = 0; i < nc; ++i) tared[i] = m[i] - baseline[i];
    d->append(k, 0, c.u_mm, c.v_mm, c.depth_mm, patch.model().force_n(c.depth_mm), tared.data());
  }
}

}  // namespace

Dataset generate_random_test_set(SimulatedPatch& patch, int count, const PressedArea& area,
                                 double max_depth_mm, uint64_t seed, const Environment& env,
                                 int tare_samples, double tip_radius_mm) {
  Dataset d;
  fill_layout(patch, &d);
  char extent[96];
  if (area == PressedArea::square(area.u_max_mm)) {
    std::snprintf(extent, sizeof extent, "half_extent_mm=%g", area.u_max_mm);
  } else {
    std::snprintf(extent, sizeof extent, "u_mm=%g..%g v_mm=%g..%g", area.u_min_mm, area.u_max_mm,
                  area.v_min_mm, area.v_max_mm);
  }
  char buf[224];
  std::snprintf(buf, sizeof buf,
                "random_static count=%d %s max_depth_mm=%g tip_radius_mm=%g seed=%llu", count,
                extent, max_depth_mm, tip_radius_mm, static_cast<unsigned long long>(seed));
  d.meta["protocol"] = buf;
  static_presses(
      patch, env, tare_samples, count, seed,
      [&](int, Rng& rng) {
        const double u = along(area.u_min_mm, area.u_max_mm, rng.uniform(-1, 1));
        const double v = along(area.v_min_mm, area.v_max_mm, rng.uniform(-1, 1));
        return Contact{u, v, max_depth_mm * (1 - rng.uniform()),  // depth in (0, max]
                       tip_radius_mm};
      },
      &d);
  return d;
}

Dataset generate_static_test_set(SimulatedPatch& patch, const std::vector<PressPoint>& points,
                                 int per_point, double max_depth_mm, uint64_t seed,
                                 const Environment& env, int tare_samples, double tip_radius_mm) {
  Dataset d;
  fill_layout(patch, &d);
  char buf[160];
  std::snprintf(buf, sizeof buf,
                "static_at_points points=%zu per_point=%d max_depth_mm=%g tip_radius_mm=%g "
                "seed=%llu",
                points.size(), per_point, max_depth_mm, tip_radius_mm,
                static_cast<unsigned long long>(seed));
  d.meta["protocol"] = buf;
  const int count = static_cast<int>(points.size()) * std::max(per_point, 0);
  static_presses(
      patch, env, tare_samples, count, seed,
      [&](int k, Rng& rng) {
        const PressPoint& p = points[static_cast<std::size_t>(k / per_point)];
        return Contact{p.u_mm, p.v_mm, max_depth_mm * (1 - rng.uniform()), tip_radius_mm};
      },
      &d);
  return d;
}

// ---- CSV ---------------------------------------------------------------------------------------

namespace {

const char* const kStandardColumns[] = {"press", "t_s", "u_mm", "v_mm", "depth_mm", "force_n"};

void put_number(std::string* s, double x) {
  char buf[32];
  auto r = std::to_chars(buf, buf + sizeof buf, x, std::chars_format::general, 9);
  s->append(buf, r.ptr);
}

}  // namespace

Status write_dataset_csv(const Dataset& d, const std::string& path) {
  AtomicFile f;
  if (Status st = f.open(path, "dataset"); !st.ok()) return st;
  std::string s;
  for (const auto& [k, v] : d.meta) {
    if (k == "sensors" || k.rfind("sensor ", 0) == 0) continue;
    s += "# " + k + ": " + v + "\n";
  }
  s += "# sensors: " + std::to_string(d.sensors.size()) + "\n";
  for (std::size_t i = 0; i < d.sensors.size(); ++i) {
    s += "# sensor " + std::to_string(i) + ": u_mm=";
    put_number(&s, d.sensors[i].u_mm);
    s += " v_mm=";
    put_number(&s, d.sensors[i].v_mm);
    s += " h_mm=";
    put_number(&s, d.sensors[i].h_mm);
    s += "\n";
  }
  for (const char* c : kStandardColumns)
    s += std::string(c) + (std::strcmp(c, "force_n") ? "," : "");
  for (int c = 0; c < d.channels(); ++c) s += "," + field_column_name(c);
  for (const std::string& e : d.extra_columns) s += "," + e;
  s += "\n";
  const int nc = d.channels();
  const std::size_t ne = d.extra_columns.size();
  for (std::size_t r = 0; r < d.rows(); ++r) {
    s += std::to_string(d.press[r]);
    for (double x : {d.t_s[r], d.u_mm[r], d.v_mm[r], d.depth_mm[r], d.force_n[r]}) {
      s += ',';
      put_number(&s, x);
    }
    for (int i = 0; i < nc; ++i) {
      s += ',';
      put_number(&s, d.field_ut[r * nc + i]);
    }
    for (std::size_t e = 0; e < ne; ++e) {
      s += ',';
      put_number(&s, d.extra[r * ne + e]);
    }
    s += '\n';
    if (s.size() > (1 << 20)) {
      if (Status st = f.write(s); !st.ok()) return st;
      s.clear();
    }
  }
  if (Status st = f.write(s); !st.ok()) return st;
  return f.commit();
}

namespace {

bool parse_double(std::string_view t, double* out) {
  while (!t.empty() && (t.front() == ' ' || t.front() == '\t')) t.remove_prefix(1);
  while (!t.empty() && (t.back() == ' ' || t.back() == '\t' || t.back() == '\r'))
    t.remove_suffix(1);
  if (t.empty()) return false;
  auto r = std::from_chars(t.data(), t.data() + t.size(), *out);
  return r.ec == std::errc() && r.ptr == t.data() + t.size();
}

std::vector<std::string_view> split(std::string_view line, char sep) {
  std::vector<std::string_view> out;
  std::size_t start = 0;
  for (;;) {
    const std::size_t p = line.find(sep, start);
    out.push_back(
        line.substr(start, p == std::string_view::npos ? std::string_view::npos : p - start));
    if (p == std::string_view::npos) break;
    start = p + 1;
  }
  return out;
}

}  // namespace

Result<Dataset> read_dataset_csv(const std::string& path) {
  Result<UniqueFd> fd = open_input_file(path, "dataset");
  if (!fd.ok()) return fd.error();
  LineReader lines(fd->get(), kMaxDatasetLineBytes);
  Dataset d;
  std::string line;
  uint64_t lineno = 0;
  auto err = [&](const std::string& what) {
    return make_error(ErrorCode::kParse, path + ":" + std::to_string(lineno) + ": " + what);
  };
  // The next line into `line`; false at the end. A line over the bound or a failed read is an
  // error (kept in `read_error`).
  std::optional<Error> read_error;
  auto next_line = [&]() -> bool {
    for (;;) {
      std::string_view v;
      switch (lines.next(&v)) {
        case LineReader::Status::kLine:
          lineno = lines.line_number();
          line.assign(v);
          if (lineno == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) line.erase(0, 3);  // UTF-8 BOM
          return true;
        case LineReader::Status::kTooLong:
          lineno = lines.line_number();
          read_error = err("longer than " + std::to_string(kMaxDatasetLineBytes) + " bytes");
          return false;
        case LineReader::Status::kError:
          read_error = make_error(ErrorCode::kIo, path + ": read failed after line " +
                                                      std::to_string(lineno) + ": " +
                                                      std::strerror(lines.error_number()));
          return false;
        case LineReader::Status::kWait:  // a signal interrupted the read: go on
          continue;
        case LineReader::Status::kEof:
          return false;
      }
    }
  };
  int declared_sensors = -1;
  std::map<int, DatasetSensor> layout;
  // Header block.
  std::vector<std::string_view> cols;
  std::string header_line;
  while (next_line()) {
    if (line.empty() || line == "\r") continue;
    if (line[0] != '#') {
      header_line = line;
      break;
    }
    const std::size_t colon = line.find(':');
    if (colon == std::string::npos) continue;  // a plain comment
    std::string key = line.substr(1, colon - 1);
    while (!key.empty() && key.front() == ' ') key.erase(0, 1);
    std::string value = line.substr(colon + 1);
    while (!value.empty() && (value.front() == ' ')) value.erase(0, 1);
    while (!value.empty() && (value.back() == '\r')) value.pop_back();
    if (key == "sensors") {
      double n;
      if (!parse_double(value, &n) || n < 1 || n > kMaxSensors || n != std::floor(n))
        return err("bad sensor count '" + value + "'");
      declared_sensors = static_cast<int>(n);
    } else if (key.rfind("sensor ", 0) == 0) {
      double idx;
      if (!parse_double(key.substr(7), &idx) || idx < 0 || idx >= kMaxSensors)
        return err("bad sensor index in '" + key + "'");
      DatasetSensor s;
      std::istringstream kv(value);
      std::string item;
      int found = 0;
      while (kv >> item) {
        const std::size_t eq = item.find('=');
        double x;
        if (eq == std::string::npos || !parse_double(item.substr(eq + 1), &x) ||
            !std::isfinite(x)) {
          return err("bad sensor position '" + item + "'");
        }
        const std::string k = item.substr(0, eq);
        if (k == "u_mm" || k == "x_mm") s.u_mm = x, ++found;
        if (k == "v_mm" || k == "y_mm") s.v_mm = x, ++found;
        if (k == "h_mm" || k == "z_mm") s.h_mm = x, ++found;
      }
      if (found < 2) return err("sensor position needs u_mm and v_mm");
      layout[static_cast<int>(idx)] = s;
    } else {
      d.meta[key] = value;
    }
  }
  if (read_error) return *read_error;
  if (header_line.empty()) return err("no column header line");
  if (d.meta.count("format") && d.meta["format"].rfind("skinbus-dataset 1", 0) != 0) {
    return err("unsupported format '" + d.meta["format"] +
               "' (this reader knows skinbus-dataset 1)");
  }
  cols = split(header_line, ',');
  // Map columns.
  int col_press = -1, col_t = -1, col_u = -1, col_v = -1, col_d = -1, col_f = -1;
  std::map<int, int> field_col;  // channel -> column
  std::vector<int> extra_cols;
  if (cols.size() > kMaxDatasetColumns) {
    return err(std::to_string(cols.size()) + " columns, more than the " +
               std::to_string(kMaxDatasetColumns) + " accepted");
  }
  // Every column once: a name twice (or u_mm and its alias x_mm) would silently let one column
  // replace the other.
  std::map<std::string, int> seen;  // canonical name -> column
  for (int c = 0; c < static_cast<int>(cols.size()); ++c) {
    std::string name(cols[c]);
    while (!name.empty() && (name.back() == '\r' || name.back() == ' ')) name.pop_back();
    while (!name.empty() && name.front() == ' ') name.erase(0, 1);
    const std::string canonical = name == "x_mm" ? "u_mm" : name == "y_mm" ? "v_mm" : name;
    if (!name.empty()) {
      if (auto [it, fresh] = seen.emplace(canonical, c); !fresh) {
        return err("column '" + name + "' (column " + std::to_string(c + 1) + ") repeats column " +
                   std::to_string(it->second + 1) + " ('" + std::string(cols[it->second]) + "')");
      }
    }
    unsigned sensor = 0;
    char axis = 0;
    int consumed = 0;
    if (name == "press")
      col_press = c;
    else if (name == "t_s")
      col_t = c;
    else if (name == "u_mm" || name == "x_mm")
      col_u = c;
    else if (name == "v_mm" || name == "y_mm")
      col_v = c;
    else if (name == "depth_mm")
      col_d = c;
    else if (name == "force_n")
      col_f = c;
    else if (std::sscanf(name.c_str(), "s%u_b%c_ut%n", &sensor, &axis, &consumed) == 2 &&
             consumed == static_cast<int>(name.size()) &&
             (axis == 'x' || axis == 'y' || axis == 'z') &&
             sensor < static_cast<unsigned>(kMaxSensors)) {
      const int ch = static_cast<int>(3 * sensor) + (axis - 'x');
      if (field_col.count(ch)) return err("column '" + name + "' appears twice");
      field_col[ch] = c;
    } else {
      if (name.empty()) return err("empty column name (column " + std::to_string(c + 1) + ")");
      d.extra_columns.push_back(name);
      extra_cols.push_back(c);
    }
  }
  if (col_u < 0 || col_v < 0 || col_d < 0)
    return err("missing one of the columns u_mm, v_mm, depth_mm");
  if (field_col.empty()) return err("no sensor columns (s<i>_b<x|y|z>_ut)");
  const int nsens = static_cast<int>(field_col.size() / 3);
  if (static_cast<int>(field_col.size()) != 3 * nsens ||
      field_col.rbegin()->first != 3 * nsens - 1) {
    return err("sensor columns must be s00..s" + std::to_string(nsens - 1) +
               " each with bx, by and bz");
  }
  if (declared_sensors >= 0 && declared_sensors != nsens) {
    return err("header says " + std::to_string(declared_sensors) +
               " sensors but the columns have " + std::to_string(nsens));
  }
  d.sensors.resize(nsens);
  for (const auto& [i, s] : layout) {
    if (i >= nsens) return err("sensor " + std::to_string(i) + " described but not in the columns");
    d.sensors[i] = s;
  }
  if (!layout.empty() && static_cast<int>(layout.size()) != nsens)
    return err("sensor layout lines missing for some sensors");
  d.sensor_layout_known = !layout.empty();

  // Rows.
  std::vector<double> row_field(3 * nsens);
  const std::size_t max_rows = kMaxDatasetCells / cols.size();
  while (next_line()) {
    if (line.empty() || line == "\r" || line[0] == '#') continue;
    if (d.rows() >= max_rows) {
      return err("more than " + std::to_string(max_rows) + " rows of " +
                 std::to_string(cols.size()) + " columns (" + std::to_string(kMaxDatasetCells) +
                 " values at most)");
    }
    const auto cells = split(line, ',');
    if (cells.size() != cols.size()) {
      return err("row has " + std::to_string(cells.size()) + " fields, the header " +
                 std::to_string(cols.size()));
    }
    auto num = [&](int c, double* x) -> bool {
      return parse_double(cells[c], x) && std::isfinite(*x);
    };
    double u, v, depth, t = 0, force = std::nan(""), press = -1;
    if (!num(col_u, &u) || !num(col_v, &v) || !num(col_d, &depth))
      return err("bad number in u_mm, v_mm or depth_mm");
    if (col_t >= 0 && !num(col_t, &t)) return err("bad number in t_s");
    if (col_f >= 0 && !parse_double(cells[col_f], &force)) return err("bad number in force_n");
    if (col_press >= 0 && (!num(col_press, &press) || press != std::floor(press)))
      return err("bad press number");
    for (const auto& [ch, c] : field_col) {
      if (!parse_double(cells[c], &row_field[ch])) {
        return err("bad number '" + std::string(cells[c]) + "' in column " + std::string(cols[c]));
      }
      // NaN is allowed (a dead channel in a lab recording); infinity is not.
      if (std::isinf(row_field[ch])) return err("infinite value in column " + std::string(cols[c]));
    }
    d.append(static_cast<int64_t>(press), t, u, v, depth, force, row_field.data());
    for (int c : extra_cols) {
      double x;
      if (!parse_double(cells[c], &x)) x = std::nan("");
      d.extra.push_back(x);
    }
  }
  if (read_error) return *read_error;
  if (d.rows() == 0) return err("no data rows");
  return d;
}

void record_in_press_frame(Dataset* d, const PressFrame& f) {
  const double c = std::cos(f.yaw_deg * M_PI / 180), s = std::sin(f.yaw_deg * M_PI / 180);
  for (std::size_t r = 0; r < d->rows(); ++r) {
    const double u = d->u_mm[r], v = d->v_mm[r];
    d->u_mm[r] = c * u - s * v + f.du_mm;
    d->v_mm[r] = s * u + c * v + f.dv_mm;
    d->depth_mm[r] += f.depth_zero_mm;
  }
}

uint64_t dataset_fingerprint(const Dataset& d) {
  uint64_t h = 1469598103934665603ull;
  auto mix = [&](double x) {
    uint64_t b;
    std::memcpy(&b, &x, sizeof b);
    for (int i = 0; i < 8; ++i) {
      h ^= (b >> (8 * i)) & 0xFF;
      h *= 1099511628211ull;
    }
  };
  for (std::size_t r = 0; r < d.rows(); ++r) {
    mix(d.u_mm[r]);
    mix(d.v_mm[r]);
    mix(d.depth_mm[r]);
  }
  for (double x : d.field_ut) mix(x);
  return h;
}

Status check_sensor_layout(const Dataset& d, const PatchModel& model, double tolerance_mm) {
  // The surface the recording names (its `geometry:` header, when it has one): a cylinder's
  // presses read on a flat design (or on another radius) are placed on the wrong surface.
  if (const auto it = d.meta.find("geometry"); it != d.meta.end()) {
    const std::string& g = it->second;
    const PatchDesign& des = model.design();
    const bool cylinder = g.rfind("cylinder", 0) == 0, flat = g.rfind("flat", 0) == 0;
    double radius_mm = std::nan("");
    if (const std::optional<std::string_view> r = header_field(d, "geometry", "radius_mm")) {
      radius_mm = std::strtod(std::string(*r).c_str(), nullptr);
    }
    const bool design_cylinder = des.surface == SurfaceKind::kCylinder;
    char text[256];
    if ((cylinder && !design_cylinder) || (flat && design_cylinder)) {
      std::snprintf(text, sizeof text,
                    "the recording's geometry header says %s, the design a %s surface: give the "
                    "patch's own design file",
                    g.c_str(), design_cylinder ? "cylinder" : "flat");
      return make_error(ErrorCode::kInvalidArgument, text);
    }
    if (cylinder && std::isfinite(radius_mm) &&
        std::fabs(radius_mm - des.radius_mm) > 0.02 * des.radius_mm) {
      std::snprintf(text, sizeof text,
                    "the recording's geometry header says a cylinder of radius %g mm, the design "
                    "%g mm: give the patch's own design file",
                    radius_mm, des.radius_mm);
      return make_error(ErrorCode::kInvalidArgument, text);
    }
  }
  if (!d.sensor_layout_known) return Status::Ok();
  const auto& sensors = model.sensors();
  if (d.sensors.size() != sensors.size()) {
    return make_error(ErrorCode::kInvalidArgument, std::to_string(d.sensors.size()) +
                                                       " sensors, the design has " +
                                                       std::to_string(sensors.size()));
  }
  for (std::size_t i = 0; i < sensors.size(); ++i) {
    const DatasetSensor& r = d.sensors[i];
    if (std::hypot(r.u_mm - sensors[i].u, r.v_mm - sensors[i].v) > tolerance_mm) {
      char text[256];
      std::snprintf(text, sizeof text,
                    "sensor %zu is at u_mm=%.1f v_mm=%.1f in the recording's header, at u_mm=%.1f "
                    "v_mm=%.1f in the design: the recording lists its sensors in another order "
                    "than the design file, or is of another patch",
                    i, r.u_mm, r.v_mm, sensors[i].u, sensors[i].v);
      return make_error(ErrorCode::kInvalidArgument, text);
    }
  }
  return Status::Ok();
}

std::optional<std::string_view> header_field(const Dataset& d, std::string_view meta_key,
                                             std::string_view key) {
  const auto it = d.meta.find(std::string(meta_key));
  if (it == d.meta.end()) return std::nullopt;
  const std::string_view line = it->second;
  const std::string tag = std::string(key) + "=";
  std::size_t at = 0;
  while ((at = line.find(tag, at)) != std::string_view::npos && at > 0 &&
         std::isspace(static_cast<unsigned char>(line[at - 1])) == 0) {
    at += tag.size();
  }
  if (at == std::string_view::npos) return std::nullopt;
  const std::size_t begin = at + tag.size();
  const std::size_t end = std::min(line.find_first_of(" \t\r", begin), line.size());
  return line.substr(begin, end - begin);
}

Result<std::optional<double>> recorded_tip_radius_mm(const Dataset& d) {
  const std::optional<std::string_view> field = header_field(d, "protocol", "tip_radius_mm");
  if (!field) return std::optional<double>{};
  const std::string text(*field);
  double tip = std::nan("");
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), tip);
  if (ec != std::errc() || ptr != text.data() + text.size() || !std::isfinite(tip) || tip < 0 ||
      tip > kMaxIndenterTipRadiusMm) {
    char range[48];
    std::snprintf(range, sizeof range, "' is not a tip radius (0 to %g mm)",
                  kMaxIndenterTipRadiusMm);
    return make_error(ErrorCode::kParse, "protocol header: tip_radius_mm='" + text + range);
  }
  return std::optional<double>{tip};
}

Result<double> presses_tip_radius_mm(const Dataset& d, const PatchDesign& design,
                                     std::string* from) {
  Result<std::optional<double>> recorded = recorded_tip_radius_mm(d);
  if (!recorded.ok()) return recorded.error();
  if (from != nullptr) {
    *from = recorded->has_value() ? "the recording's protocol header" : "the design's indenter";
  }
  return recorded->value_or(design.indenter_tip_radius_mm);
}

}  // namespace skinbus::sim
