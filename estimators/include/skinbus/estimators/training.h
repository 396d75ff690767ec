// skinbus/estimators/training.h: training per-patch networks with LibTorch (for the training tool
// and the tests; the host runtime does not link this).
//
// train_model() reads a sim::Dataset (the one dataset format, any number of sensors), normalises
// inputs (per channel) and targets (u_mm, v_mm, depth_mm, force_n; per output), splits
// train/validation by indentation location (all samples of presses at one (u, v) fall on one
// side: neighbouring samples of a press never leak across), trains with AdamW and MSE (optionally
// with the XY terms of shallow presses weighted down, TrainOptions::xy_full_weight_depth_mm), clips
// the gradient norm, and keeps the epoch with the best validation score. The score is the mean XY
// error of validation samples at least `select_min_depth_mm` deep plus the mean depth error:
// shallow presses cannot be localised and would swamp a plain validation loss. Everything is
// seeded: the same data, options and thread count give the same model.
//
// Costs: one epoch is a forward and backward pass over the training samples; the seed CNN costs
// about 40 MFLOP per sample and step on the CPU (see docs/models.md for measured times).
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/estimators/model_file.h"
#include "skinbus/sim/dataset.h"
#include "skinbus/sim/patch_model.h"

namespace skinbus::estimators {

struct EpochReport {
  int epoch = 0, epochs = 0;
  double train_loss = 0;         // MSE of normalised outputs (weighted as the training loss)
  double val_loss = 0;           // the same on the validation split
  double val_xy_mean_mm = 0;     // all validation samples
  double val_xy_deep_mm = 0;     // validation samples >= select_min_depth_mm deep
  double val_depth_mean_mm = 0;  // mean |depth error|
  double val_force_mean_n = 0;
  double score = 0;  // val_xy_deep_mm + val_depth_mean_mm: what selects the kept model
  // A proposer's (train_proposer): the share of validation samples whose count it gets right;
  // its XY and depth errors are then over the contacts of those samples. NaN otherwise.
  double val_count_accuracy = std::numeric_limits<double>::quiet_NaN();
  bool improved = false;
  double elapsed_s = 0;
};

struct TrainOptions {
  Architecture architecture = seed_cnn(1.0, 4, 4);  // sensor_cell is filled from the data
  std::string name = "model";
  int max_epochs = 200;
  int patience = 20;  // stop after this many epochs without a better score
  // Halve the learning rate after this many epochs without a better score (0: never).
  int plateau_epochs = 6;
  int batch_size = 128;
  double learning_rate = 1e-3;
  double weight_decay = 1e-4;  // AdamW
  double grad_clip_norm = 1.0;
  double validation_fraction = 0.2;  // of the press locations
  double select_min_depth_mm = 1.0;
  // Depth-weighted XY loss: a sample's two XY squared errors are weighted by f^2, f = true depth
  // / xy_full_weight_depth_mm clamped to [xy_weight_floor, 1], so presses too shallow to localise
  // stop dominating the loss (their XY targets are noise to the network) while still pulling
  // their answers towards the likely region. 0: plain MSE (the seed's).
  double xy_full_weight_depth_mm = 0;
  double xy_weight_floor = 0;
  int sample_stride = 1;   // keep every n-th sample of the training split (ramps are dense)
  double max_seconds = 0;  // stop after this long (0: no limit); the best epoch so far is kept
  uint64_t seed = 1;
  int threads = 2;
  // Fine-tuning: normalise inputs and outputs by the data's own statistics (make_meta) rather
  // than the base's. For a patch whose fields or size are far from the base's training data (a
  // fingertip read at thousands of uT, the base at hundreds): the inputs the base's weights meet
  // are then distributed as the ones they were trained on.
  bool renormalise = false;
  // Called after every epoch (progress display); may be empty.
  std::function<void(const EpochReport&)> progress;
};

struct TrainResult {
  ModelFile model;  // the kept epoch's weights; metrics hold its validation errors
  std::vector<EpochReport> history;
  int best_epoch = 0;
  int train_samples = 0, validation_samples = 0;
  int train_locations = 0, validation_locations = 0;
  int masked_rows = 0;  // rows left out for a NaN field value (a network cannot drop a channel)
};

// Trains a network on `data`. With `base` (fine-tuning), the base model's architecture and
// normalisation (unless options.renormalise) are kept and its weights are the start
// (options.architecture is ignored); the geometry is the data's (its sensors, and so the CNN's
// cells, the patch's extent and deepest press: the runtime flags contacts by them); the base
// itself is scored as epoch 0 and kept unless an epoch beats it, so fine-tuning on a few presses
// never returns a model worse than its base on the new unit's validation presses.
// Rows with a NaN field value are left out (counted in masked_rows); a NaN force is left out of
// the loss. The split is by press location: a press's rows, or without press numbers the rows at
// one (u, v), stay on one side.
// Errors: kInvalidArgument for a dataset without rows (or none without a NaN field value) or with
// fewer than 2 press locations, a
// CNN asked for sensors that do not form a grid (use an MLP), or a base model with another
// sensor count or grid; kNotConverged if the loss becomes non-finite.
Result<TrainResult> train_model(const sim::Dataset& data, const TrainOptions& options,
                                const ModelFile* base = nullptr);

// A proposer (contact_proposal.h): a network that tells how many contacts a sample holds (0 to
// kMaxContacts) and roughly where, trained on simulated presses of `design`: the nominal unit and
// `units` fabricated ones (sim::PatchModel::fabricated, seeded), each sample on one of them at
// random with the design's sensor noise; 0 presses in a tenth of the samples, else 1, 2 or 3
// alike, each within the patch less `margin_mm`, at least `min_separation_mm` apart, 0.3-4.5 mm
// deep (5 mm tips), half of them with a shear of friction 0-0.3 in any direction. The loss: the
// squared error of the count plus, over the best of the 6 orders of the slots, each present
// contact's (u, v, depth) and each absent slot's depth against 0 (normalised). The epoch with the
// lowest validation loss (a fresh set of `validation_samples`) is kept. Costs: the samples'
// fields (~20 us each) and the epochs (an MLP of ~0.1 MMAC: about a second an epoch of 200k on 2
// threads). Errors: kInvalidArgument for sizes out of range or a design that cannot be
// fabricated; kNotConverged for a non-finite loss.
struct ProposerTrainOptions {
  Architecture architecture = mlp({256, 256, 128});
  std::string name = "proposer";
  int units = 8;
  int samples = 200000;
  int validation_samples = 20000;
  double margin_mm = 10;
  double min_separation_mm = 12;
  int max_epochs = 40;
  int patience = 8;
  int plateau_epochs = 4;
  int batch_size = 256;
  double learning_rate = 1e-3;
  double weight_decay = 1e-4;
  double max_seconds = 0;
  uint64_t seed = 1;
  int threads = 2;
  std::function<void(const EpochReport&)> progress;
};
Result<TrainResult> train_proposer(const sim::PatchDesign& design,
                                   const ProposerTrainOptions& options);

// The grid cells of sensors laid out on a regular grid (rows along v, columns along u, both
// ascending): fills grid_rows, grid_cols and sensor_cell. kInvalidArgument if they do not form
// a full grid (rows x columns == sensors, one sensor per cell).
Status fit_grid(std::span<const SensorPosition> sensors, Architecture& a);

// Normalisation and metadata from a dataset, as train_model() sets them: normalisation over
// `rows_used` (row indices; empty: every row), extent and fingerprint over the whole dataset.
ModelMeta make_meta(const sim::Dataset& data, const Architecture& a, const std::string& name,
                    std::span<const int64_t> rows_used = {});

// LibTorch running a model: the reference runtime (tests, benchmark). Owns its network; run()
// allocates LibTorch tensors per call.
class TorchRunner {
 public:
  static Result<TorchRunner> create(const ModelFile& model, int threads);
  ~TorchRunner();
  TorchRunner(TorchRunner&&) noexcept;
  TorchRunner& operator=(TorchRunner&&) noexcept;
  // `batch` samples of tared fields (batch x channels, uT) -> batch x outputs, physical units.
  Status run(std::span<const double> field_ut, int batch, std::span<double> outputs);

  // LibTorch at its best, the peer the benchmarks time the host runtime against: prepare()
  // turns `batch` samples into the network's input tensor once (normalised; a CNN's grid) and
  // sets the runner's thread count; forward_prepared() then runs only the layers on it under
  // c10::InferenceMode and returns the first normalised output (NaN before prepare() or on a
  // LibTorch error), with no conversion in or out.
  Status prepare(std::span<const double> field_ut, int batch);
  double forward_prepared();

 private:
  struct Impl;
  explicit TorchRunner(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// LibTorch's forward pass of `model` on `batch` samples of tared fields (batch x channels, uT):
// batch x outputs in physical units, row-major. The reference the host runtime is checked
// against. `threads` sets LibTorch's intra-op threads.
Result<std::vector<double>> torch_forward(const ModelFile& model, std::span<const double> field_ut,
                                          int batch, int threads);

// A model with random weights (LibTorch's default initialisation, seeded) and a plausible
// normalisation for the nominal 4 x 4 layout of `sensors` (16) sensors: for tests and benchmarks.
Result<ModelFile> random_model(const Architecture& a, int sensors, uint64_t seed);

}  // namespace skinbus::estimators
