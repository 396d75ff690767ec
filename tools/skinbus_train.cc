// skinbus-train: train a per-patch network (or fine-tune one) on an indentation dataset.
//
//   skinbus-train train.csv -o models/nominal --test test.csv
//   skinbus-train unit7.csv --base models/nominal -o models/unit7 --epochs 60
#include <CLI/CLI.hpp>

#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "skinbus/estimators/evaluation.h"
#include "skinbus/estimators/training.h"
#include "skinbus/sim/dataset.h"
#include "tool_util.h"

namespace {

using namespace skinbus;
using namespace skinbus::estimators;

std::vector<int> parse_widths(const std::string& text) {
  std::vector<int> out;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t comma = std::min(text.find(',', pos), text.size());
    const std::string field = text.substr(pos, comma - pos);
    std::size_t used = 0;
    const int v = std::stoi(field, &used);
    if (used != field.size() || v <= 0)
      throw CLI::ValidationError("--hidden", "bad width " + field);
    out.push_back(v);
    pos = comma + 1;
  }
  return out;
}

// Errors of `model` on `test` through LibTorch, stored into the model's metrics.
void evaluate_into(ModelFile& model, const sim::Dataset& test, int threads) {
  Result<std::vector<double>> y =
      torch_forward(model, test.field_ut, static_cast<int>(test.rows()), threads);
  if (!y.ok()) throw std::runtime_error("evaluation failed: " + y.error().to_string());
  std::vector<ContactEstimate> est(test.rows());
  for (std::size_t r = 0; r < test.rows(); ++r) {
    const double* p = y->data() + 4 * r;
    est[r] = {p[0], p[1], p[2], p[3], kEstimateOk, RejectReason::kNone};
    flag_range(est[r], model.meta.half_u_mm, model.meta.half_v_mm, model.meta.max_depth_mm);
  }
  const ErrorSummary s = summarize_errors(est, {test.u_mm, test.v_mm, test.depth_mm, test.force_n});
  std::fprintf(
      stderr, "test (%zu samples): XY mean %.3f mm, p95 %.3f mm, depth %.3f mm, force %.3f N\n",
      test.rows(), s.all.xy_mean_mm, s.all.xy_p95_mm, s.all.depth_mean_mm, s.all.force_mean_n);
  model.meta.metrics["test_xy_mean_mm"] = s.all.xy_mean_mm;
  model.meta.metrics["test_xy_p95_mm"] = s.all.xy_p95_mm;
  model.meta.metrics["test_depth_mean_mm"] = s.all.depth_mean_mm;
  model.meta.metrics["test_force_mean_n"] = s.all.force_mean_n;
  for (int b = 0; b < kDepthBins; ++b) {
    const ErrorStats& st = s.bins[static_cast<std::size_t>(b)];
    std::fprintf(stderr, "  depth %-7s n=%-5d XY mean %.3f mm  p95 %.3f mm  depth %.3f mm\n",
                 depth_bin_name(b).c_str(), st.count, st.xy_mean_mm, st.xy_p95_mm,
                 st.depth_mean_mm);
    model.meta.metrics["test_xy_mean_mm_depth_" + depth_bin_name(b)] = st.xy_mean_mm;
    model.meta.metrics["test_depth_mean_mm_depth_" + depth_bin_name(b)] = st.depth_mean_mm;
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "skinbus-train: train a per-patch network on an indentation dataset (docs/models.md).\n\n"
      "Reads the project's dataset CSV (docs/dataset_format.md, any number of sensors), splits\n"
      "train/validation by press location, trains with AdamW and MSE, keeps the epoch with the\n"
      "best validation score (XY error of presses at least --select-depth deep + depth error),\n"
      "and writes MODEL.safetensors + MODEL.json. With --base it fine-tunes that model on the\n"
      "new unit's presses. With --test it measures the kept model on a test split (e.g.\n"
      "skinbus-dataset --plan random-test) and stores the errors in the metadata.\n\n"
      "Examples:\n"
      "  skinbus-train train.csv -o nominal --test test.csv\n"
      "  skinbus-train train.csv -o small --arch cnn --width 0.25\n"
      "  skinbus-train train.csv -o mlp --arch mlp --hidden 256,256\n"
      "  skinbus-train unit7.csv --base nominal -o unit7 --lr 3e-4 --epochs 60\n"};
  std::string data_path, out_path, test_path, base_path, arch = "cnn", hidden_text = "256,256";
  std::string name;
  TrainOptions o;
  double width = 1.0, max_minutes = 0;
  bool quiet = false;
  app.add_option("data", data_path, "training dataset (CSV)")->required()->check(CLI::ExistingFile);
  app.add_option("-o,--output", out_path, "model path (stem; .safetensors and .json are written)")
      ->required();
  app.add_option("--test", test_path, "test split to measure the kept model on")
      ->check(CLI::ExistingFile);
  app.add_option("--base", base_path, "fine-tune this model (keeps its architecture)");
  app.add_flag("--renormalise", o.renormalise,
               "with --base: normalise the inputs and outputs by this data's statistics, not the "
               "base's (a patch whose fields or size are far from the base's: its weights then "
               "meet inputs distributed as the ones they learned on)");
  app.add_option("--arch", arch, "cnn (the seed's, for sensors on a grid) | mlp")
      ->capture_default_str()
      ->check(CLI::IsMember({"cnn", "mlp"}));
  app.add_option("--width", width, "CNN width multiplier (1: the seed's 32-64-128-256)")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 4.0));
  app.add_option("--hidden", hidden_text, "MLP hidden widths, comma separated")
      ->capture_default_str();
  app.add_option("--name", name, "model name in the metadata (default: the output's file name)");
  app.add_option("--epochs", o.max_epochs, "most epochs")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--patience", o.patience, "stop after this many epochs without improvement")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--plateau", o.plateau_epochs,
                 "halve the learning rate after this many epochs without improvement (0: never)")
      ->capture_default_str();
  app.add_option("--batch", o.batch_size, "minibatch size")
      ->capture_default_str()
      ->check(CLI::Range(1, 65536));
  app.add_option("--lr", o.learning_rate, "AdamW learning rate")
      ->capture_default_str()
      ->check(CLI::Range(1e-7, 1.0));
  app.add_option("--weight-decay", o.weight_decay, "AdamW weight decay")->capture_default_str();
  app.add_option("--clip", o.grad_clip_norm, "gradient norm clip")
      ->capture_default_str()
      ->check(CLI::Range(1e-6, 1e6));
  app.add_option("--val-fraction", o.validation_fraction, "share of press locations held out")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 0.9));
  app.add_option("--select-depth", o.select_min_depth_mm,
                 "validation XY error counts presses at least this deep, mm")
      ->capture_default_str();
  app.add_option("--xy-weight-depth", o.xy_full_weight_depth_mm,
                 "weight the XY loss of presses shallower than this by (depth / this)^2, mm "
                 "(0: plain MSE, the seed's)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 10.0));
  app.add_option("--xy-weight-floor", o.xy_weight_floor,
                 "least XY weight factor of the shallowest presses (squared like the rest)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--stride", o.sample_stride, "keep every n-th training sample of a ramp")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--max-minutes", max_minutes, "stop after this long (0: no limit)")
      ->capture_default_str();
  app.add_option("--seed", o.seed, "seed (split, initialisation, shuffling)")
      ->capture_default_str();
  app.add_option("--threads", o.threads, "LibTorch threads")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  app.add_flag("-q,--quiet", quiet, "no per-epoch progress");
  CLI11_PARSE(app, argc, argv);

  try {
    Result<sim::Dataset> data = sim::read_dataset_csv(data_path);
    if (!data.ok()) {
      return skinbus::tools::fail("skinbus-train", data.error().to_string(), 2);
    }
    std::optional<sim::Dataset> test;
    if (!test_path.empty()) {
      Result<sim::Dataset> t = sim::read_dataset_csv(test_path);
      if (!t.ok()) {
        return skinbus::tools::fail("skinbus-train", t.error().to_string(), 2);
      }
      test = std::move(t.value());
    }
    std::optional<ModelFile> base;
    if (!base_path.empty()) {
      Result<ModelFile> b = read_model(base_path);
      if (!b.ok()) {
        return skinbus::tools::fail("skinbus-train", b.error().to_string(), 2);
      }
      base = std::move(b.value());
    }
    o.architecture = arch == "cnn" ? seed_cnn(width, 0, 0) : mlp(parse_widths(hidden_text));
    o.name = name.empty() ? out_path.substr(out_path.find_last_of('/') + 1) : name;
    o.max_seconds = max_minutes * 60;
    if (!quiet) {
      o.progress = [](const EpochReport& r) {
        std::fprintf(stderr,
                     "epoch %4d/%d  loss %.4f  val %.4f  XY %.3f mm (>= deep: %.3f)  depth %.3f mm"
                     "  force %.3f N  %6.1f s%s\n",
                     r.epoch, r.epochs, r.train_loss, r.val_loss, r.val_xy_mean_mm,
                     r.val_xy_deep_mm, r.val_depth_mean_mm, r.val_force_mean_n, r.elapsed_s,
                     r.improved ? "  *" : "");
      };
    }
    std::fprintf(stderr, "skinbus-train: %zu samples, %d sensors, %s\n", data->rows(),
                 static_cast<int>(data->sensors.size()),
                 base ? ("fine-tuning " + base->meta.name).c_str() : arch.c_str());
    Result<TrainResult> r = train_model(*data, o, base ? &*base : nullptr);
    if (!r.ok()) {
      std::fprintf(stderr, "skinbus-train: %s\n", r.error().to_string().c_str());
      return r.error().code == ErrorCode::kInvalidArgument ? 2 : 3;
    }
    std::fprintf(stderr,
                 "kept epoch %d of %zu: validation XY %.3f mm (>= %.1f mm deep: %.3f), depth %.3f "
                 "mm (%d train / %d validation locations)\n",
                 r->best_epoch, r->history.size(), r->model.meta.metrics["val_xy_mean_mm"],
                 o.select_min_depth_mm, r->model.meta.metrics["val_xy_deep_mean_mm"],
                 r->model.meta.metrics["val_depth_mean_mm"], r->train_locations,
                 r->validation_locations);
    if (r->masked_rows > 0) {
      std::fprintf(stderr,
                   "skinbus-train: %d of %zu rows left out: a NaN field value (a network cannot "
                   "leave a channel out; docs/models.md)\n",
                   r->masked_rows, data->rows());
    }
    if (test) evaluate_into(r->model, *test, o.threads);
    r->model.meta.info["data"] = data_path;
    if (Status s = write_model(r->model, out_path); !s.ok()) {
      return skinbus::tools::fail("skinbus-train", s.error().to_string(), 1);
    }
    std::fprintf(stderr, "wrote %s.safetensors and %s.json\n", model_stem(out_path).c_str(),
                 model_stem(out_path).c_str());
  } catch (const std::exception& e) {
    return skinbus::tools::fail("skinbus-train", e.what(), 2);
  }
  return 0;
}
