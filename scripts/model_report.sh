#!/usr/bin/env bash
# Trains the per-patch networks on simulated data and measures every estimator: the source of
# docs/benchmarks/models.md and of the shipped default model (estimators/models/).
#
#   scripts/model_report.sh [work-dir]       (default build/models; trained models are cached there)
#   scripts/model_report.sh --ship           also copies the default model into estimators/models/
#
# Steps: datasets (skinbus-dataset), networks (skinbus-train; a model already in work-dir is not
# retrained), then skinbus-bench models, budget and finetune, writing tables, CSV and plots into
# docs/benchmarks/ (the tables also into work-dir/*_table.md). Training runs on one thread per
# network; training everything takes about two hours on 2 cores (most of it the seed CNNs), the
# benchmarks about 15 minutes.
set -euo pipefail
cd "$(dirname "$0")/.."
ship=0
work=build/models
for a in "$@"; do
  case "$a" in
    --ship) ship=1 ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
    *) work="$a" ;;
  esac
done
bin=build/tools
[[ -x $bin/skinbus-train ]] || scripts/build.sh
mkdir -p "$work" docs/benchmarks
threads=${SKINBUS_TRAIN_THREADS:-1}

dataset() {  # name, skinbus-dataset arguments...
  local name=$1; shift
  [[ -f $work/$name.csv ]] || "$bin/skinbus-dataset" "$@" -o "$work/$name.csv"
}
train() {  # name, minutes, data, skinbus-train arguments... (test split: $test_split)
  local name=$1 minutes=$2 data=$3; shift 3
  if [[ -f $work/$name.json ]]; then
    echo "model_report: $name: cached"
    return
  fi
  echo "model_report: training $name (at most $minutes min)"
  if ! "$bin/skinbus-train" "$work/$data.csv" -o "$work/$name" --test "$work/${test_split:-test_nominal}.csv" \
      --threads "$threads" --max-minutes "$minutes" --seed 1 "$@" >"$work/$name.log" 2>&1; then
    echo "model_report: training $name failed; its log:" >&2
    tail -20 "$work/$name.log" >&2
    exit 1
  fi
  grep -E "^(kept|test|  depth)" "$work/$name.log" || true
}

# The nominal patch: 1200 presses at Halton positions (dense synthetic training data) and the
# off-grid test split; the seed's 19 x 19 grid on three simulated units (the 361-press budget).
dataset halton1200_nominal --plan halton --count 1200
dataset test_nominal --plan random-test --count 2000 --seed 7
dataset grid_nominal --plan grid
dataset grid_fabricated --plan grid --fabricated
dataset grid_anisotropic --plan grid --fabricated --anisotropy 0.05
# Ten times as many press locations for the small network (ramps at 8 mm/s: a quarter of the
# samples per press, as --stride 4 keeps of the 2 mm/s ones).
dataset halton12k_nominal --plan halton --count 12000 --speed 8 --seed 5

# Networks for the estimator table (all on the Halton set).
train nominal_seed_cnn 35 halton1200_nominal --name nominal_seed_cnn --stride 4 --patience 20 --plateau 5
train cnn_w0.5 12 halton1200_nominal --width 0.5 --stride 4 --patience 20 --plateau 5
train cnn_w0.25 8 halton1200_nominal --width 0.25 --stride 4 --patience 20 --plateau 5
train cnn_w0.125 6 halton1200_nominal --width 0.125 --stride 4 --patience 20 --plateau 5
train mlp_256x256 5 halton1200_nominal --arch mlp --hidden 256,256 --stride 4 --patience 20 --plateau 5
# The small network: an MLP 48-128-128-128-128-4 on ten times the press locations, its XY loss
# weighted by depth (docs/benchmarks/models.md: what each part pays).
train mlp_128x128x128x128_12k 30 halton12k_nominal --arch mlp --hidden 128,128,128,128 \
  --batch 256 --epochs 150 --patience 40 --plateau 8 --xy-weight-depth 1.0 --xy-weight-floor 0.3
# A unit's own small network within the 361-press budget: identify the fabricated unit from
# its 19 x 19 grid, simulate 12000 presses of the identified unit, train the small network on
# them; tested on the fabricated unit itself.
[[ -f $work/fabricated_identified.json ]] ||
  "$bin/skinbus-identify" "$work/grid_fabricated.csv" -o "$work/fabricated_identified.json" |
  tee "$work/fabricated_identified.txt"
dataset halton12k_fabricated_identified --plan halton --count 12000 --speed 8 --seed 5 \
  --unit "$work/fabricated_identified.json"
dataset test_fabricated --plan random-test --count 2000 --seed 7 --fabricated
test_split=test_fabricated train mlp_128x128x128x128_12k_fabricated_identified 30 \
  halton12k_fabricated_identified --arch mlp --hidden 128,128,128,128 \
  --batch 256 --epochs 150 --patience 40 --plateau 8 --xy-weight-depth 1.0 --xy-weight-floor 0.3
# The seed recipe per unit: the seed CNN on that unit's 19 x 19 grid.
for unit in nominal fabricated anisotropic; do
  train "seed_recipe_$unit" 12 "grid_$unit" --stride 2 --patience 20 --plateau 5
done

"$bin/skinbus-bench" models --test "$work/test_nominal.csv" --train "$work/grid_nominal.csv" \
  --model "$work/nominal_seed_cnn" --model "$work/cnn_w0.5" --model "$work/cnn_w0.25" \
  --model "$work/cnn_w0.125" --model "$work/mlp_256x256" --model "$work/mlp_128x128x128x128_12k" \
  --csv docs/benchmarks/models.csv --errors-csv "$work/model_errors.csv" \
  --plot docs/benchmarks/models | tee "$work/models_table.md"
"$bin/skinbus-bench" models --test "$work/test_fabricated.csv" --no-reduced \
  --model "$work/nominal_seed_cnn" --model "$work/seed_recipe_fabricated" \
  --model "$work/mlp_128x128x128x128_12k" --model "$work/mlp_128x128x128x128_12k_fabricated_identified" \
  --csv docs/benchmarks/models_fabricated.csv | tee "$work/models_fabricated_table.md"
"$bin/skinbus-bench" budget --seed-model "nominal=$work/seed_recipe_nominal" \
  --seed-model "fabricated=$work/seed_recipe_fabricated" \
  --seed-model "anisotropic=$work/seed_recipe_anisotropic" \
  --csv docs/benchmarks/budget.csv | tee "$work/budget_table.md"
"$bin/skinbus-bench" finetune --base "$work/nominal_seed_cnn" --points 10,20,40,80,160 --epochs 15 \
  --csv docs/benchmarks/finetune.csv | tee "$work/finetune_table.md"
"$bin/skinbus-bench" finetune --base "$work/nominal_seed_cnn" --points 10,20,40,80,160 --epochs 15 \
  --anisotropy 0.05 --lr 1e-3 --csv docs/benchmarks/finetune_anisotropic.csv |
  tee "$work/finetune_anisotropic_table.md"
"$bin/skinbus-bench" finetune --base "$work/nominal_seed_cnn" --points 16,36,64,100 --plan grid \
  --epochs 15 --csv docs/benchmarks/finetune_grid.csv | tee "$work/finetune_grid_table.md"

if ((ship)); then
  mkdir -p estimators/models
  cp "$work/nominal_seed_cnn.json" "$work/nominal_seed_cnn.safetensors" estimators/models/
  echo "model_report: shipped estimators/models/nominal_seed_cnn"
fi
