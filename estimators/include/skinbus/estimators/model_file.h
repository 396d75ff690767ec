// skinbus/estimators/model_file.h: the model file a training tool writes and the host runtime
// reads.
//
// A model is two files with one stem: `<stem>.safetensors` holds the weights (the safetensors
// format: 8-byte little-endian header length, a JSON header naming each tensor's dtype, shape and
// byte range, then the raw little-endian data; only F32 is used) and `<stem>.json` holds the
// metadata: architecture, sensor layout, normalisation, units, the training data's fingerprint
// and the errors measured at training time. docs/models.md is the reference.
//
// Network (what the tensors mean):
//   input x[c] = (field_ut[c] - input_mean[c]) / input_scale[c], c over the 3 * sensors channels
//   kCnn: the channels form a grid_rows x grid_cols x 3 image: sensor i sits at cell
//         sensor_cell[i] (= row * grid_cols + col), its bx, by, bz are the image's 3 channels.
//         conv<k> (k = 0..): 3x3, stride 1, zero padding 1, weight [out, in, 3, 3], bias [out],
//         ReLU. Then global average and global max over the cells, concatenated (average first).
//   kMlp: the channels as a vector.
//   fc<k> (k = 0..): weight [out, in], bias [out], ReLU.   head: weight [outputs, in], bias.
//   output y[j] = head[j] * output_scale[j] + output_mean[j] (u_mm, v_mm, depth_mm, force_n).
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/common/result.h"

namespace skinbus::estimators {

enum class ArchitectureKind : uint8_t { kCnn, kMlp };

struct Architecture {
  ArchitectureKind kind = ArchitectureKind::kCnn;
  std::vector<int> conv_channels;  // kCnn: output channels of each 3x3 conv layer
  std::vector<int> hidden;         // widths of the fully connected hidden layers
  int grid_rows = 0, grid_cols = 0;
  std::vector<int> sensor_cell;  // kCnn: one cell per sensor
  double width = 1.0;            // width multiplier it was built with (informative)
};

// The seed's CNN (input 4x4x3; conv 32, 64, 128, 256; pools to 512; fc 512-256-128-64) scaled
// by `width` (channels and hidden widths rounded, at least 1), for a grid_rows x grid_cols grid.
Architecture seed_cnn(double width, int grid_rows, int grid_cols);
// An MLP with the given hidden widths.
Architecture mlp(std::vector<int> hidden);

struct SensorPosition {
  double u_mm = 0, v_mm = 0, h_mm = 0;
};

struct ModelMeta {
  std::string name;
  Architecture architecture;
  std::vector<SensorPosition> sensors;
  std::vector<double> input_mean, input_scale;    // one per channel (uT)
  std::vector<std::string> outputs;               // {"u_mm", "v_mm", "depth_mm", "force_n"}
  std::vector<double> output_mean, output_scale;  // one per output
  double half_u_mm = 70, half_v_mm = 70;          // patch extent (for range flags)
  double max_depth_mm = 9;                        // deepest press the model knows
  uint64_t data_fingerprint = 0;                  // sim::dataset_fingerprint of the training set
  std::map<std::string, std::string> info;        // seed, data path, base model, ...
  std::map<std::string, double> metrics;          // errors measured on the validation split

  int channels() const { return 3 * static_cast<int>(sensors.size()); }
};

struct Tensor {
  std::string name;
  std::vector<int64_t> shape;
  std::vector<float> data;  // row-major

  int64_t numel() const;
};

struct ModelFile {
  ModelMeta meta;
  std::vector<Tensor> tensors;

  const Tensor* find(const std::string& name) const;
  // Multiply-adds of one forward pass, counting only in-bounds convolution taps.
  int64_t macs() const;
  int64_t parameters() const;
};

// The tensors an architecture needs, with their shapes (data left empty), for `channels` inputs
// and `outputs` outputs.
std::vector<Tensor> expected_tensors(const Architecture& a, int channels, int outputs);

// Checks metadata and tensors agree: sizes of the normalisation vectors, a grid that holds every
// sensor once, every tensor present with its shape and no others, finite values, positive scales.
Status validate_model(const ModelFile& model);

// `path` is either stem, `<stem>.json` or `<stem>.safetensors`. Reading validates the model;
// errors name the file and what is wrong (a truncated or corrupt weight file, a missing key).
Result<ModelFile> read_model(const std::string& path);
// The same from the two files' contents (`name` is used in error messages). What read_model()
// does after reading the files; also the fuzzed entry point.
Result<ModelFile> parse_model(std::string_view metadata_json, std::string_view weights,
                              const std::string& name);
Status write_model(const ModelFile& model, const std::string& path);

// The stem of a model path ("a/b.json" -> "a/b").
std::string model_stem(const std::string& path);

}  // namespace skinbus::estimators
