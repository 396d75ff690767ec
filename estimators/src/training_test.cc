#include "skinbus/estimators/training.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <vector>

#include "skinbus/estimators/contact_proposal.h"
#include "skinbus/estimators/network_runtime.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/design_file.h"
#include "skinbus/sim/simulated_patch.h"

namespace skinbus::estimators {
namespace {

constexpr uint64_t kSeed = 20261121;

sim::Dataset ramp_set(const sim::PatchModel& model, const std::vector<sim::PressPoint>& plan,
                      uint64_t noise_seed) {
  sim::SimulatedPatch patch(model, noise_seed);
  sim::RampProtocol ramp;
  ramp.rate_hz = 20;  // a coarse ramp keeps the test quick
  return sim::generate_ramp_dataset(patch, plan, ramp);
}

sim::Dataset test_set(const sim::PatchModel& model, int count, uint64_t seed) {
  sim::SimulatedPatch patch(model, seed);
  return sim::generate_random_test_set(patch, count, 60, 4, seed);
}

struct Errors {
  double xy_deep_mm = 0, depth_mm = 0;
};

// Mean XY error on samples >= 1 mm deep and mean depth error of `model` on `test`, through
// LibTorch.
Errors evaluate(const ModelFile& model, const sim::Dataset& test) {
  Result<std::vector<double>> out =
      torch_forward(model, test.field_ut, static_cast<int>(test.rows()), 2);
  EXPECT_TRUE(out.ok());
  Errors e;
  int deep = 0;
  for (std::size_t r = 0; r < test.rows(); ++r) {
    const double* y = out->data() + 4 * r;
    e.depth_mm += std::fabs(y[2] - test.depth_mm[r]);
    if (test.depth_mm[r] >= 1.0) {
      e.xy_deep_mm += std::hypot(y[0] - test.u_mm[r], y[1] - test.v_mm[r]);
      ++deep;
    }
  }
  e.xy_deep_mm /= std::max(deep, 1);
  e.depth_mm /= static_cast<double>(test.rows());
  return e;
}

TrainOptions quick_options() {
  TrainOptions o;
  o.architecture = mlp({128, 128});
  o.max_epochs = 150;
  o.patience = 150;
  o.batch_size = 64;
  o.learning_rate = 3e-3;
  o.seed = kSeed;
  o.threads = 1;
  return o;
}

TEST(Training, SmallSimulatedSetBeatsTheMeanByAClearMargin) {
  std::printf("seed %llu\n", static_cast<unsigned long long>(kSeed));
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const sim::Dataset train = ramp_set(nominal, sim::plan_halton(200, 60), kSeed);
  const sim::Dataset test = test_set(nominal, 300, kSeed + 1);
  Result<TrainResult> r = train_model(train, quick_options());
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  // Trivial baseline: always answer the training mean.
  double base_xy = 0;
  int deep = 0;
  for (std::size_t i = 0; i < test.rows(); ++i) {
    if (test.depth_mm[i] < 1.0) continue;
    base_xy += std::hypot(test.u_mm[i] - r->model.meta.output_mean[0],
                          test.v_mm[i] - r->model.meta.output_mean[1]);
    ++deep;
  }
  base_xy /= deep;
  const Errors e = evaluate(r->model, test);
  std::printf("baseline XY %.2f mm, trained XY (>= 1 mm deep) %.2f mm, depth %.3f mm\n", base_xy,
              e.xy_deep_mm, e.depth_mm);
  EXPECT_LT(e.xy_deep_mm, 0.25 * base_xy);
  EXPECT_LT(e.depth_mm, 0.3);
  // The split is by location and recorded.
  EXPECT_GT(r->validation_locations, 0);
  EXPECT_EQ(r->train_locations + r->validation_locations, 200);
  EXPECT_GT(r->model.meta.metrics.at("val_xy_deep_mean_mm"), 0);
  // The score that kept the epoch is in the metadata (what a choice between trainings reads),
  // and it is the kept epoch's.
  const std::map<std::string, double>& m = r->model.meta.metrics;
  EXPECT_DOUBLE_EQ(m.at("val_score"), m.at("val_xy_deep_mean_mm") + m.at("val_depth_mean_mm"));
  const auto kept = std::find_if(r->history.begin(), r->history.end(), [&](const EpochReport& rep) {
    return rep.epoch == r->best_epoch;
  });
  ASSERT_NE(kept, r->history.end());
  EXPECT_EQ(m.at("val_score"), kept->score);
  for (const EpochReport& rep : r->history) ASSERT_TRUE(std::isfinite(rep.train_loss));
}

TEST(Training, SameSeedSameModel) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const sim::Dataset train = ramp_set(nominal, sim::plan_halton(30, 60), kSeed);
  TrainOptions o = quick_options();
  o.max_epochs = 3;
  Result<TrainResult> a = train_model(train, o);
  Result<TrainResult> b = train_model(train, o);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->model.tensors.size(), b->model.tensors.size());
  for (std::size_t i = 0; i < a->model.tensors.size(); ++i) {
    EXPECT_EQ(a->model.tensors[i].data, b->model.tensors[i].data) << a->model.tensors[i].name;
  }
  o.seed += 1;
  Result<TrainResult> c = train_model(train, o);
  ASSERT_TRUE(c.ok());
  EXPECT_NE(a->model.tensors[0].data, c->model.tensors[0].data);
}

