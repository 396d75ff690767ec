#include "skinbus/estimators/model_file.h"

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/json_text.h"
#include "skinbus/common/text_file.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

namespace skinbus::estimators {
namespace {

using nlohmann::json;

constexpr int kSeedConv[] = {32, 64, 128, 256};
constexpr int kSeedHidden[] = {512, 256, 128, 64};
// Largest safetensors header accepted (bytes): far above any per-patch model's.
constexpr uint64_t kMaxHeaderBytes = 1u << 24;
// Bounds of what a per-patch model may be (validate_model): far above any useful network, low
// enough that every size computed from them fits and every buffer stays small.
constexpr int kMaxGridSide = 64;
constexpr int kMaxWidth = 8192;
constexpr std::size_t kMaxLayers = 32;
constexpr std::size_t kMaxSensors = 256;

int scaled(int base, double width) {
  return std::max(1, static_cast<int>(std::lround(base * width)));
}

const char* kind_name(ArchitectureKind k) {
  return k == ArchitectureKind::kCnn ? "cnn" : "mlp";
}

Error file_error(const std::string& file, const std::string& what) {
  return make_error(ErrorCode::kParse, file + ": " + what);
}

// The largest weight file read (bytes): the largest tensors validate_model allows, and more.
constexpr uint64_t kMaxWeightBytes = 1ull << 30;

// The metadata format this writer produces: 2 carries the weights' fingerprint.
constexpr int kModelVersion = 2;

// The weights' fingerprint as the metadata holds it.
std::string weights_fingerprint(std::string_view weights) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "fnv1a64:%016llx",
                static_cast<unsigned long long>(fnv1a64(weights)));
  return buf;
}

// The header length a safetensors file states (0 when it is too short to state one).
std::size_t header_bytes(std::string_view b) {
  if (b.size() < 8) return 0;
  uint64_t n = 0;
  for (int i = 7; i >= 0; --i) n = (n << 8) | static_cast<uint8_t>(b[static_cast<std::size_t>(i)]);
  return static_cast<std::size_t>(std::min<uint64_t>(n, b.size() - 8));
}

// Parses JSON text; a syntax error (or a number no double holds, 1e400) names the line and what
// the parser found instead of a bare "not a JSON object".
Result<json> parse_json(std::string_view text, const std::string& file) {
  Result<json> j = parse_json_text(text);
  if (!j.ok()) return file_error(file, j.error().message);
  return j;
}

}  // namespace

Architecture seed_cnn(double width, int grid_rows, int grid_cols) {
  Architecture a;
  a.kind = ArchitectureKind::kCnn;
  a.width = width;
  for (int c : kSeedConv) a.conv_channels.push_back(scaled(c, width));
  for (int h : kSeedHidden) a.hidden.push_back(scaled(h, width));
  a.grid_rows = grid_rows;
  a.grid_cols = grid_cols;
  return a;
}

Architecture mlp(std::vector<int> hidden) {
  Architecture a;
  a.kind = ArchitectureKind::kMlp;
  a.hidden = std::move(hidden);
  return a;
}

int64_t Tensor::numel() const {
  int64_t n = 1;
  for (int64_t d : shape) n *= d;
  return n;
}

const Tensor* ModelFile::find(const std::string& name) const {
  for (const Tensor& t : tensors) {
    if (t.name == name) return &t;
  }
  return nullptr;
}

std::vector<Tensor> expected_tensors(const Architecture& a, int channels, int outputs) {
  std::vector<Tensor> out;
  auto add = [&](std::string name, std::vector<int64_t> shape) {
    out.push_back(Tensor{std::move(name), std::move(shape), {}});
  };
  int in = channels;
  if (a.kind == ArchitectureKind::kCnn) {
    int c = 3;
    for (std::size_t k = 0; k < a.conv_channels.size(); ++k) {
      const int o = a.conv_channels[k];
      add("conv" + std::to_string(k) + ".weight", {o, c, 3, 3});
      add("conv" + std::to_string(k) + ".bias", {o});
      c = o;
    }
    in = 2 * c;
  }
  for (std::size_t k = 0; k < a.hidden.size(); ++k) {
    add("fc" + std::to_string(k) + ".weight", {a.hidden[k], in});
    add("fc" + std::to_string(k) + ".bias", {a.hidden[k]});
    in = a.hidden[k];
  }
  add("head.weight", {outputs, in});
  add("head.bias", {outputs});
  return out;
}

