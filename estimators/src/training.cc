#include "skinbus/estimators/training.h"

#include <dlfcn.h>
#include <torch/torch.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <sstream>

#include "skinbus/common/stats.h"
#include "skinbus/estimators/contact_proposal.h"
#include "skinbus/sim/mlx90393.h"
#include "skinbus/sim/rng.h"

namespace skinbus::estimators {
namespace {

// The network of model_file.h in LibTorch. Parameter names match the model file's tensor names.
struct NetImpl : torch::nn::Module {
  NetImpl(const Architecture& a, int channels, int outputs) : arch(a) {
    int in = channels;
    if (a.kind == ArchitectureKind::kCnn) {
      int c = 3;
      for (std::size_t k = 0; k < a.conv_channels.size(); ++k) {
        convs.push_back(register_module(
            "conv" + std::to_string(k),
            torch::nn::Conv2d(torch::nn::Conv2dOptions(c, a.conv_channels[k], 3).padding(1))));
        c = a.conv_channels[k];
      }
      in = 2 * c;
      std::vector<int64_t> cells(a.sensor_cell.begin(), a.sensor_cell.end());
      cell_index = torch::tensor(cells, torch::kLong);
    }
    for (std::size_t k = 0; k < a.hidden.size(); ++k) {
      fcs.push_back(register_module("fc" + std::to_string(k), torch::nn::Linear(in, a.hidden[k])));
      in = a.hidden[k];
    }
    head = register_module("head", torch::nn::Linear(in, outputs));
  }

  // x: [batch, channels], normalised.
  torch::Tensor forward(torch::Tensor x) { return layers(grid_input(x)); }

  // A CNN's input grid [batch, 3, rows, cols] (zeros where no sensor sits); an MLP's x as it is.
  torch::Tensor grid_input(torch::Tensor x) {
    if (arch.kind != ArchitectureKind::kCnn) return x;
    const int64_t b = x.size(0);
    const int64_t sensors = cell_index.size(0);
    const int64_t cells = arch.grid_rows * arch.grid_cols;
    torch::Tensor per_sensor = x.view({b, sensors, 3});
    torch::Tensor grid = torch::zeros({b, cells, 3}, x.options());
    grid = grid.index_copy(1, cell_index, per_sensor);
    return grid.permute({0, 2, 1}).reshape({b, 3, arch.grid_rows, arch.grid_cols}).contiguous();
  }

  // The layers, from grid_input()'s tensor to the normalised outputs.
  torch::Tensor layers(torch::Tensor x) {
    if (arch.kind == ArchitectureKind::kCnn) {
      for (auto& conv : convs) x = torch::relu(conv->forward(x));
      torch::Tensor avg = x.mean({2, 3});
      torch::Tensor mx = std::get<0>(x.flatten(2).max(2));
      x = torch::cat({avg, mx}, 1);
    }
    for (auto& fc : fcs) x = torch::relu(fc->forward(x));
    return head->forward(x);
  }

  Architecture arch;
  std::vector<torch::nn::Conv2d> convs;
  std::vector<torch::nn::Linear> fcs;
  torch::nn::Linear head{nullptr};
  torch::Tensor cell_index;
};
TORCH_MODULE(Net);

Status load_weights(Net& net, const ModelFile& model) {
  torch::NoGradGuard no_grad;
  for (auto& p : net->named_parameters()) {
    const Tensor* t = model.find(p.key());
    if (t == nullptr || !std::equal(t->shape.begin(), t->shape.end(), p.value().sizes().begin(),
                                    p.value().sizes().end())) {
      return make_error(ErrorCode::kInvalidArgument,
                        "model lacks tensor '" + p.key() + "' with the network's shape");
    }
    torch::Tensor src =
        torch::from_blob(const_cast<float*>(t->data.data()), p.value().sizes(), torch::kFloat32);
    p.value().copy_(src);
  }
  return Status::Ok();
}

std::vector<Tensor> save_weights(Net& net) {
  std::vector<Tensor> out;
  for (auto& p : net->named_parameters()) {
    torch::Tensor v = p.value().detach().contiguous().to(torch::kFloat32);
    Tensor t;
    t.name = p.key();
    for (int64_t d : v.sizes()) t.shape.push_back(d);
    t.data.assign(v.data_ptr<float>(), v.data_ptr<float>() + v.numel());
    out.push_back(std::move(t));
  }
  return out;
}

torch::Tensor normalised_inputs(const ModelMeta& m, std::span<const double> field, int64_t rows) {
  const int channels = m.channels();
  torch::Tensor x = torch::empty({rows, channels}, torch::kFloat32);
  float* p = x.data_ptr<float>();
  for (int64_t r = 0; r < rows; ++r) {
    for (int c = 0; c < channels; ++c) {
      const std::size_t i = static_cast<std::size_t>(r * channels + c);
      p[i] = static_cast<float>((field[i] - m.input_mean[c]) / m.input_scale[c]);
    }
  }
  return x;
}

// Runs `f`, turning any exception (LibTorch reports errors as c10::Error) into an error: none
// leaves the library.
template <typename F>
auto guarded(const char* what, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const std::exception& e) {
    return make_error(ErrorCode::kInternal, std::string(what) + ": " + e.what());
  }
}

// How the epochs of a training run go (run_epochs()).
struct EpochPlan {
  int max_epochs = 1, patience = 1, plateau_epochs = 0, batch_size = 1;
  double clip_norm = 1, max_seconds = 0;
  const char* what = "";  // prefixed to the errors ("proposer: ")
};

// The epochs both trainings share: AdamW steps over shuffled minibatches of the `n` training
// rows (`batch_loss(rows)`: the loss tensor of those rows, a LibTorch index tensor), the gradient
// norm clipped; after each epoch `validate(epoch, mean training loss)` gives its report. The
// epoch with the lowest score below `best_score` (a fine-tuning base's, or infinity) is kept:
// its weights into `best_weights`, its report into `best_report`, its number into
// result->best_epoch. The learning rate is halved after every plan.plateau_epochs epochs without
// a better one (0: never); the run stops after plan.patience of them or plan.max_seconds. Every
// report goes to result->history and to `progress`. Errors: kNotConverged for a non-finite loss
// or score.
template <typename BatchLoss, typename Validate>
Status run_epochs(Net& net, torch::optim::AdamW& opt, std::mt19937_64& rng, int64_t n,
                  const EpochPlan& plan, BatchLoss&& batch_loss, Validate&& validate,
                  const std::function<void(const EpochReport&)>& progress, double best_score,
                  std::vector<Tensor>* best_weights, EpochReport* best_report,
                  TrainResult* result) {
  std::vector<int64_t> order(static_cast<std::size_t>(n));
  std::iota(order.begin(), order.end(), 0);
  int since_best = 0;
  for (int epoch = 1; epoch <= plan.max_epochs; ++epoch) {
    net->train();
    std::shuffle(order.begin(), order.end(), rng);
    const torch::Tensor perm = torch::from_blob(order.data(), {n}, torch::kLong);
    double loss_sum = 0;
    int64_t seen = 0;
    for (int64_t b = 0; b < n; b += plan.batch_size) {
      const int64_t e = std::min(n, b + plan.batch_size);
      const torch::Tensor idx = perm.slice(0, b, e);
      opt.zero_grad();
      torch::Tensor loss = batch_loss(idx);
      const double l = loss.item<double>();
      if (!std::isfinite(l)) {
        return make_error(ErrorCode::kNotConverged,
                          std::string(plan.what) + "training loss became non-finite at epoch " +
                              std::to_string(epoch));
      }
      loss.backward();
      torch::nn::utils::clip_grad_norm_(net->parameters(), plan.clip_norm);
      opt.step();
      loss_sum += l * static_cast<double>(e - b);
      seen += e - b;
    }
    EpochReport rep = validate(epoch, loss_sum / static_cast<double>(std::max<int64_t>(seen, 1)));
    if (!std::isfinite(rep.score)) {
      return make_error(ErrorCode::kNotConverged,
                        std::string(plan.what) + "validation error became non-finite");
    }
    if (rep.score < best_score) {
      best_score = rep.score;
      *best_weights = save_weights(net);
      result->best_epoch = epoch;
      rep.improved = true;
      *best_report = rep;
      since_best = 0;
    } else {
      ++since_best;
      if (plan.plateau_epochs > 0 && since_best % plan.plateau_epochs == 0) {
        for (auto& group : opt.param_groups()) {
          auto& go = static_cast<torch::optim::AdamWOptions&>(group.options());
          go.lr(go.lr() * 0.5);
        }
      }
    }
    result->history.push_back(rep);
    if (progress) progress(rep);
    if (since_best >= plan.patience) break;
    if (plan.max_seconds > 0 && rep.elapsed_s >= plan.max_seconds) break;
  }
  return Status::Ok();
}

}  // namespace