TEST(Training, DepthWeightedLossIsMseWhenEveryWeightIsOne) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const sim::Dataset train = ramp_set(nominal, sim::plan_halton(30, 60), kSeed);
  TrainOptions o = quick_options();
  o.max_epochs = 3;
  Result<TrainResult> plain = train_model(train, o);
  o.xy_full_weight_depth_mm = 1.5;
  o.xy_weight_floor = 1.0;  // every factor clamped to 1: the weighted loss is the MSE
  Result<TrainResult> ones = train_model(train, o);
  ASSERT_TRUE(plain.ok() && ones.ok());
  ASSERT_EQ(plain->model.tensors.size(), ones->model.tensors.size());
  for (std::size_t i = 0; i < plain->model.tensors.size(); ++i) {
    const auto& a = plain->model.tensors[i].data;
    const auto& b = ones->model.tensors[i].data;
    ASSERT_EQ(a.size(), b.size());
    for (std::size_t k = 0; k < a.size(); ++k) {
      ASSERT_NEAR(a[k], b[k], 1e-4) << plain->model.tensors[i].name << "[" << k << "]";
    }
  }
  for (std::size_t e = 0; e < plain->history.size(); ++e) {
    EXPECT_NEAR(plain->history[e].train_loss, ones->history[e].train_loss,
                1e-5 * plain->history[e].train_loss);
  }
  EXPECT_EQ(plain->model.meta.info.count("xy_loss"), 0u);
  EXPECT_NE(ones->model.meta.info.at("xy_loss").find("1.5 mm"), std::string::npos);
}

TEST(Training, DepthWeightedLossLocalisesDeepPressesBetter) {
  // Shallow presses cannot be localised; under a plain MSE their XY targets dominate the loss.
  // Weighting them down spends the network on presses it can localise.
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const sim::Dataset train = ramp_set(nominal, sim::plan_halton(200, 60), kSeed);
  const sim::Dataset test = test_set(nominal, 300, kSeed + 1);
  TrainOptions o = quick_options();
  o.max_epochs = 60;
  Result<TrainResult> plain = train_model(train, o);
  o.xy_full_weight_depth_mm = 1.5;
  Result<TrainResult> weighted = train_model(train, o);
  ASSERT_TRUE(plain.ok() && weighted.ok());
  const Errors p = evaluate(plain->model, test), w = evaluate(weighted->model, test);
  std::printf("XY (>= 1 mm deep): plain MSE %.2f mm, depth-weighted %.2f mm\n", p.xy_deep_mm,
              w.xy_deep_mm);
  EXPECT_LT(w.xy_deep_mm, 0.9 * p.xy_deep_mm);
}

