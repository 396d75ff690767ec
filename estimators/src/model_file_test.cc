#include "skinbus/estimators/model_file.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>

namespace skinbus::estimators {
namespace {

ModelFile make_model(const Architecture& a, uint32_t seed) {
  ModelFile m;
  m.meta.name = "test";
  m.meta.architecture = a;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      m.meta.sensors.push_back({-45.0 + 30 * c, -45.0 + 30 * r, -17});
      if (a.kind == ArchitectureKind::kCnn) m.meta.architecture.sensor_cell.push_back(r * 4 + c);
    }
  }
  m.meta.input_mean.assign(48, 1.5);
  m.meta.input_scale.assign(48, 20.0);
  m.meta.outputs = {"u_mm", "v_mm", "depth_mm", "force_n"};
  m.meta.output_mean = {0, 0, 1, 2};
  m.meta.output_scale = {40, 40, 1, 2};
  m.meta.data_fingerprint = 0x123456789abcdefULL;
  m.meta.info["seed"] = "7";
  m.meta.metrics["xy_mean_mm"] = 0.75;
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0, 1);
  m.tensors = expected_tensors(a, 48, 4);
  for (Tensor& t : m.tensors) {
    t.data.resize(static_cast<std::size_t>(t.numel()));
    for (float& v : t.data) v = n(rng);
  }
  return m;
}

std::string temp_stem(const char* name) {
  return (std::filesystem::temp_directory_path() / name).string();
}

TEST(ModelFile, SeedCnnShapeAndCost) {
  const Architecture a = seed_cnn(1.0, 4, 4);
  EXPECT_EQ(a.conv_channels, (std::vector<int>{32, 64, 128, 256}));
  EXPECT_EQ(a.hidden, (std::vector<int>{512, 256, 128, 64}));
  const ModelFile m = make_model(a, 1);
  // 100 in-bounds taps on a 4x4 grid; 4.31 M conv MACs + 0.434 M fc MACs (the seed's ~9.5 MFLOP).
  EXPECT_EQ(m.macs(), 100 * (3 * 32 + 32 * 64 + 64 * 128 + 128 * 256) +
                          (512 * 512 + 512 * 256 + 256 * 128 + 128 * 64 + 64 * 4));
  const Architecture q = seed_cnn(0.25, 4, 4);
  EXPECT_EQ(q.conv_channels, (std::vector<int>{8, 16, 32, 64}));
  EXPECT_EQ(q.hidden, (std::vector<int>{128, 64, 32, 16}));
}

TEST(ModelFile, RoundTripIsExact) {
  for (const Architecture& a : {seed_cnn(0.25, 4, 4), mlp({64, 32})}) {
    const ModelFile m = make_model(a, 2);
    const std::string stem = temp_stem("skinbus_model_rt");
    ASSERT_TRUE(write_model(m, stem + ".json").ok());
    Result<ModelFile> r = read_model(stem);
    ASSERT_TRUE(r.ok()) << r.error().to_string();
    EXPECT_EQ(r->meta.name, "test");
    EXPECT_EQ(r->meta.architecture.kind, a.kind);
    EXPECT_EQ(r->meta.architecture.sensor_cell, m.meta.architecture.sensor_cell);
    EXPECT_EQ(r->meta.input_mean, m.meta.input_mean);
    EXPECT_EQ(r->meta.output_scale, m.meta.output_scale);
    EXPECT_EQ(r->meta.data_fingerprint, m.meta.data_fingerprint);
    EXPECT_EQ(r->meta.info.at("seed"), "7");
    EXPECT_DOUBLE_EQ(r->meta.metrics.at("xy_mean_mm"), 0.75);
    ASSERT_EQ(r->tensors.size(), m.tensors.size());
    for (const Tensor& t : m.tensors) {
      const Tensor* u = r->find(t.name);
      ASSERT_NE(u, nullptr) << t.name;
      EXPECT_EQ(u->shape, t.shape);
      EXPECT_EQ(u->data, t.data) << t.name;
    }
  }
}

TEST(ModelFile, RefusesModelsThatDoNotMatchTheirArchitecture) {
  ModelFile m = make_model(seed_cnn(0.25, 4, 4), 3);
  ModelFile wrong_shape = m;
  wrong_shape.tensors[0].shape = {8, 3, 3, 2};
  EXPECT_FALSE(validate_model(wrong_shape).ok());
  ModelFile missing = m;
  missing.tensors.pop_back();
  EXPECT_FALSE(validate_model(missing).ok());
  ModelFile nan = m;
  nan.tensors[1].data[0] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(validate_model(nan).error().message.find("non-finite"), std::string::npos);
  ModelFile twice = m;
  twice.meta.architecture.sensor_cell[1] = twice.meta.architecture.sensor_cell[0];
  EXPECT_NE(validate_model(twice).error().message.find("used twice"), std::string::npos);
  ModelFile scale = m;
  scale.meta.input_scale[5] = 0;
  EXPECT_FALSE(validate_model(scale).ok());
  EXPECT_FALSE(write_model(scale, temp_stem("skinbus_model_bad")).ok());
}