Status fit_grid(std::span<const SensorPosition> sensors, Architecture& a) {
  // The distinct rows (v) and columns (u) of the layout: positions closer than a quarter of the
  // largest gap between neighbours are one row or column (a unit's sensors sit ~0.1 mm off the
  // nominal grid, the pitch is tens of mm). Returns each cluster's upper bound.
  auto clusters = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    double largest = 0;
    for (std::size_t i = 1; i < v.size(); ++i) largest = std::max(largest, v[i] - v[i - 1]);
    std::vector<double> upper;
    for (std::size_t i = 0; i < v.size(); ++i) {
      if (i + 1 == v.size() || v[i + 1] - v[i] > 0.25 * largest) upper.push_back(v[i]);
    }
    return upper;
  };
  std::vector<double> us, vs;
  for (const SensorPosition& s : sensors) {
    us.push_back(s.u_mm);
    vs.push_back(s.v_mm);
  }
  const std::vector<double> cols = clusters(us), rows = clusters(vs);
  if (cols.size() * rows.size() != sensors.size()) {
    return make_error(ErrorCode::kInvalidArgument,
                      "the sensors do not form a grid (" + std::to_string(rows.size()) + " x " +
                          std::to_string(cols.size()) + " distinct positions for " +
                          std::to_string(sensors.size()) + " sensors): use an MLP");
  }
  a.grid_rows = static_cast<int>(rows.size());
  a.grid_cols = static_cast<int>(cols.size());
  a.sensor_cell.clear();
  std::set<int> used;
  for (const SensorPosition& s : sensors) {
    const auto find = [](const std::vector<double>& upper, double x) {
      return static_cast<int>(std::lower_bound(upper.begin(), upper.end(), x) - upper.begin());
    };
    const int cell = find(rows, s.v_mm) * a.grid_cols + find(cols, s.u_mm);
    if (!used.insert(cell).second) {
      return make_error(ErrorCode::kInvalidArgument, "two sensors share a grid cell: use an MLP");
    }
    a.sensor_cell.push_back(cell);
  }
  return Status::Ok();
}