TEST(Training, FineTuningImprovesAMismatchedUnit) {
  const sim::PatchDesign design;
  const sim::PatchModel nominal = sim::PatchModel::nominal(design).value();
  // A unit the nominal model does not describe: stiffer lattice spread, displaced magnets.
  sim::PatchDesign other = design;
  other.spread_mm = 11.5;
  sim::FabricationVariation var;
  var.magnet_position_sd_mm = 0.5;
  const sim::PatchModel unit = sim::PatchModel::fabricated(other, 77, var).value();
  Result<TrainResult> base =
      train_model(ramp_set(nominal, sim::plan_halton(200, 60), kSeed), quick_options());
  ASSERT_TRUE(base.ok());
  const sim::Dataset unit_test = test_set(unit, 300, kSeed + 2);
  const Errors before = evaluate(base->model, unit_test);
  TrainOptions ft = quick_options();
  ft.learning_rate = 1e-3;
  ft.max_epochs = 40;
  Result<TrainResult> tuned =
      train_model(ramp_set(unit, sim::plan_halton(25, 60, 500), kSeed + 3), ft, &base->model);
  ASSERT_TRUE(tuned.ok()) << tuned.error().to_string();
  const Errors after = evaluate(tuned->model, unit_test);
  std::printf("mismatched unit: XY %.2f -> %.2f mm, depth %.3f -> %.3f mm (25 presses)\n",
              before.xy_deep_mm, after.xy_deep_mm, before.depth_mm, after.depth_mm);
  EXPECT_LT(after.xy_deep_mm + after.depth_mm, 0.8 * (before.xy_deep_mm + before.depth_mm));
  EXPECT_EQ(tuned->model.meta.info.at("base_model"), base->model.meta.name);
}

TEST(Training, FineTuningNeverReturnsAWorseModelThanItsBase) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  TrainOptions o = quick_options();
  o.max_epochs = 30;
  Result<TrainResult> base = train_model(ramp_set(nominal, sim::plan_halton(60, 60), kSeed), o);
  ASSERT_TRUE(base.ok());
  // A learning rate that wrecks the weights: every epoch is worse than the base.
  TrainOptions wreck = quick_options();
  wreck.learning_rate = 0.5;
  wreck.max_epochs = 3;
  wreck.plateau_epochs = 0;
  Result<TrainResult> tuned =
      train_model(ramp_set(nominal, sim::plan_halton(20, 60, 900), kSeed + 5), wreck, &base->model);
  ASSERT_TRUE(tuned.ok()) << tuned.error().to_string();
  EXPECT_EQ(tuned->best_epoch, 0);
  EXPECT_EQ(tuned->history.front().epoch, 0);
  for (std::size_t i = 0; i < base->model.tensors.size(); ++i) {
    EXPECT_EQ(tuned->model.tensors[i].data, base->model.tensors[i].data);
  }
}