int64_t ModelFile::parameters() const {
  int64_t n = 0;
  for (const Tensor& t : tensors) n += t.numel();
  return n;
}

int64_t ModelFile::macs() const {
  const Architecture& a = meta.architecture;
  int64_t total = 0;
  int in = meta.channels();
  if (a.kind == ArchitectureKind::kCnn) {
    // In-bounds taps of a 3x3 same-padded convolution over the grid.
    int64_t taps = 0;
    for (int r = 0; r < a.grid_rows; ++r) {
      for (int c = 0; c < a.grid_cols; ++c) {
        const int rows = std::min(r + 1, a.grid_rows - 1) - std::max(r - 1, 0) + 1;
        const int cols = std::min(c + 1, a.grid_cols - 1) - std::max(c - 1, 0) + 1;
        taps += rows * cols;
      }
    }
    int ch = 3;
    for (int o : a.conv_channels) {
      total += taps * ch * o;
      ch = o;
    }
    in = 2 * ch;
  }
  for (int h : a.hidden) {
    total += static_cast<int64_t>(in) * h;
    in = h;
  }
  total += static_cast<int64_t>(in) * static_cast<int64_t>(meta.outputs.size());
  return total;
}

Status validate_model(const ModelFile& model) {
  const ModelMeta& m = model.meta;
  const Architecture& a = m.architecture;
  auto bad = [](const std::string& what) { return make_error(ErrorCode::kInvalidArgument, what); };
  if (m.sensors.empty()) return bad("model has no sensors");
  if (m.sensors.size() > kMaxSensors) return bad("model has more than 256 sensors");
  if (a.conv_channels.size() > kMaxLayers || a.hidden.size() > kMaxLayers) {
    return bad("model has more than 32 conv or hidden layers");
  }
  for (const std::vector<int>* widths : {&a.conv_channels, &a.hidden}) {
    for (int w : *widths) {
      if (w <= 0 || w > kMaxWidth) return bad("layer width must be in 1..8192");
    }
  }
  const int channels = m.channels();
  if (static_cast<int>(m.input_mean.size()) != channels ||
      static_cast<int>(m.input_scale.size()) != channels) {
    return bad("input_mean/input_scale need one entry per channel (" + std::to_string(channels) +
               ")");
  }
  if (m.outputs.size() > 16) return bad("model has more than 16 outputs");
  if (m.outputs.empty() || m.output_mean.size() != m.outputs.size() ||
      m.output_scale.size() != m.outputs.size()) {
    return bad("output_mean/output_scale need one entry per output");
  }
  for (std::size_t i = 0; i < m.input_scale.size(); ++i) {
    if (!std::isfinite(m.input_mean[i]) || !std::isfinite(m.input_scale[i]) ||
        !(m.input_scale[i] > 0)) {
      return bad("input normalisation of channel " + std::to_string(i) +
                 " is not finite or its scale is not positive");
    }
  }
  for (std::size_t j = 0; j < m.output_scale.size(); ++j) {
    if (!std::isfinite(m.output_mean[j]) || !std::isfinite(m.output_scale[j]) ||
        !(m.output_scale[j] > 0)) {
      return bad("output normalisation of '" + m.outputs[j] + "' is not finite or not positive");
    }
  }
  if (!(m.half_u_mm > 0) || !(m.half_v_mm > 0) || !(m.max_depth_mm > 0)) {
    return bad("patch extent (half_u_mm, half_v_mm, max_depth_mm) must be positive");
  }
  for (int h : a.hidden) {
    if (h <= 0) return bad("hidden layer width must be positive");
  }
  if (a.kind == ArchitectureKind::kCnn) {
    if (a.conv_channels.empty()) return bad("a CNN needs at least one conv layer");
    for (int c : a.conv_channels) {
      if (c <= 0) return bad("conv channel count must be positive");
    }
    if (a.grid_rows <= 0 || a.grid_cols <= 0 || a.grid_rows > kMaxGridSide ||
        a.grid_cols > kMaxGridSide) {
      return bad("a CNN needs a grid of 1..64 rows and columns");
    }
    if (a.sensor_cell.size() != m.sensors.size()) {
      return bad("sensor_cell needs one cell per sensor");
    }
    std::set<int> cells;
    for (int cell : a.sensor_cell) {
      if (cell < 0 || cell >= a.grid_rows * a.grid_cols || !cells.insert(cell).second) {
        return bad("sensor_cell " + std::to_string(cell) + " is outside the grid or used twice");
      }
    }
  }
  const std::vector<Tensor> want =
      expected_tensors(a, channels, static_cast<int>(m.outputs.size()));
  if (want.size() != model.tensors.size()) {
    return bad("model has " + std::to_string(model.tensors.size()) +
               " tensors, architecture needs " + std::to_string(want.size()));
  }
  for (const Tensor& w : want) {
    const Tensor* t = model.find(w.name);
    if (t == nullptr) return bad("tensor '" + w.name + "' is missing");
    if (t->shape != w.shape) return bad("tensor '" + w.name + "' has the wrong shape");
    if (static_cast<int64_t>(t->data.size()) != t->numel()) {
      return bad("tensor '" + w.name + "' has the wrong number of values");
    }
    for (float v : t->data) {
      if (!std::isfinite(v)) return bad("tensor '" + w.name + "' holds a non-finite value");
    }
  }
  return Status::Ok();
}