ModelMeta make_meta(const sim::Dataset& data, const Architecture& a, const std::string& name,
                    std::span<const int64_t> rows_used) {
  ModelMeta m;
  m.name = name;
  m.architecture = a;
  for (const sim::DatasetSensor& s : data.sensors) m.sensors.push_back({s.u_mm, s.v_mm, s.h_mm});
  std::vector<std::size_t> idx;
  if (rows_used.empty()) {
    idx.resize(data.rows());
    std::iota(idx.begin(), idx.end(), std::size_t{0});
  } else {
    for (int64_t r : rows_used) idx.push_back(static_cast<std::size_t>(r));
  }
  // Mean and standard deviation (at least 1e-3) of value(r) over the rows used, finite values
  // only (a force not measured is NaN); none finite: mean 0, scale 1.
  auto moments = [&](auto value, double* mean_out, double* scale_out) {
    double s = 0, s2 = 0, n = 0;
    for (std::size_t r : idx) {
      const double v = value(r);
      if (!std::isfinite(v)) continue;
      s += v;
      s2 += v * v;
      ++n;
    }
    if (n == 0) {
      *mean_out = 0;
      *scale_out = 1;
      return;
    }
    const double mean = s / n;
    *mean_out = mean;
    *scale_out = std::max(std::sqrt(std::max(s2 / n - mean * mean, 0.0)), 1e-3);
  };
  const int channels = data.channels();
  m.input_mean.assign(channels, 0.0);
  m.input_scale.assign(channels, 1.0);
  for (int c = 0; c < channels; ++c) {
    moments([&](std::size_t r) { return data.field(r)[c]; }, &m.input_mean[c], &m.input_scale[c]);
  }
  m.outputs = {"u_mm", "v_mm", "depth_mm", "force_n"};
  const std::vector<double>* cols[] = {&data.u_mm, &data.v_mm, &data.depth_mm, &data.force_n};
  m.output_mean.assign(4, 0.0);
  m.output_scale.assign(4, 1.0);
  for (int j = 0; j < 4; ++j) {
    moments([&](std::size_t r) { return (*cols[j])[r]; }, &m.output_mean[j], &m.output_scale[j]);
  }
  const std::size_t rows = data.rows();
  double max_u = 0, max_v = 0, max_d = 0;
  for (std::size_t r = 0; r < rows; ++r) {
    max_u = std::max(max_u, std::fabs(data.u_mm[r]));
    max_v = std::max(max_v, std::fabs(data.v_mm[r]));
    max_d = std::max(max_d, data.depth_mm[r]);
  }
  // The patch extent: "size_u_mm=" / "size_v_mm=" in the dataset's geometry header when
  // present, else the presses' extent.
  auto meta_number = [&](const char* key, double fallback) {
    auto it = data.meta.find("geometry");
    if (it == data.meta.end()) return fallback;
    const std::size_t at = it->second.find(std::string(key) + "=");
    if (at == std::string::npos) return fallback;
    const char* start = it->second.c_str() + at + std::strlen(key) + 1;
    char* end = nullptr;
    const double v = std::strtod(start, &end);
    return end != start && v > 0 ? v : fallback;
  };
  m.half_u_mm = meta_number("size_u_mm", 2 * std::max(max_u, 1.0)) / 2;
  m.half_v_mm = meta_number("size_v_mm", 2 * std::max(max_v, 1.0)) / 2;
  m.max_depth_mm = std::max(max_d, 0.1);
  m.data_fingerprint = sim::dataset_fingerprint(data);
  return m;
}