// A base trained on the built-in patch fine-tuned on a 48 mm fingertip read at thousands of uT:
// the model's geometry is the fingertip's (the runtime flags contacts outside its extent: the
// base's 140 mm would flag none), its scaling the base's unless renormalised, then the data's.
// A base whose grid the data's sensors do not fill is refused.
TEST(Training, FineTuningTakesTheDatasGeometryAndOnAskItsScaling) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  TrainOptions o = quick_options();
  o.architecture = seed_cnn(0.25, 0, 0);
  o.max_epochs = 1;
  Result<TrainResult> base = train_model(ramp_set(nominal, sim::plan_halton(30, 60), kSeed), o);
  ASSERT_TRUE(base.ok()) << base.error().to_string();
  const char* dir = std::getenv("SKINBUS_SOURCE_DIR");
  Result<sim::PatchDesign> tip_file = sim::read_design_file(
      std::string(dir != nullptr ? dir : ".") + "/docs/benchmarks/design_fingertip_4x4.yaml");
  ASSERT_TRUE(tip_file.ok()) << tip_file.error().to_string();
  sim::PatchDesign tip = tip_file.value();
  const sim::Dataset data =
      ramp_set(sim::PatchModel::nominal(tip).value(), sim::plan_halton(30, 20), kSeed + 1);
  Result<TrainResult> kept = train_model(data, o, &base->model);
  ASSERT_TRUE(kept.ok()) << kept.error().to_string();
  const ModelMeta& b = base->model.meta;
  const ModelMeta& k = kept->model.meta;
  EXPECT_EQ(b.half_u_mm, 70);
  EXPECT_EQ(k.half_u_mm, 24);
  EXPECT_EQ(k.half_v_mm, 24);
  ASSERT_EQ(k.sensors.size(), 16u);
  EXPECT_EQ(k.sensors[5].u_mm, data.sensors[5].u_mm);
  EXPECT_EQ(k.architecture.sensor_cell, b.architecture.sensor_cell);
  EXPECT_EQ(k.input_scale, b.input_scale);
  EXPECT_EQ(k.output_scale, b.output_scale);
  o.renormalise = true;
  Result<TrainResult> renormalised = train_model(data, o, &base->model);
  ASSERT_TRUE(renormalised.ok()) << renormalised.error().to_string();
  const ModelMeta& r = renormalised->model.meta;
  std::printf("z scale of sensor 5: base %.1f uT, renormalised %.1f uT; u scale %.1f -> %.1f mm\n",
              b.input_scale[17], r.input_scale[17], b.output_scale[0], r.output_scale[0]);
  EXPECT_GT(r.input_scale[17], 5 * b.input_scale[17]);  // fields tens of times the built-in's
  EXPECT_LT(r.output_scale[0], 0.5 * b.output_scale[0]);
  EXPECT_EQ(r.half_u_mm, 24);
  // Sensors in a 2 x 8 grid: not the base's 4 x 4.
  tip.sensors_u = 8;
  tip.sensors_v = 2;
  tip.sensor_pitch_mm = 6;
  Result<TrainResult> other =
      train_model(ramp_set(sim::PatchModel::nominal(tip).value(), sim::plan_halton(10, 20), kSeed),
                  o, &base->model);
  ASSERT_FALSE(other.ok());
  EXPECT_EQ(other.error().code, ErrorCode::kInvalidArgument);
  EXPECT_NE(other.error().message.find("the base model's grid is 4 x 4, the data's sensors 2 x 8"),
            std::string::npos)
      << other.error().message;
}

// Without press numbers (an optional column; or a byte-order mark that hid it) the rows of one
// press must still fall on one side of the split, or validation sees the training presses.
TEST(Training, WithoutPressNumbersTheSplitIsStillByLocation) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  sim::Dataset train = ramp_set(nominal, sim::plan_halton(30, 60), kSeed);
  ASSERT_GT(train.rows(), 300u);
  std::fill(train.press.begin(), train.press.end(), -1);
  TrainOptions o = quick_options();
  o.max_epochs = 1;
  Result<TrainResult> r = train_model(train, o);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  EXPECT_EQ(r->train_locations + r->validation_locations, 30);
  EXPECT_EQ(r->train_samples + r->validation_samples, static_cast<int>(train.rows()));
}