std::string model_stem(const std::string& path) {
  for (const char* ext : {".json", ".safetensors"}) {
    const std::size_t n = std::strlen(ext);
    if (path.size() > n && path.compare(path.size() - n, n, ext) == 0) {
      return path.substr(0, path.size() - n);
    }
  }
  return path;
}

Status write_model(const ModelFile& model, const std::string& path) {
  if (Status s = validate_model(model); !s.ok()) return s;
  const std::string stem = model_stem(path);
  const ModelMeta& m = model.meta;
  // Weights: safetensors.
  json header = json::object();
  uint64_t offset = 0;
  for (const Tensor& t : model.tensors) {
    const uint64_t bytes = static_cast<uint64_t>(t.data.size()) * sizeof(float);
    header[t.name] = {
        {"dtype", "F32"}, {"shape", t.shape}, {"data_offsets", {offset, offset + bytes}}};
    offset += bytes;
  }
  // The format version in the weights too: a reader then tells these weights from an older
  // writer's, whose metadata carries no fingerprint.
  header["__metadata__"] = {{"format", "pt"},
                            {"skinbus_model", m.name},
                            {"skinbus_model_version", std::to_string(kModelVersion)}};
  std::string text = header.dump();
  while (text.size() % 8 != 0) text.push_back(' ');
  std::string weights;
  weights.reserve(8 + text.size() + static_cast<std::size_t>(offset));
  const uint64_t n = text.size();
  for (int i = 0; i < 8; ++i) weights.push_back(static_cast<char>(n >> (8 * i)));
  weights += text;
  for (const Tensor& t : model.tensors) {
    for (float v : t.data) {  // little endian on every supported host; written byte by byte
      uint32_t u;
      std::memcpy(&u, &v, 4);
      for (int i = 0; i < 4; ++i) weights.push_back(static_cast<char>(u >> (8 * i)));
    }
  }
  // Metadata: JSON.
  const Architecture& a = m.architecture;
  json arch = {{"kind", kind_name(a.kind)}, {"hidden", a.hidden}, {"width", a.width}};
  if (a.kind == ArchitectureKind::kCnn) {
    arch["conv_channels"] = a.conv_channels;
    arch["grid_rows"] = a.grid_rows;
    arch["grid_cols"] = a.grid_cols;
    arch["sensor_cell"] = a.sensor_cell;
  }
  json sensors = json::array();
  for (const SensorPosition& s : m.sensors) sensors.push_back({s.u_mm, s.v_mm, s.h_mm});
  json meta = {
      {"format", "skinbus-model"},
      {"version", kModelVersion},
      {"weights_fingerprint", weights_fingerprint(weights)},
      {"name", m.name},
      {"architecture", arch},
      {"weights", stem.substr(stem.find_last_of('/') + 1) + ".safetensors"},
      {"units",
       {{"input", "uT, tared, each sensor's own frame"},
        {"u_mm", "mm"},
        {"v_mm", "mm"},
        {"depth_mm", "mm, positive into the skin"},
        {"force_n", "N"}}},
      {"sensors_uvh_mm", sensors},
      {"input_mean", m.input_mean},
      {"input_scale", m.input_scale},
      {"outputs", m.outputs},
      {"output_mean", m.output_mean},
      {"output_scale", m.output_scale},
      {"half_u_mm", m.half_u_mm},
      {"half_v_mm", m.half_v_mm},
      {"max_depth_mm", m.max_depth_mm},
      {"data_fingerprint", m.data_fingerprint},
      {"info", m.info},
      {"metrics", m.metrics},
      {"parameters", model.parameters()},
      {"macs", model.macs()},
  };
  // Both files to temporary names, each written, checked and synced; then renamed one after the
  // other. Whenever it stops, a reader finds the old pair, the new pair, or a mixed pair that
  // the fingerprint refuses: never new weights read with old metadata.
  AtomicFile weights_file, meta_file;
  for (Status s :
       {weights_file.open(stem + ".safetensors", "model weights"), weights_file.write(weights),
        weights_file.finish(), meta_file.open(stem + ".json", "model metadata"),
        meta_file.write(meta.dump(2) + "\n"), meta_file.finish(), weights_file.rename_into_place(),
        meta_file.rename_into_place()}) {
    if (!s.ok()) return s;
  }
  return Status::Ok();
}