namespace {

Result<TrainResult> train_unguarded(const sim::Dataset& data, const TrainOptions& o,
                                    const ModelFile* base) {
  const auto t0 = std::chrono::steady_clock::now();
  if (data.rows() == 0) return make_error(ErrorCode::kInvalidArgument, "the dataset has no rows");
  const int channels = data.channels();
  ModelMeta meta;
  if (base != nullptr) {
    if (base->meta.channels() != channels) {
      return make_error(ErrorCode::kInvalidArgument,
                        "the base model has " + std::to_string(base->meta.channels()) +
                            " channels, the data " + std::to_string(channels));
    }
    meta = base->meta;
    meta.name = o.name;
    meta.info["base_model"] = base->meta.name;
    meta.data_fingerprint = sim::dataset_fingerprint(data);
  } else {
    Architecture a = o.architecture;
    if (a.kind == ArchitectureKind::kCnn) {
      std::vector<SensorPosition> sensors;
      for (const sim::DatasetSensor& s : data.sensors) sensors.push_back({s.u_mm, s.v_mm, s.h_mm});
      if (Status s = fit_grid(sensors, a); !s.ok()) return s.error();
    }
    meta.architecture = a;  // the rest of the metadata once the training rows are known
  }

  // A network cannot leave a channel out (the host's runtime rejects such a sample), so a row
  // with a NaN field value (a dead channel in a recording, docs/dataset_format.md) is left out
  // of training and validation: counted, and named when it leaves nothing.
  std::vector<int> nan_rows_of_channel(static_cast<std::size_t>(channels), 0);
  std::vector<bool> usable(data.rows(), true);
  int masked_rows = 0;
  for (std::size_t r = 0; r < data.rows(); ++r) {
    const double* f = data.field(r);
    for (int c = 0; c < channels; ++c) {
      if (std::isfinite(f[c])) continue;
      ++nan_rows_of_channel[static_cast<std::size_t>(c)];
      usable[r] = false;
    }
    masked_rows += usable[r] ? 0 : 1;
  }
  if (masked_rows == static_cast<int>(data.rows())) {
    const auto worst = std::max_element(nan_rows_of_channel.begin(), nan_rows_of_channel.end());
    const int c = static_cast<int>(worst - nan_rows_of_channel.begin());
    return make_error(ErrorCode::kInvalidArgument,
                      "every row has a NaN field value (channel " + sim::field_column_name(c) +
                          " in " + std::to_string(*worst) +
                          " rows): a network cannot be trained without that channel");
  }
  // Split by press location: every row of a press takes its press's location (its first row's
  // (u, v), rounded to 0.01 mm), so presses repeated at one point stay together; a row that is
  // not from a press (press < 0, or no press column) takes its own (u, v), so the samples of one
  // place still fall on one side.
  using LocationKey = std::pair<int64_t, int64_t>;
  std::map<LocationKey, std::vector<int64_t>> by_location;
  std::map<int64_t, LocationKey> press_location;
  for (std::size_t r = 0; r < data.rows(); ++r) {
    if (!usable[r]) continue;
    const LocationKey here{std::llround(data.u_mm[r] * 100), std::llround(data.v_mm[r] * 100)};
    LocationKey key = here;
    if (data.press[r] >= 0) key = press_location.emplace(data.press[r], here).first->second;
    by_location[key].push_back(static_cast<int64_t>(r));
  }
  if (by_location.size() < 2) {
    return make_error(ErrorCode::kInvalidArgument,
                      "the dataset has fewer than 2 press locations: nothing to validate on");
  }
  std::vector<std::vector<int64_t>> locations;
  for (auto& kv : by_location) locations.push_back(std::move(kv.second));
  std::mt19937_64 rng(o.seed);
  std::shuffle(locations.begin(), locations.end(), rng);
  const std::size_t n_val = std::clamp<std::size_t>(
      static_cast<std::size_t>(
          std::lround(o.validation_fraction * static_cast<double>(locations.size()))),
      1, locations.size() - 1);
  std::vector<int64_t> train_rows, val_rows;
  for (std::size_t i = 0; i < locations.size(); ++i) {
    auto& dst = i < n_val ? val_rows : train_rows;
    const auto& rows = locations[i];
    for (std::size_t k = 0; k < rows.size(); ++k) {
      if (i < n_val || k % static_cast<std::size_t>(std::max(o.sample_stride, 1)) == 0) {
        dst.push_back(rows[k]);
      }
    }
  }
  // A new model's normalisation comes from the training split only.
  if (base == nullptr) {
    meta = make_meta(data, meta.architecture, o.name, train_rows);
  } else {
    // A base's weights and (unless renormalised) normalisation; the data's geometry: a base
    // trained on another design would flag this patch's contacts by its own extent.
    const ModelMeta own = make_meta(data, meta.architecture, o.name, train_rows);
    if (meta.architecture.kind == ArchitectureKind::kCnn) {
      Architecture a = meta.architecture;
      if (Status s = fit_grid(own.sensors, a); !s.ok()) return s.error();
      if (a.grid_rows != meta.architecture.grid_rows ||
          a.grid_cols != meta.architecture.grid_cols) {
        return make_error(
            ErrorCode::kInvalidArgument,
            "the base model's grid is " + std::to_string(meta.architecture.grid_rows) + " x " +
                std::to_string(meta.architecture.grid_cols) + ", the data's sensors " +
                std::to_string(a.grid_rows) + " x " + std::to_string(a.grid_cols));
      }
      meta.architecture.sensor_cell = a.sensor_cell;
    }
    meta.sensors = own.sensors;
    meta.half_u_mm = own.half_u_mm;
    meta.half_v_mm = own.half_v_mm;
    meta.max_depth_mm = own.max_depth_mm;
    if (o.renormalise) {
      meta.input_mean = own.input_mean;
      meta.input_scale = own.input_scale;
      meta.output_mean = own.output_mean;
      meta.output_scale = own.output_scale;
      meta.info["normalisation"] = "the data's (renormalised)";
    }
  }

  torch::manual_seed(o.seed);
  torch::set_num_threads(std::max(o.threads, 1));
  const int outputs = static_cast<int>(meta.outputs.size());
  Net net(meta.architecture, channels, outputs);
  if (base != nullptr) {
    if (Status s = load_weights(net, *base); !s.ok()) return s.error();
  }

  // Inputs, normalised targets and, when the XY loss is depth-weighted, per-output loss weights
  // (left undefined otherwise: the plain MSE needs none).
  // Per-output loss weights: the depth weighting of the XY terms, and 0 for a target that is not
  // known (a force not measured is NaN: it is left out of the loss, not learned as 0).
  bool any_unknown_target = false;
  for (std::size_t r = 0; r < data.rows() && !any_unknown_target; ++r) {
    any_unknown_target = usable[r] && !std::isfinite(data.force_n[r]);
  }
  const bool weighted = o.xy_full_weight_depth_mm > 0 || any_unknown_target;
  const bool depth_weighted = o.xy_full_weight_depth_mm > 0;
  const double weight_floor = std::clamp(o.xy_weight_floor, 0.0, 1.0);
  auto make_xy = [&](const std::vector<int64_t>& rows, torch::Tensor& x, torch::Tensor& y,
                     torch::Tensor& w) {
    std::vector<double> field(rows.size() * static_cast<std::size_t>(channels));
    y = torch::empty({static_cast<int64_t>(rows.size()), outputs}, torch::kFloat32);
    if (weighted) w = torch::ones({static_cast<int64_t>(rows.size()), outputs}, torch::kFloat32);
    float* py = y.data_ptr<float>();
    float* pw = weighted ? w.data_ptr<float>() : nullptr;
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const std::size_t r = static_cast<std::size_t>(rows[i]);
      std::copy(data.field(r), data.field(r) + channels,
                field.begin() + static_cast<std::ptrdiff_t>(i * channels));
      const double t[4] = {data.u_mm[r], data.v_mm[r], data.depth_mm[r], data.force_n[r]};
      for (int j = 0; j < outputs; ++j) {
        const bool known = std::isfinite(t[j]);
        py[i * outputs + j] =
            known ? static_cast<float>((t[j] - meta.output_mean[j]) / meta.output_scale[j]) : 0.f;
        if (weighted && !known) pw[i * outputs + j] = 0.f;
      }
      if (depth_weighted) {
        const double f =
            std::clamp(data.depth_mm[r] / o.xy_full_weight_depth_mm, weight_floor, 1.0);
        for (int j = 0; j < std::min(outputs, 2); ++j)
          pw[i * outputs + j] = static_cast<float>(f * f);
      }
    }
    x = normalised_inputs(meta, field, static_cast<int64_t>(rows.size()));
  };
  torch::Tensor x_train, y_train, w_train, x_val, y_val, w_val;
  make_xy(train_rows, x_train, y_train, w_train);
  make_xy(val_rows, x_val, y_val, w_val);
  auto loss_of = [&](const torch::Tensor& pred, const torch::Tensor& y, const torch::Tensor& w) {
    return weighted ? ((pred - y).square() * w).mean() : torch::mse_loss(pred, y);
  };
  std::vector<double> val_depth(val_rows.size());
  for (std::size_t i = 0; i < val_rows.size(); ++i)
    val_depth[i] = data.depth_mm[static_cast<std::size_t>(val_rows[i])];

