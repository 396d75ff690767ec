// Fuzzes the model file reader: the input is split at its first NUL byte into the metadata JSON
// and the safetensors weights (no NUL: metadata alone, empty weights).
// Invariants beyond "does not crash": a model that parses validates, and writing it and reading
// it back gives the same tensors bit for bit and the same normalisation.
#include <unistd.h>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <string_view>

#include "skinbus/estimators/model_file.h"

using namespace skinbus;
using namespace skinbus::estimators;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view all(reinterpret_cast<const char*>(data), size);
  const std::size_t nul = all.find('\0');
  const std::string_view meta = all.substr(0, nul);
  const std::string_view weights =
      nul == std::string_view::npos ? std::string_view() : all.substr(nul + 1);
  Result<ModelFile> m = parse_model(meta, weights, "fuzz");
  if (!m.ok()) return 0;
  if (!validate_model(*m).ok()) {
    std::fprintf(stderr, "fuzz_model_file: a parsed model does not validate\n");
    std::abort();
  }
  const std::string stem =
      (std::filesystem::temp_directory_path() / ("fuzz_model_" + std::to_string(getpid())))
          .string();
  if (!write_model(*m, stem).ok()) return 0;
  Result<ModelFile> back = read_model(stem);
  if (!back.ok() || back->tensors.size() != m->tensors.size() ||
      back->meta.input_mean != m->meta.input_mean ||
      back->meta.output_scale != m->meta.output_scale) {
    std::fprintf(stderr, "fuzz_model_file: round trip differs\n");
    std::abort();
  }
  for (const Tensor& t : m->tensors) {
    const Tensor* u = back->find(t.name);
    if (u == nullptr || u->shape != t.shape ||
        std::memcmp(u->data.data(), t.data.data(), t.data.size() * sizeof(float)) != 0) {
      std::fprintf(stderr, "fuzz_model_file: tensor %s differs after the round trip\n",
                   t.name.c_str());
      std::abort();
    }
  }
  return 0;
}