namespace {

Status parse_weights(std::string_view b, const std::string& file, ModelFile& model) {
  if (b.size() < 8) return file_error(file, "shorter than the 8-byte header length");
  uint64_t n = 0;
  for (int i = 7; i >= 0; --i) n = (n << 8) | static_cast<uint8_t>(b[static_cast<std::size_t>(i)]);
  if (n > kMaxHeaderBytes || n > b.size() - 8) {
    return file_error(file, "header length " + std::to_string(n) + " exceeds the file");
  }
  Result<json> parsed = parse_json(b.substr(8, static_cast<std::size_t>(n)), file + " header");
  if (!parsed.ok()) return parsed.error();
  json header = std::move(parsed).value();
  if (!header.is_object()) return file_error(file, "header is not a JSON object");
  const uint64_t data_bytes = b.size() - 8 - n;
  const char* data = b.data() + 8 + n;
  std::vector<std::pair<uint64_t, uint64_t>> ranges;
  for (auto it = header.begin(); it != header.end(); ++it) {
    if (it.key() == "__metadata__") continue;
    const json& t = it.value();
    if (!t.is_object() || !t.contains("dtype") || !t.contains("shape") ||
        !t.contains("data_offsets")) {
      return file_error(file, "tensor '" + it.key() + "' lacks dtype, shape or data_offsets");
    }
    if (t["dtype"] != "F32") {
      return file_error(file, "tensor '" + it.key() + "' is not F32 (only F32 is supported)");
    }
    Tensor tensor;
    tensor.name = it.key();
    const json& shape = t["shape"];
    const json& off = t["data_offsets"];
    if (!shape.is_array() || !off.is_array() || off.size() != 2 || !off[0].is_number_unsigned() ||
        !off[1].is_number_unsigned()) {
      return file_error(file, "tensor '" + it.key() + "' has a malformed shape or data_offsets");
    }
    uint64_t numel = 1;
    for (const json& d : shape) {
      if (!d.is_number_unsigned() || d.get<uint64_t>() > (1u << 24)) {
        return file_error(file, "tensor '" + it.key() + "' has a bad dimension");
      }
      numel *= d.get<uint64_t>();
      if (numel > (1u << 26)) return file_error(file, "tensor '" + it.key() + "' is too large");
      tensor.shape.push_back(d.get<int64_t>());
    }
    const uint64_t begin = off[0].get<uint64_t>(), end = off[1].get<uint64_t>();
    if (begin > end || end > data_bytes || end - begin != numel * 4) {
      return file_error(file, "tensor '" + it.key() + "' data range [" + std::to_string(begin) +
                                  ", " + std::to_string(end) + ") does not fit its shape or the " +
                                  std::to_string(data_bytes) + "-byte data block");
    }
    ranges.emplace_back(begin, end);
    tensor.data.resize(numel);
    for (uint64_t i = 0; i < numel; ++i) {
      const auto* p = reinterpret_cast<const uint8_t*>(data + begin + 4 * i);
      const uint32_t u = static_cast<uint32_t>(p[0]) | static_cast<uint32_t>(p[1]) << 8 |
                         static_cast<uint32_t>(p[2]) << 16 | static_cast<uint32_t>(p[3]) << 24;
      std::memcpy(&tensor.data[i], &u, 4);
    }
    model.tensors.push_back(std::move(tensor));
  }
  std::sort(ranges.begin(), ranges.end());
  for (std::size_t i = 1; i < ranges.size(); ++i) {
    if (ranges[i].first < ranges[i - 1].second) return file_error(file, "tensor data overlap");
  }
  return Status::Ok();
}

template <typename T>
bool get_to(const json& j, const char* key, T& out) {
  if (!j.contains(key)) return false;
  try {
    out = j.at(key).get<T>();
  } catch (const json::exception&) {
    return false;
  }
  return true;
}

}  // namespace