// NaN field values are allowed in a dataset (a dead channel in a recording): their rows are left
// out, as the runtime rejects such a sample; a NaN force (not measured) is left out of the loss.
TEST(Training, NanCellsAreMaskedNotFatal) {
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  sim::Dataset train = ramp_set(nominal, sim::plan_halton(30, 60), kSeed);
  train.field_ut[5 * static_cast<std::size_t>(train.channels()) + 7] = std::nan("");
  for (std::size_t r = 0; r < train.rows(); r += 3) train.force_n[r] = std::nan("");
  TrainOptions o = quick_options();
  o.max_epochs = 3;
  Result<TrainResult> r = train_model(train, o);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  EXPECT_EQ(r->masked_rows, 1);
  EXPECT_EQ(r->train_samples + r->validation_samples, static_cast<int>(train.rows()) - 1);
  for (const EpochReport& rep : r->history) {
    EXPECT_TRUE(std::isfinite(rep.train_loss));
    EXPECT_TRUE(std::isfinite(rep.val_force_mean_n));
  }
  for (double x : r->model.meta.output_scale) EXPECT_TRUE(std::isfinite(x));
  // A channel dead in every row leaves nothing: refused, naming it.
  for (std::size_t row = 0; row < train.rows(); ++row) {
    train.field_ut[row * static_cast<std::size_t>(train.channels()) + 11] = std::nan("");
  }
  Result<TrainResult> dead = train_model(train, o);
  ASSERT_FALSE(dead.ok());
  EXPECT_EQ(dead.error().code, ErrorCode::kInvalidArgument);
  EXPECT_NE(dead.error().message.find("channel s03_bz_ut"), std::string::npos)
      << dead.error().message;
}

TEST(Training, RefusesDataItCannotLearnFrom) {
  sim::Dataset empty;
  EXPECT_EQ(train_model(empty, quick_options()).error().code, ErrorCode::kInvalidArgument);
  const sim::PatchModel nominal = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const sim::Dataset one = ramp_set(nominal, {{0, 0}}, kSeed);
  EXPECT_NE(train_model(one, quick_options()).error().message.find("fewer than 2"),
            std::string::npos);
  // A CNN needs a grid; scattered sensors are refused with a pointer to the MLP.
  Architecture a;
  std::vector<SensorPosition> scattered = {{0, 0, 0}, {1, 7, 0}, {3, 2, 0}, {9, 5, 0}};
  EXPECT_NE(fit_grid(scattered, a).error().message.find("MLP"), std::string::npos);
  // A fabricated unit's sensors sit a little off the nominal grid: still a grid, cells by
  // position (row along v, column along u).
  std::vector<SensorPosition> jittered;
  for (int r = 0; r < 4; ++r) {
    for (int c = 3; c >= 0; --c) {
      jittered.push_back(
          {30.0 * c - 45 + 0.1 * ((r + c) % 3 - 1), 30.0 * r - 45 - 0.15 * (c % 2), -17});
    }
  }
  ASSERT_TRUE(fit_grid(jittered, a).ok());
  EXPECT_EQ(a.grid_rows, 4);
  EXPECT_EQ(a.grid_cols, 4);
  EXPECT_EQ(a.sensor_cell[0], 3);    // row 0, column 3
  EXPECT_EQ(a.sensor_cell[15], 12);  // row 3, column 0
}

TEST(Training, TorchForwardMatchesTheModelFileSemantics) {
  // A one-layer MLP with known weights: y = head(relu(fc0(x))) by hand.
  Result<ModelFile> m = random_model(mlp({3}), 16, 5);
  ASSERT_TRUE(m.ok());
  std::vector<double> field(48);
  for (int c = 0; c < 48; ++c) field[c] = 10.0 * std::sin(c);
  Result<std::vector<double>> y = torch_forward(*m, field, 1, 1);
  ASSERT_TRUE(y.ok());
  const Tensor& w0 = *m->find("fc0.weight");
  const Tensor& b0 = *m->find("fc0.bias");
  const Tensor& wh = *m->find("head.weight");
  const Tensor& bh = *m->find("head.bias");
  double h[3];
  for (int k = 0; k < 3; ++k) {
    double s = b0.data[k];
    for (int c = 0; c < 48; ++c) {
      s += w0.data[k * 48 + c] * (field[c] - m->meta.input_mean[c]) / m->meta.input_scale[c];
    }
    h[k] = std::max(s, 0.0);
  }
  for (int j = 0; j < 4; ++j) {
    double s = bh.data[j];
    for (int k = 0; k < 3; ++k) s += wh.data[j * 3 + k] * h[k];
    EXPECT_NEAR((*y)[j], s * m->meta.output_scale[j] + m->meta.output_mean[j], 1e-4);
  }
}

