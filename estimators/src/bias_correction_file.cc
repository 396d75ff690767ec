// Correction files: a BiasCorrection as JSON ("skinbus-correction 1").
#include <cmath>
#include <string>
#include <utility>

#include "skinbus/common/atomic_file.h"
#include "skinbus/common/json_text.h"
#include "skinbus/common/text_file.h"
#include "skinbus/estimators/bias_correction.h"

namespace skinbus::estimators {
namespace {

using json = nlohmann::json;

constexpr const char* kFormat = "skinbus-correction";
constexpr int kMajorVersion = 1;

// The first problem of a document read field by field, with the field's name.
class Reader {
 public:
  bool ok() const { return error_.empty(); }
  const std::string& error() const { return error_; }
  void fail(const std::string& what) {
    if (ok()) error_ = what;
  }
  double number(const json& j, const char* key, const std::string& where) {
    if (!ok()) return 0;
    const auto it = j.find(key);
    if (it == j.end() || !it->is_number() || !std::isfinite(it->get<double>())) {
      fail(where + key + (it == j.end() ? " is missing" : " is not a finite number"));
      return 0;
    }
    return it->get<double>();
  }
  double positive(const json& j, const char* key, const std::string& where) {
    const double v = number(j, key, where);
    if (ok() && !(v > 0)) fail(where + key + " must be positive");
    return v;
  }
  int integer(const json& j, const char* key, const std::string& where, int lo, int hi) {
    if (!ok()) return 0;
    const auto it = j.find(key);
    if (it == j.end() || !it->is_number_integer() || it->get<long long>() < lo ||
        it->get<long long>() > hi) {
      fail(where + key + " must be an integer from " + std::to_string(lo) + " to " +
           std::to_string(hi));
      return 0;
    }
    return static_cast<int>(it->get<long long>());
  }
  bool boolean(const json& j, const char* key, const std::string& where) {
    if (!ok()) return false;
    const auto it = j.find(key);
    if (it == j.end() || !it->is_boolean()) {
      fail(where + key + " must be true or false");
      return false;
    }
    return it->get<bool>();
  }
  // `count` finite numbers at j[key], appended to `out`.
  void numbers(const json& j, const char* key, const std::string& where, std::size_t count,
               std::vector<double>* out) {
    if (!ok()) return;
    const auto it = j.find(key);
    if (it == j.end() || !it->is_array() || it->size() != count) {
      fail(where + key + " must be an array of " + std::to_string(count) +
           " numbers (the basis size of the degrees)");
      return;
    }
    for (std::size_t i = 0; i < count; ++i) {
      const json& x = (*it)[i];
      if (!x.is_number() || !std::isfinite(x.get<double>())) {
        fail(where + key + "[" + std::to_string(i) + "] is not a finite number");
        return;
      }
      out->push_back(x.get<double>());
    }
  }