  torch::optim::AdamW opt(net->parameters(),
                          torch::optim::AdamWOptions(o.learning_rate).weight_decay(o.weight_decay));
  TrainResult result;
  result.train_samples = static_cast<int>(train_rows.size());
  result.validation_samples = static_cast<int>(val_rows.size());
  result.validation_locations = static_cast<int>(n_val);
  result.train_locations = static_cast<int>(locations.size() - n_val);
  result.masked_rows = masked_rows;
  std::vector<Tensor> best_weights = save_weights(net);
  double best_score = std::numeric_limits<double>::infinity();
  EpochReport best_report;
  // Validation in physical units.
  auto validate = [&](int epoch, double train_loss) {
    net->eval();
    torch::NoGradGuard no_grad;
    torch::Tensor pred = net->forward(x_val);
    EpochReport rep;
    rep.epoch = epoch;
    rep.epochs = o.max_epochs;
    rep.train_loss = train_loss;
    rep.val_loss = loss_of(pred, y_val, w_val).item<double>();
    const float* pp = pred.data_ptr<float>();
    const float* py = y_val.data_ptr<float>();
    std::vector<double> xy, xy_deep, depth, force;
    for (std::size_t i = 0; i < val_rows.size(); ++i) {
      double d[4];
      for (int j = 0; j < outputs; ++j) {
        d[j] = (pp[i * outputs + j] - py[i * outputs + j]) * meta.output_scale[j];
      }
      xy.push_back(std::hypot(d[0], d[1]));
      if (val_depth[i] >= o.select_min_depth_mm) xy_deep.push_back(xy.back());
      depth.push_back(std::fabs(d[2]));
      if (std::isfinite(data.force_n[static_cast<std::size_t>(val_rows[i])])) {
        force.push_back(std::fabs(d[3]));
      }
    }
    rep.val_xy_mean_mm = mean(xy);
    rep.val_xy_deep_mm = xy_deep.empty() ? rep.val_xy_mean_mm : mean(xy_deep);
    rep.val_depth_mean_mm = mean(depth);
    rep.val_force_mean_n = force.empty() ? 0.0 : mean(force);
    rep.score = rep.val_xy_deep_mm + rep.val_depth_mean_mm;
    rep.elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  };
  // Fine-tuning starts from a model that already works: it is epoch 0, kept unless an epoch
  // beats it on the new unit's validation presses (few presses must not make it worse).
  if (base != nullptr) {
    EpochReport rep = validate(0, 0.0);
    if (std::isfinite(rep.score)) {
      best_score = rep.score;
      rep.improved = true;
      best_report = rep;
      result.history.push_back(rep);
      if (o.progress) o.progress(rep);
    }
  }
  EpochPlan plan;
  plan.max_epochs = o.max_epochs;
  plan.patience = o.patience;
  plan.plateau_epochs = o.plateau_epochs;
  plan.batch_size = o.batch_size;
  plan.clip_norm = o.grad_clip_norm;
  plan.max_seconds = o.max_seconds;
  auto batch_loss = [&](const torch::Tensor& idx) {
    torch::Tensor xb = x_train.index_select(0, idx), yb = y_train.index_select(0, idx);
    torch::Tensor wb = weighted ? w_train.index_select(0, idx) : w_train;
    return loss_of(net->forward(xb), yb, wb);
  };
  if (Status st = run_epochs(net, opt, rng, x_train.size(0), plan, batch_loss, validate, o.progress,
                             best_score, &best_weights, &best_report, &result);
      !st.ok()) {
    return st.error();
  }
  result.model.meta = meta;
  result.model.tensors = std::move(best_weights);
  ModelMeta& m = result.model.meta;
  m.info["seed"] = std::to_string(o.seed);
  m.info["best_epoch"] = std::to_string(result.best_epoch);
  m.info["epochs_run"] = std::to_string(result.history.size());
  m.info["split"] = "by press location, " + std::to_string(result.validation_locations) + " of " +
                    std::to_string(locations.size()) + " locations held out";
  m.metrics["val_xy_mean_mm"] = best_report.val_xy_mean_mm;
  m.metrics["val_xy_deep_mean_mm"] = best_report.val_xy_deep_mm;
  m.metrics["val_depth_mean_mm"] = best_report.val_depth_mean_mm;
  m.metrics["val_score"] = best_report.score;  // what kept this epoch (EpochReport::score)
  m.metrics["val_force_mean_n"] = best_report.val_force_mean_n;
  m.metrics["select_min_depth_mm"] = o.select_min_depth_mm;
  if (masked_rows > 0) {
    m.info["masked_rows"] = std::to_string(masked_rows) + " rows with a NaN field value left out";
  }
  if (depth_weighted) {
    std::ostringstream w;
    w << "XY terms weighted by clamp(depth / " << o.xy_full_weight_depth_mm << " mm, "
      << weight_floor << ", 1)^2";
    m.info["xy_loss"] = w.str();
  }
  m.metrics["train_seconds"] = best_report.elapsed_s;
  if (Status s = validate_model(result.model); !s.ok()) return s.error();
  return result;
}

}  // namespace

Result<TrainResult> train_model(const sim::Dataset& data, const TrainOptions& o,
                                const ModelFile* base) {
  return guarded("training", [&] { return train_unguarded(data, o, base); });
}