// LibTorch at its best, as the CPU benchmark times it: runners of 1 and 2 threads, each prepared
// once with its own input, run in turn; each returns its own first normalised output (the model's
// first output, unscaled), NaN before prepare().
TEST(Training, PreparedRunnersOfDifferentThreadCountsRunInTurn) {
  Result<ModelFile> m = random_model(mlp({8}), 16, 6);
  ASSERT_TRUE(m.ok());
  std::vector<double> a(48), b(48);
  for (int c = 0; c < 48; ++c) {
    a[c] = 10.0 * std::sin(c);
    b[c] = 20.0 * std::cos(0.5 * c);
  }
  Result<TorchRunner> one = TorchRunner::create(*m, 1), two = TorchRunner::create(*m, 2);
  ASSERT_TRUE(one.ok() && two.ok());
  EXPECT_TRUE(std::isnan(one->forward_prepared()));
  ASSERT_TRUE(one->prepare(a, 1).ok());
  ASSERT_TRUE(two->prepare(b, 1).ok());
  auto normalised = [&](const std::vector<double>& f) {
    Result<std::vector<double>> y = torch_forward(*m, f, 1, 1);
    EXPECT_TRUE(y.ok());
    return ((*y)[0] - m->meta.output_mean[0]) / m->meta.output_scale[0];
  };
  const double ya = normalised(a), yb = normalised(b);
  ASSERT_GT(std::fabs(ya - yb), 1e-3);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(one->forward_prepared(), ya, 1e-5);
    EXPECT_NEAR(two->forward_prepared(), yb, 1e-5);
  }
}

}  // namespace
}  // namespace skinbus::estimators

namespace skinbus::estimators {
namespace {

// A proposer learns the count well beyond always answering the commonest one (30 %), its file
// validates as a proposer, and the host's runtime gives LibTorch's outputs for it.
TEST(Training, AProposerLearnsTheCountAndRunsInTheHostsRuntime) {
  using sim::Contact;
  ProposerTrainOptions o;
  o.architecture = mlp({128, 128});
  o.units = 2;
  o.samples = 8000;
  o.validation_samples = 1000;
  o.max_epochs = 6;
  o.seed = 3;
  auto r = train_proposer(sim::PatchDesign{}, o);
  ASSERT_TRUE(r.ok()) << r.error().to_string();
  const double first = r->history.front().val_count_accuracy;
  const double kept = r->model.meta.metrics.at("val_count_accuracy");
  std::printf("proposer: validation count right %.1f %% after one epoch, %.1f %% kept\n",
              100 * first, 100 * kept);
  EXPECT_TRUE(is_proposer(r->model.meta));
  EXPECT_TRUE(validate_model(r->model).ok());
  EXPECT_GT(kept, 0.45);
  EXPECT_LT(r->history.back().val_loss, r->history.front().val_loss);
  // The same network through the host's runtime and through LibTorch.
  const sim::PatchModel unit = sim::PatchModel::nominal(sim::PatchDesign{}).value();
  const Contact presses[2] = {{-20, 10, 2.5, 5}, {25, -5, 3, 5}};
  std::vector<double> f(static_cast<std::size_t>(unit.channel_count()));
  unit.contact_field_ut(presses, f);
  auto rt = NetworkRuntime::create(r->model);
  ASSERT_TRUE(rt.ok()) << rt.error().to_string();
  double y[kProposerOutputCount];
  ASSERT_TRUE(rt->run_outputs(f, 1, y).ok());
  auto torch_y = torch_forward(r->model, f, 1, 1);
  ASSERT_TRUE(torch_y.ok());
  for (int j = 0; j < kProposerOutputCount; ++j) EXPECT_NEAR(y[j], (*torch_y)[j], 1e-3) << j;
  // Sizes it cannot train with are refused.
  o.samples = 10;
  EXPECT_FALSE(train_proposer(sim::PatchDesign{}, o).ok());
}

}  // namespace
}  // namespace skinbus::estimators