Result<ModelFile> read_model(const std::string& path) {
  const std::string stem = model_stem(path);
  Result<std::string> text = read_text_file(stem + ".json", "model metadata");
  if (!text.ok()) return text.error();
  Result<std::string> weights =
      read_text_file(stem + ".safetensors", "model weights", kMaxWeightBytes);
  if (!weights.ok()) return weights.error();
  return parse_model(text.value(), weights.value(), stem);
}

namespace {

Result<ModelFile> parse_model_unguarded(std::string_view metadata_json, std::string_view weights,
                                        const std::string& stem) {
  const std::string meta_file = stem + ".json";
  Result<json> parsed = parse_json(metadata_json, meta_file);
  if (!parsed.ok()) return parsed.error();
  json j = std::move(parsed).value();
  if (!j.is_object()) return file_error(meta_file, "not a JSON object");
  std::string format;
  if (!get_to(j, "format", format) || format != "skinbus-model") {
    return file_error(meta_file, "\"format\" is not \"skinbus-model\"");
  }
  // The pair must be one write's: version 2 metadata names its weights' fingerprint; version 1
  // metadata (an older writer's, without one) is read only with weights of that writer too.
  int version = 1;
  if (j.contains("version") && !get_to(j, "version", version)) {
    return file_error(meta_file, "\"version\" is not a number");
  }
  if (version < 1 || version > kModelVersion) {
    return file_error(meta_file, "version " + std::to_string(version) +
                                     " (this reader knows 1 to " + std::to_string(kModelVersion) +
                                     ")");
  }
  ModelFile model;
  ModelMeta& m = model.meta;
  auto need = [&](const char* key, auto& out) -> Status {
    if (!get_to(j, key, out)) {
      return file_error(meta_file, std::string("missing or malformed \"") + key + "\"");
    }
    return Status::Ok();
  };
  const json* arch = j.contains("architecture") ? &j["architecture"] : nullptr;
  if (arch == nullptr || !arch->is_object())
    return file_error(meta_file, "missing \"architecture\"");
  std::string kind;
  Architecture& a = m.architecture;
  if (!get_to(*arch, "kind", kind) || (kind != "cnn" && kind != "mlp")) {
    return file_error(meta_file, "architecture.kind must be \"cnn\" or \"mlp\"");
  }
  a.kind = kind == "cnn" ? ArchitectureKind::kCnn : ArchitectureKind::kMlp;
  if (!get_to(*arch, "hidden", a.hidden)) return file_error(meta_file, "architecture.hidden");
  get_to(*arch, "width", a.width);
  if (a.kind == ArchitectureKind::kCnn &&
      (!get_to(*arch, "conv_channels", a.conv_channels) ||
       !get_to(*arch, "grid_rows", a.grid_rows) || !get_to(*arch, "grid_cols", a.grid_cols) ||
       !get_to(*arch, "sensor_cell", a.sensor_cell))) {
    return file_error(meta_file, "a CNN needs conv_channels, grid_rows, grid_cols and sensor_cell");
  }
  std::vector<std::vector<double>> sensors;
  for (Status s : {need("name", m.name), need("sensors_uvh_mm", sensors),
                   need("input_mean", m.input_mean), need("input_scale", m.input_scale),
                   need("outputs", m.outputs), need("output_mean", m.output_mean),
                   need("output_scale", m.output_scale), need("half_u_mm", m.half_u_mm),
                   need("half_v_mm", m.half_v_mm), need("max_depth_mm", m.max_depth_mm)}) {
    if (!s.ok()) return s.error();
  }
  for (const auto& s : sensors) {
    if (s.size() != 3) return file_error(meta_file, "each sensor needs [u_mm, v_mm, h_mm]");
    m.sensors.push_back({s[0], s[1], s[2]});
  }
  get_to(j, "data_fingerprint", m.data_fingerprint);
  get_to(j, "info", m.info);
  get_to(j, "metrics", m.metrics);
  if (Status s = parse_weights(weights, stem + ".safetensors", model); !s.ok()) return s.error();
  const std::string weights_file = stem + ".safetensors";
  if (version >= 2) {
    std::string want;
    if (!get_to(j, "weights_fingerprint", want)) {
      return file_error(meta_file, "missing or malformed \"weights_fingerprint\"");
    }
    const std::string got = weights_fingerprint(weights);
    if (got != want) {
      return file_error(weights_file,
                        "does not match its metadata (fingerprint " + got + ", " + meta_file +
                            " names " + want +
                            "): the two files come from different writes (a training run "
                            "stopped between them, or one file copied alone); write both again");
    }
  } else if (weights.substr(0, 8 + header_bytes(weights)).find("\"skinbus_model_version\"") !=
             std::string_view::npos) {
    return file_error(weights_file,
                      "was written with a fingerprint that " + meta_file +
                          " (version 1) does not carry: the two files come from different "
                          "writes; write both again");
  }

  if (Status s = validate_model(model); !s.ok()) {
    return make_error(ErrorCode::kParse, stem + ": " + s.error().message);
  }
  return model;
}

}  // namespace

Result<ModelFile> parse_model(std::string_view metadata_json, std::string_view weights,
                              const std::string& name) {
  // The parser checks types before reading; this is the net under it, so that no exception
  // leaves the library whatever the files hold.
  try {
    return parse_model_unguarded(metadata_json, weights, name);
  } catch (const std::exception& e) {
    return make_error(ErrorCode::kParse, name + ": malformed model (" + e.what() + ")");
  }
}

}  // namespace skinbus::estimators
