// skinbus-train-proposer: train a proposer, the network that tells how many contacts a sample
// holds (0 to 3) and roughly where, as starts for the physics count (docs/models.md, "The
// proposer").
//
//   skinbus-train-proposer -o estimators/models/nominal_proposer
//   skinbus-train-proposer --design my_patch.yaml -o my_proposer --samples 400000
#include <CLI/CLI.hpp>

#include <cstdio>
#include <string>
#include <vector>

#include "skinbus/estimators/training.h"
#include "skinbus/sim/design_file.h"
#include "tool_util.h"

int main(int argc, char** argv) {
  using namespace skinbus;
  using namespace skinbus::estimators;
  CLI::App app{
      "skinbus-train-proposer: train a proposer network (docs/models.md, \"The proposer\").\n\n"
      "Simulates presses on the design's nominal unit and --units fabricated ones (none, one,\n"
      "two or three presses a sample, half of them with shear, the design's sensor noise),\n"
      "trains an MLP to give the contact count and each contact's (u, v, depth), keeps the epoch\n"
      "with the lowest validation loss and writes MODEL.safetensors + MODEL.json. The host's\n"
      "physics count starts from its answer instead of searching (it still decides the count).\n\n"
      "Examples:\n"
      "  skinbus-train-proposer -o estimators/models/nominal_proposer\n"
      "  skinbus-train-proposer --design patch.yaml -o patch_proposer --samples 400000\n"};
  std::string out_path, design_path, name;
  std::vector<int> hidden = {256, 256, 128};
  ProposerTrainOptions o;
  double max_minutes = 0;
  bool quiet = false;
  app.add_option("-o,--output", out_path, "model path (stem; .safetensors and .json are written)")
      ->required();
  app.add_option("--design", design_path, "design file (docs/design_file.md; default: built-in)")
      ->check(CLI::ExistingFile);
  app.add_option("--name", name, "model name in the metadata (default: the output's file name)");
  app.add_option("--hidden", hidden, "MLP hidden widths, comma separated")
      ->delimiter(',')
      ->capture_default_str();
  app.add_option("--units", o.units, "fabricated units the presses are drawn on (and the nominal)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000));
  app.add_option("--samples", o.samples, "training samples")
      ->capture_default_str()
      ->check(CLI::Range(100, 100000000));
  app.add_option("--validation-samples", o.validation_samples, "validation samples")
      ->capture_default_str()
      ->check(CLI::Range(10, 10000000));
  app.add_option("--epochs", o.max_epochs, "most epochs")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--patience", o.patience, "stop after this many epochs without improvement")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--batch", o.batch_size, "minibatch size")
      ->capture_default_str()
      ->check(CLI::Range(1, 65536));
  app.add_option("--lr", o.learning_rate, "AdamW learning rate")
      ->capture_default_str()
      ->check(CLI::Range(1e-7, 1.0));
  app.add_option("--max-minutes", max_minutes, "stop after this long (0: no limit)")
      ->capture_default_str();
  app.add_option("--seed", o.seed, "seed (units, presses, noise, initialisation, shuffling)")
      ->capture_default_str();
  app.add_option("--threads", o.threads, "LibTorch threads")
      ->capture_default_str()
      ->check(CLI::Range(1, 256));
  app.add_flag("-q,--quiet", quiet, "no per-epoch progress");
  CLI11_PARSE(app, argc, argv);

  auto design = sim::read_design_or_builtin(design_path);
  if (!design.ok()) return skinbus::tools::report_error("skinbus-train-proposer", design.error());
  for (int w : hidden) {
    if (w <= 0) return skinbus::tools::fail("skinbus-train-proposer", "--hidden: bad width", 2);
  }
  o.architecture = mlp(hidden);
  o.name = name.empty() ? out_path.substr(out_path.find_last_of('/') + 1) : name;
  o.max_seconds = max_minutes * 60;
  if (!quiet) {
    o.progress = [](const EpochReport& r) {
      std::fprintf(stderr,
                   "epoch %4d/%d  loss %.4f  val %.4f  count right %.1f %%  XY %.2f mm  depth "
                   "%.3f mm  %6.1f s%s\n",
                   r.epoch, r.epochs, r.train_loss, r.val_loss, 100 * r.val_count_accuracy,
                   r.val_xy_mean_mm, r.val_depth_mean_mm, r.elapsed_s, r.improved ? "  *" : "");
    };
  }
  std::fprintf(stderr, "skinbus-train-proposer: %d samples on %d units, MLP", o.samples,
               o.units + 1);
  for (int w : hidden) std::fprintf(stderr, " %d", w);
  std::fprintf(stderr, "\n");
  Result<TrainResult> r = train_proposer(*design, o);
  if (!r.ok()) return skinbus::tools::report_error("skinbus-train-proposer", r.error());
  const auto& m = r->model.meta.metrics;
  std::fprintf(stderr,
               "kept epoch %d of %zu: validation count right %.1f %%, XY %.2f mm and depth %.3f mm "
               "over the samples counted right\n",
               r->best_epoch, r->history.size(), 100 * m.at("val_count_accuracy"),
               m.at("val_xy_mean_mm"), m.at("val_depth_mean_mm"));
  r->model.meta.info["design"] = design_path.empty() ? "(built-in)" : design_path;
  if (Status s = write_model(r->model, out_path); !s.ok()) {
    return skinbus::tools::report_error("skinbus-train-proposer", s.error());
  }
  std::fprintf(stderr, "wrote %s.safetensors and %s.json\n", model_stem(out_path).c_str(),
               model_stem(out_path).c_str());
  return 0;
}