 private:
  std::string error_;
};

}  // namespace

std::string BiasCorrection::to_json(const CorrectionCheck* check, std::string_view source) const {
  const BiasCorrectionOptions& o = options_;
  json j;
  j["format"] = json_format_name(kFormat, kMajorVersion);
  j["source"] = std::string(source);
  j["options"] = {{"degree_uv", o.degree_uv},
                  {"degree_depth", o.degree_depth},
                  {"min_depth_mm", o.min_depth_mm},
                  {"half_u_mm", o.half_u_mm},
                  {"half_v_mm", o.half_v_mm},
                  {"max_depth_mm", o.max_depth_mm},
                  {"correct_position", o.correct_position},
                  {"correct_depth", o.correct_depth}};
  // Written only when the depth has a degree of its own (files without it read as the same).
  if (o.depth_uv() != o.degree_uv) j["options"]["depth_degree_uv"] = o.depth_uv();
  j["samples"] = samples_;
  j["rms_correction_mm"] = rms_correction_mm_;
  const auto t = static_cast<std::ptrdiff_t>(terms_);
  const auto part = [&](int k) {
    return std::vector<double>(coef_.begin() + k * t, coef_.begin() + (k + 1) * t);
  };
  j["coefficients"] = {{"u_mm", part(0)},
                       {"v_mm", part(1)},
                       {"depth_mm", std::vector<double>(coef_.begin() + 2 * t, coef_.end())}};
  if (check != nullptr) {
    j["held_out_check"] = {{"samples", check->samples},
                           {"xy_mean_without_mm", check->xy_mean_without_mm},
                           {"xy_mean_with_mm", check->xy_mean_with_mm},
                           {"explained", check->explained},
                           {"depth_mean_without_mm", check->depth_mean_without_mm},
                           {"depth_mean_with_mm", check->depth_mean_with_mm},
                           {"new_press_share", check->new_press_share},
                           {"xy_ratio_new_presses", check->xy_ratio()},
                           {"depth_ratio_new_presses", check->depth_ratio()}};
  }
  // nlohmann::json writes doubles with 17 significant digits: the round trip is exact.
  return j.dump(1) + "\n";
}

Status BiasCorrection::write(const std::string& path, const CorrectionCheck* check,
                             std::string_view source) const {
  return write_file_atomic(path, to_json(check, source), "correction file");
}

Result<BiasCorrection> BiasCorrection::parse(std::string_view text, std::string* source) {
  Result<json> doc = parse_json_document(text, kFormat, kMajorVersion, "correction file");
  if (!doc.ok()) return doc.error();
  const json& j = *doc;
  Reader r;
  BiasCorrection c;
  BiasCorrectionOptions& o = c.options_;
  const auto opts = j.find("options");
  if (opts == j.end() || !opts->is_object()) return make_error(ErrorCode::kParse, "no options");
  const std::string w = "options.";
  o.degree_uv = r.integer(*opts, "degree_uv", w, 0, kMaxDegreeUv);
  o.degree_depth = r.integer(*opts, "degree_depth", w, 0, kMaxDegreeDepth);
  if (opts->contains("depth_degree_uv")) {
    o.depth_degree_uv = r.integer(*opts, "depth_degree_uv", w, 0, kMaxDegreeUv);
  }
  o.min_depth_mm = r.number(*opts, "min_depth_mm", w);
  o.half_u_mm = r.positive(*opts, "half_u_mm", w);
  o.half_v_mm = r.positive(*opts, "half_v_mm", w);
  o.max_depth_mm = r.positive(*opts, "max_depth_mm", w);
  o.correct_position = r.boolean(*opts, "correct_position", w);
  o.correct_depth = r.boolean(*opts, "correct_depth", w);
  c.samples_ = r.integer(j, "samples", "", 0, 1 << 30);
  c.rms_correction_mm_ = r.number(j, "rms_correction_mm", "");
  if (!r.ok()) return make_error(ErrorCode::kParse, r.error());
  c.size_terms();
  const auto coef = j.find("coefficients");
  if (coef == j.end() || !coef->is_object()) {
    return make_error(ErrorCode::kParse, "coefficients must be an object (u_mm, v_mm, depth_mm)");
  }
  const auto t = static_cast<std::size_t>(c.terms_);
  c.coef_.reserve(2 * t + static_cast<std::size_t>(c.depth_terms_));
  r.numbers(*coef, "u_mm", "coefficients.", t, &c.coef_);
  r.numbers(*coef, "v_mm", "coefficients.", t, &c.coef_);
  r.numbers(*coef, "depth_mm", "coefficients.", static_cast<std::size_t>(c.depth_terms_), &c.coef_);
  if (!r.ok()) return make_error(ErrorCode::kParse, r.error());
  if (source != nullptr) {
    const auto it = j.find("source");
    *source = it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
  }
  return c;
}

Result<BiasCorrection> BiasCorrection::read(const std::string& path, std::string* source) {
  Result<std::string> text = read_text_file(path, "correction file", 16u << 20);
  if (!text.ok()) return text.error();
  Result<BiasCorrection> c = parse(*text, source);
  if (!c.ok()) {
    return make_error(c.error().code, "correction file " + path + ": " + c.error().message);
  }
  return c;
}

}  // namespace skinbus::estimators