namespace {

// A proposer's simulated samples: fields (rows x channels, uT), the slots' targets (rows x 3 x
// (u, v, depth), deepest first, absent slots 0) and which are present (rows x 3), the counts.
struct ProposerData {
  std::vector<double> field;
  std::vector<float> slots, present, count;
  int rows = 0;
};

ProposerData proposer_data(const std::vector<sim::PatchModel>& units, int rows, double half_u,
                           double half_v, const ProposerTrainOptions& o, uint64_t seed) {
  ProposerData d;
  const int channels = units.front().channel_count();
  d.rows = rows;
  d.field.reserve(static_cast<std::size_t>(rows) * static_cast<std::size_t>(channels));
  d.slots.assign(static_cast<std::size_t>(rows) * 3 * kMaxContacts, 0.f);
  d.present.assign(static_cast<std::size_t>(rows) * kMaxContacts, 0.f);
  d.count.assign(static_cast<std::size_t>(rows), 0.f);
  sim::Rng rng(seed);
  const mlx90393::Config& config = units.front().design().sensor_config;
  const double noise[3] = {sim::mlx90393_noise_xy_ut(config), sim::mlx90393_noise_xy_ut(config),
                           sim::mlx90393_noise_z_ut(config)};
  for (int r = 0; r < rows; ++r) {
    const sim::PatchModel& unit = units[rng.next() % units.size()];
    const int k = rng.uniform() < 0.1 ? 0 : 1 + static_cast<int>(rng.next() % kMaxContacts);
    sim::Contact c[kMaxContacts];
    const bool sheared = rng.uniform() < 0.5;
    for (int j = 0; j < k; ++j) {
      // Apart from the ones before (a few tries; the last is kept if none is far enough).
      for (int tries = 0; tries < 20; ++tries) {
        c[j] = {rng.uniform(-half_u + o.margin_mm, half_u - o.margin_mm),
                rng.uniform(-half_v + o.margin_mm, half_v - o.margin_mm), rng.uniform(0.3, 4.5),
                5.0};
        bool apart = true;
        for (int i = 0; i < j; ++i) {
          apart = apart &&
                  std::hypot(c[i].u_mm - c[j].u_mm, c[i].v_mm - c[j].v_mm) >= o.min_separation_mm;
        }
        if (apart) break;
      }
      if (sheared) {
        const double mag = rng.uniform(0, 0.3) * unit.force_n(c[j].depth_mm);
        const double dir = rng.uniform(0, 2 * M_PI);
        c[j].shear_u_n = mag * std::cos(dir);
        c[j].shear_v_n = mag * std::sin(dir);
      }
    }
    std::sort(c, c + k,
              [](const sim::Contact& a, const sim::Contact& b) { return a.depth_mm > b.depth_mm; });
    // The contacts' field with the design's sensor noise (independent per channel).
    const std::size_t at = d.field.size();
    d.field.resize(at + static_cast<std::size_t>(channels));
    const std::span<double> f(d.field.data() + at, static_cast<std::size_t>(channels));
    unit.contact_field_ut(std::span<const sim::Contact>(c, static_cast<std::size_t>(k)), f);
    for (int i = 0; i < channels; ++i)
      f[static_cast<std::size_t>(i)] += noise[i % 3] * rng.normal();
    for (int j = 0; j < k; ++j) {
      float* t = &d.slots[(static_cast<std::size_t>(r) * kMaxContacts + j) * 3];
      t[0] = static_cast<float>(c[j].u_mm);
      t[1] = static_cast<float>(c[j].v_mm);
      t[2] = static_cast<float>(c[j].depth_mm);
      d.present[static_cast<std::size_t>(r) * kMaxContacts + j] = 1.f;
    }
    d.count[static_cast<std::size_t>(r)] = static_cast<float>(k);
  }
  return d;
}

Result<TrainResult> train_proposer_unguarded(const sim::PatchDesign& design,
                                             const ProposerTrainOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  if (o.units < 0 || o.units > 1000 || o.samples < 100 || o.validation_samples < 10 ||
      o.max_epochs < 1 || o.batch_size < 1 || o.architecture.kind != ArchitectureKind::kMlp) {
    return make_error(ErrorCode::kInvalidArgument,
                      "proposer: units 0-1000, at least 100 samples and 10 validation samples, "
                      "an MLP, at least one epoch and a batch");
  }
  std::vector<sim::PatchModel> units;
  auto nominal = sim::PatchModel::nominal(design);
  if (!nominal.ok()) return nominal.error();
  units.push_back(std::move(*nominal));
  for (int u = 0; u < o.units; ++u) {
    auto f = sim::PatchModel::fabricated(design, o.seed * 1000003ull + static_cast<uint64_t>(u),
                                         sim::FabricationVariation{});
    if (!f.ok()) return f.error();
    units.push_back(std::move(*f));
  }
  const double half_u = design.size_u_mm / 2, half_v = design.size_v_mm / 2;
  const int channels = units.front().channel_count();
  const ProposerData train = proposer_data(units, o.samples, half_u, half_v, o, o.seed);
  const ProposerData val =
      proposer_data(units, o.validation_samples, half_u, half_v, o, o.seed ^ 0x9e3779b97f4a7c15ull);

  ModelMeta meta;
  meta.name = o.name;
  meta.architecture = o.architecture;
  for (const sim::PatchModel::Sensor& s : units.front().sensors()) {
    meta.sensors.push_back({s.u, s.v, s.h});
  }
  meta.input_mean.assign(static_cast<std::size_t>(channels), 0.0);
  meta.input_scale.assign(static_cast<std::size_t>(channels), 1.0);
  for (int c = 0; c < channels; ++c) {
    double s1 = 0, s2 = 0;
    for (int r = 0; r < train.rows; ++r) {
      const double v = train.field[static_cast<std::size_t>(r) * channels + c];
      s1 += v;
      s2 += v * v;
    }
    const double m = s1 / train.rows;
    meta.input_mean[static_cast<std::size_t>(c)] = m;
    meta.input_scale[static_cast<std::size_t>(c)] =
        std::max(std::sqrt(std::max(s2 / train.rows - m * m, 0.0)), 1e-3);
  }
  meta.outputs.assign(kProposerOutputs.begin(), kProposerOutputs.end());
  // Fixed scales: positions in half the patch's half-size, depth in 2 mm, the count as it is.
  const double position_scale[3] = {half_u / 2, half_v / 2, 2.0};
  for (int k = 0; k < kMaxContacts; ++k) {
    for (int j = 0; j < 3; ++j) {
      meta.output_mean.push_back(0.0);
      meta.output_scale.push_back(position_scale[j]);
    }
  }
  meta.output_mean.push_back(0.0);
  meta.output_scale.push_back(1.0);
  meta.half_u_mm = half_u;
  meta.half_v_mm = half_v;
  meta.max_depth_mm = 4.5;
  meta.info["kind"] = "proposer";
  meta.info["units"] = "nominal + " + std::to_string(o.units) + " fabricated";

  torch::manual_seed(o.seed);
  torch::set_num_threads(std::max(o.threads, 1));
  const int outputs = static_cast<int>(meta.outputs.size());
  Net net(meta.architecture, channels, outputs);
  auto tensors = [&](const ProposerData& d, torch::Tensor& x, torch::Tensor& slots,
                     torch::Tensor& present, torch::Tensor& count) {
    x = normalised_inputs(meta, d.field, d.rows);
    slots = torch::from_blob(const_cast<float*>(d.slots.data()), {d.rows, kMaxContacts, 3},
                             torch::kFloat32)
                .clone();
    const torch::Tensor scale =
        torch::tensor({static_cast<float>(position_scale[0]), static_cast<float>(position_scale[1]),
                       static_cast<float>(position_scale[2])});
    slots = slots / scale;
    present = torch::from_blob(const_cast<float*>(d.present.data()), {d.rows, kMaxContacts},
                               torch::kFloat32)
                  .clone();
    count = torch::from_blob(const_cast<float*>(d.count.data()), {d.rows}, torch::kFloat32).clone();
  };
  torch::Tensor xt, st, pt, ct, xv, sv, pv, cv;
  tensors(train, xt, st, pt, ct);
  tensors(val, xv, sv, pv, cv);
  // The 6 orders of the 3 slots.
  std::vector<torch::Tensor> orders;
  {
    std::array<int64_t, kMaxContacts> o3 = {0, 1, 2};
    do {
      orders.push_back(torch::tensor(std::vector<int64_t>(o3.begin(), o3.end()), torch::kLong));
    } while (std::next_permutation(o3.begin(), o3.end()));
  }
  // Per sample: the slots' squared error in the best order ([rows]) and that order's index.
  auto slot_error = [&](const torch::Tensor& pred, const torch::Tensor& slots,
                        const torch::Tensor& present) {
    const torch::Tensor p = pred.slice(1, 0, 3 * kMaxContacts).view({-1, kMaxContacts, 3});
    std::vector<torch::Tensor> errs;
    for (const torch::Tensor& ord : orders) {
      const torch::Tensor t = slots.index_select(1, ord), m = present.index_select(1, ord);
      const torch::Tensor d = (p - t).square();
      errs.push_back(((d.slice(2, 0, 2).sum(2) * m) + d.select(2, 2)).sum(1));
    }
    return torch::stack(errs, 1).min(1);
  };
  auto loss_of = [&](const torch::Tensor& pred, const torch::Tensor& slots,
                     const torch::Tensor& present, const torch::Tensor& count) {
    const torch::Tensor slot = std::get<0>(slot_error(pred, slots, present)).mean();
    return slot + (pred.select(1, 3 * kMaxContacts) - count).square().mean();
  };
  torch::optim::AdamW opt(net->parameters(),
                          torch::optim::AdamWOptions(o.learning_rate).weight_decay(o.weight_decay));
  TrainResult result;
  result.train_samples = train.rows;
  result.validation_samples = val.rows;
  std::vector<Tensor> best_weights = save_weights(net);
  EpochReport best_report;
  std::mt19937_64 rng(o.seed);
  auto validate = [&](int epoch, double train_loss) {
    net->eval();
    torch::NoGradGuard no_grad;
    const torch::Tensor pred = net->forward(xv);
    EpochReport rep;
    rep.epoch = epoch;
    rep.epochs = o.max_epochs;
    rep.train_loss = train_loss;
    rep.val_loss = loss_of(pred, sv, pv, cv).item<double>();
    const torch::Tensor best_order = std::get<1>(slot_error(pred, sv, pv));
    const float* pp = pred.data_ptr<float>();
    const int64_t* bo = best_order.data_ptr<int64_t>();
    std::vector<double> xy, depth;
    int right = 0;
    for (int r = 0; r < val.rows; ++r) {
      const float* y = pp + static_cast<std::size_t>(r) * outputs;
      const int k = static_cast<int>(val.count[static_cast<std::size_t>(r)]);
      const double c = std::clamp(std::round(static_cast<double>(y[3 * kMaxContacts])), 0.0,
                                  static_cast<double>(kMaxContacts));
      if (static_cast<int>(c) != k) continue;
      ++right;
      const int64_t* ord = orders[static_cast<std::size_t>(bo[r])].data_ptr<int64_t>();
      for (int s = 0; s < kMaxContacts; ++s) {
        const int t = static_cast<int>(ord[s]);
        if (val.present[static_cast<std::size_t>(r) * kMaxContacts + t] == 0.f) continue;
        const float* truth = &val.slots[(static_cast<std::size_t>(r) * kMaxContacts + t) * 3];
        xy.push_back(std::hypot(y[3 * s] * position_scale[0] - truth[0],
                                y[3 * s + 1] * position_scale[1] - truth[1]));
        depth.push_back(std::fabs(y[3 * s + 2] * position_scale[2] - truth[2]));
      }
    }
    rep.val_count_accuracy = static_cast<double>(right) / val.rows;
    rep.val_xy_mean_mm = xy.empty() ? 0.0 : mean(xy);
    rep.val_xy_deep_mm = rep.val_xy_mean_mm;
    rep.val_depth_mean_mm = depth.empty() ? 0.0 : mean(depth);
    rep.score = rep.val_loss;
    rep.elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  };
  EpochPlan plan;
  plan.max_epochs = o.max_epochs;
  plan.patience = o.patience;
  plan.plateau_epochs = o.plateau_epochs;
  plan.batch_size = o.batch_size;
  plan.max_seconds = o.max_seconds;
  plan.what = "proposer: ";
  auto batch_loss = [&](const torch::Tensor& idx) {
    return loss_of(net->forward(xt.index_select(0, idx)), st.index_select(0, idx),
                   pt.index_select(0, idx), ct.index_select(0, idx));
  };
  if (Status status =
          run_epochs(net, opt, rng, xt.size(0), plan, batch_loss, validate, o.progress,
                     std::numeric_limits<double>::infinity(), &best_weights, &best_report, &result);
      !status.ok()) {
    return status.error();
  }
  result.model.meta = meta;
  result.model.tensors = std::move(best_weights);
  ModelMeta& m = result.model.meta;
  m.info["seed"] = std::to_string(o.seed);
  m.info["best_epoch"] = std::to_string(result.best_epoch);
  m.info["epochs_run"] = std::to_string(result.history.size());
  m.info["samples"] = std::to_string(o.samples) + " training, " +
                      std::to_string(o.validation_samples) + " validation (simulated)";
  m.metrics["val_count_accuracy"] = best_report.val_count_accuracy;
  m.metrics["val_xy_mean_mm"] = best_report.val_xy_mean_mm;
  m.metrics["val_depth_mean_mm"] = best_report.val_depth_mean_mm;
  m.metrics["train_seconds"] = best_report.elapsed_s;
  if (Status s = validate_model(result.model); !s.ok()) return s.error();
  return result;
}

}  // namespace