TEST(ModelFile, CorruptWeightFilesGiveClearErrors) {
  const ModelFile m = make_model(mlp({16}), 4);
  const std::string stem = temp_stem("skinbus_model_corrupt");
  ASSERT_TRUE(write_model(m, stem).ok());
  std::string bytes;
  {
    std::ifstream f(stem + ".safetensors", std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), {});
  }
  auto write = [&](const std::string& b) {
    std::ofstream f(stem + ".safetensors", std::ios::binary | std::ios::trunc);
    f.write(b.data(), static_cast<std::streamsize>(b.size()));
  };
  write(bytes.substr(0, bytes.size() - 4));  // truncated data
  Result<ModelFile> r = read_model(stem);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("does not fit"), std::string::npos) << r.error().message;
  write(bytes.substr(0, 5));  // truncated header length
  r = read_model(stem);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("shorter"), std::string::npos);
  std::string huge = bytes;
  huge[7] = '\x7f';  // header length beyond the file
  write(huge);
  EXPECT_NE(read_model(stem).error().message.find("exceeds"), std::string::npos);
  std::string garbage = bytes;
  garbage[8] = '[';  // header is not an object
  write(garbage);
  EXPECT_FALSE(read_model(stem).ok());
  {
    std::ofstream f(stem + ".json", std::ios::trunc);
    f << "{\"format\": \"skinbus-model\"}";
  }
  EXPECT_NE(read_model(stem).error().message.find("architecture"), std::string::npos);
  {
    std::ofstream f(stem + ".json", std::ios::trunc);
    f << "{\"format\": 7}";  // wrong type: an error, not an exception
  }
  EXPECT_EQ(read_model(stem).error().code, ErrorCode::kParse);
  std::remove((stem + ".safetensors").c_str());
  EXPECT_EQ(read_model(stem).error().code, ErrorCode::kNotFound);
}

std::string slurp(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}
void spit(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// A model is two files. A writer stopped between them (or one file copied alone) must never give
// new weights with old metadata: the metadata names its weights' fingerprint.
TEST(ModelFile, WeightsAreNeverPairedWithAnotherWritesMetadata) {
  const std::string stem = temp_stem("skinbus_model_pair");
  ModelFile a = make_model(mlp({16}), 4);
  ModelFile b = a;
  b.tensors[0].data[0] += 1.0f;  // another training run: other weights, same shapes
  ASSERT_TRUE(write_model(a, stem).ok());
  const std::string json_a = slurp(stem + ".json"), weights_a = slurp(stem + ".safetensors");
  EXPECT_NE(json_a.find("\"weights_fingerprint\": \"fnv1a64:"), std::string::npos);
  ASSERT_TRUE(read_model(stem).ok());
  ASSERT_TRUE(write_model(b, stem).ok());
  // New weights, old metadata (stopped after the first rename).
  spit(stem + ".json", json_a);
  Result<ModelFile> r = read_model(stem);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find(".safetensors: does not match its metadata"), std::string::npos)
      << r.error().message;
  // Old weights, new metadata.
  ASSERT_TRUE(write_model(b, stem).ok());
  spit(stem + ".safetensors", weights_a);
  EXPECT_NE(read_model(stem).error().message.find("does not match"), std::string::npos);
  // Metadata of the older format (version 1, no fingerprint) with weights of this writer.
  ASSERT_TRUE(write_model(b, stem).ok());
  std::string v1 = slurp(stem + ".json");
  v1.replace(v1.find("\"version\": 2"), 12, "\"version\": 1");
  v1.replace(v1.find("\"weights_fingerprint\""), 21, "\"an_unknown_key\"");
  spit(stem + ".json", v1);
  EXPECT_NE(read_model(stem).error().message.find("was written with a fingerprint"),
            std::string::npos)
      << read_model(stem).error().message;
  // A version this reader does not know.
  std::string v9 = slurp(stem + ".json");
  v9.replace(v9.find("\"version\": 1"), 12, "\"version\": 9");
  spit(stem + ".json", v9);
  EXPECT_NE(read_model(stem).error().message.find("version 9"), std::string::npos);
  // No temporary file is left beside the model.
  for (const char* ext : {".json", ".safetensors"}) {
    EXPECT_EQ(std::system(("ls " + stem + ext + ".tmp.* >/dev/null 2>&1").c_str()) == 0, false);
  }
}

// The older writer's pair (version 1 metadata, weights without the version) still reads: the
// shipped model is one.
TEST(ModelFile, VersionOnePairsStillRead) {
  const char* d = std::getenv("SKINBUS_SOURCE_DIR");
  Result<ModelFile> shipped =
      read_model(std::string(d != nullptr ? d : ".") + "/estimators/models/nominal_seed_cnn");
  ASSERT_TRUE(shipped.ok()) << shipped.error().to_string();
}

// A number no double holds is a JSON error with its place, not "not a JSON object".
TEST(ModelFile, JsonErrorsSayWhatAndWhere) {
  const std::string stem = temp_stem("skinbus_model_json");
  ASSERT_TRUE(write_model(make_model(mlp({16}), 4), stem).ok());
  std::string text = slurp(stem + ".json");
  text.replace(text.find("\"half_u_mm\": ") + 13, 2, "1e400");
  spit(stem + ".json", text);
  Result<ModelFile> r = read_model(stem);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("not valid JSON"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("1e400"), std::string::npos) << r.error().message;
  spit(stem + ".json", "{\"format\": \"skinbus-model\",\n \"name\": }");
  r = read_model(stem);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("line 2"), std::string::npos) << r.error().message;
}

TEST(ModelFile, StemOfAnyOfTheThreeSpellings) {
  EXPECT_EQ(model_stem("a/b.json"), "a/b");
  EXPECT_EQ(model_stem("a/b.safetensors"), "a/b");
  EXPECT_EQ(model_stem("a/b"), "a/b");
}

}  // namespace
}  // namespace skinbus::estimators