Result<TrainResult> train_proposer(const sim::PatchDesign& design, const ProposerTrainOptions& o) {
  return guarded("proposer training", [&] { return train_proposer_unguarded(design, o); });
}

struct TorchRunner::Impl {
  Impl(const ModelFile& m, int t)
      : meta(m.meta),
        threads(t),
        net(m.meta.architecture, m.meta.channels(), static_cast<int>(m.meta.outputs.size())) {}
  ModelMeta meta;
  int threads;
  Net net;
  torch::Tensor prepared;  // prepare()'s input grid
};

TorchRunner::TorchRunner(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TorchRunner::~TorchRunner() = default;
TorchRunner::TorchRunner(TorchRunner&&) noexcept = default;
TorchRunner& TorchRunner::operator=(TorchRunner&&) noexcept = default;

Result<TorchRunner> TorchRunner::create(const ModelFile& model, int threads) {
  if (Status s = validate_model(model); !s.ok()) return s.error();
  return guarded("LibTorch", [&]() -> Result<TorchRunner> {
    auto impl = std::make_unique<Impl>(model, std::max(threads, 1));
    if (Status s = load_weights(impl->net, model); !s.ok()) return s.error();
    impl->net->eval();
    return TorchRunner(std::move(impl));
  });
}

Status TorchRunner::run(std::span<const double> field_ut, int batch, std::span<double> outputs) {
  const ModelMeta& m = impl_->meta;
  const int channels = m.channels();
  const int n_out = static_cast<int>(m.outputs.size());
  if (batch <= 0 || field_ut.size() != static_cast<std::size_t>(batch) * channels ||
      outputs.size() != static_cast<std::size_t>(batch) * n_out) {
    return make_error(ErrorCode::kInvalidArgument,
                      "field_ut must hold batch x channels and outputs batch x outputs values");
  }
  Result<bool> done = guarded("LibTorch", [&]() -> Result<bool> {
    // Changing LibTorch's thread count rebuilds its pool: only when it differs.
    if (torch::get_num_threads() != impl_->threads) torch::set_num_threads(impl_->threads);
    torch::NoGradGuard no_grad;
    torch::Tensor y = impl_->net->forward(normalised_inputs(m, field_ut, batch)).contiguous();
    const float* p = y.data_ptr<float>();
    for (int i = 0; i < batch; ++i) {
      for (int j = 0; j < n_out; ++j) {
        outputs[static_cast<std::size_t>(i * n_out + j)] =
            p[i * n_out + j] * m.output_scale[j] + m.output_mean[j];
      }
    }
    return true;
  });
  if (!done.ok()) return done.error();
  return Status::Ok();
}

namespace {

// LibTorch's intra-op threads, and OpenBLAS's, which LibTorch's linear layers run in: its own
// thread pool (one thread per core by default) set_num_threads does not reach, and at batch 1 on
// a busy machine its hand-offs cost more than the layers.
void use_threads(int threads) {
  if (torch::get_num_threads() != threads) torch::set_num_threads(threads);
  using SetThreads = void (*)(int);
  if (auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) {
    set(threads);
  }
}

}  // namespace

Status TorchRunner::prepare(std::span<const double> field_ut, int batch) {
  const ModelMeta& m = impl_->meta;
  if (batch <= 0 || field_ut.size() != static_cast<std::size_t>(batch) * m.channels()) {
    return make_error(ErrorCode::kInvalidArgument, "field_ut must hold batch x channels values");
  }
  Result<bool> done = guarded("LibTorch", [&]() -> Result<bool> {
    use_threads(impl_->threads);
    c10::InferenceMode inference;
    impl_->prepared = impl_->net->grid_input(normalised_inputs(m, field_ut, batch));
    return true;
  });
  if (!done.ok()) return done.error();
  return Status::Ok();
}

double TorchRunner::forward_prepared() {
  if (!impl_->prepared.defined()) return std::nan("");
  Result<double> y = guarded("LibTorch", [&]() -> Result<double> {
    // Runners of other thread counts may have run since prepare() (interleaved timings).
    if (torch::get_num_threads() != impl_->threads) use_threads(impl_->threads);
    c10::InferenceMode inference;
    return impl_->net->layers(impl_->prepared).data_ptr<float>()[0];
  });
  return y.ok() ? *y : std::nan("");
}

Result<std::vector<double>> torch_forward(const ModelFile& model, std::span<const double> field_ut,
                                          int batch, int threads) {
  Result<TorchRunner> runner = TorchRunner::create(model, threads);
  if (!runner.ok()) return runner.error();
  std::vector<double> out(static_cast<std::size_t>(std::max(batch, 0)) * model.meta.outputs.size());
  if (Status s = runner->run(field_ut, batch, out); !s.ok()) return s.error();
  return out;
}

namespace {

Result<ModelFile> random_model_unguarded(const Architecture& arch, int sensors, uint64_t seed) {
  const int side = static_cast<int>(std::lround(std::sqrt(sensors)));
  if (sensors <= 0 || side * side != sensors) {
    return make_error(ErrorCode::kInvalidArgument, "random_model needs a square sensor count");
  }
  ModelFile model;
  ModelMeta& m = model.meta;
  m.name = "random";
  m.architecture = arch;
  for (int r = 0; r < side; ++r) {
    for (int c = 0; c < side; ++c) {
      m.sensors.push_back({30.0 * (c - (side - 1) / 2.0), 30.0 * (r - (side - 1) / 2.0), -17});
    }
  }
  if (arch.kind == ArchitectureKind::kCnn) {
    if (Status s = fit_grid(m.sensors, m.architecture); !s.ok()) return s.error();
  }
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int c = 0; c < 3 * sensors; ++c) {
    m.input_mean.push_back(5 * u(rng));
    m.input_scale.push_back(30 + 10 * u(rng));
  }
  m.outputs = {"u_mm", "v_mm", "depth_mm", "force_n"};
  m.output_mean = {0, 0, 2, 4};
  m.output_scale = {40, 40, 1.2, 2.5};
  torch::manual_seed(seed);
  Net net(m.architecture, 3 * sensors, 4);
  model.tensors = save_weights(net);
  if (Status s = validate_model(model); !s.ok()) return s.error();
  return model;
}

}  // namespace

Result<ModelFile> random_model(const Architecture& arch, int sensors, uint64_t seed) {
  return guarded("LibTorch", [&] { return random_model_unguarded(arch, sensors, seed); });
}

}  // namespace skinbus::estimators
