#!/usr/bin/env bash
# One command from a lab recording of a patch's presses to a calibrated patch: its physics
# identified, its network trained on simulated presses of the identified unit, both measured,
# and the skin-map entry that tells skinbus-host to use them (the network, refined on the unit:
# docs/aggregator.md, "Physics refinement").
#
#   scripts/calibrate_unit.sh PRESSES.csv -o OUT [--held-out HELD.csv] [--design DESIGN.yaml]
#       [--node N] [--uid UID] [--link LINK] [--epochs N] [--synthetic N] [--base MODEL]
#       [--max-residual R]
#
# PRESSES.csv: the unit's presses at known places and depths (docs/dataset_format.md), e.g. the
# seed's 19 x 19 grid of ramps by an indentation robot (361 presses). HELD.csv: other presses of
# the same unit, not fitted, on which both are measured (default: none; the network is then
# measured on simulated presses of the identified unit). DESIGN.yaml: the patch's design file
# (docs/design_file.md; default: the built-in design). R: identification refuses a fit leaving
# more than this residual, noise units (skinbus-identify's --max-residual, 4). Writes into OUT:
#   unit.json            the identified unit (skinbus-identify), with its learned field
#                          correction when that lowers the residual at press places held out of
#                          its fit (skinbus-identify --field-correction; docs/physics_estimator.md,
#                          "The field correction"): what the unit's field does beyond the model
#                          class, used by every later step (the simulated presses, the bound, the
#                          refinement). A fit the class alone leaves above R is kept when the
#                          correction brings that held-out residual within R.
#   identify.log         its fit: residuals in noise units, overall and per depth bin
#   network.safetensors  the unit's network (skinbus-train: fine-tuned from --base, the shipped
#   network.json           model by default ('none': trained from scratch), on --synthetic (2000)
#                          simulated presses of the identified unit, each a ramp sampled at 8 Hz
#                          as deep as the deepest of PRESSES.csv, over the design's whole surface
#                          (and wherever PRESSES.csv reaches beyond it), 10 % short of where
#                          the design's lattice stops a press (0.6 x its thickness) at most;
#                          about 15 s an epoch on two cores, --epochs (30) at most; with a
#                          --design and the shipped model, also from scratch, and the one with
#                          the lower error on the simulated presses held out of training kept
#                          (choice.log: the shipped model learned on the built-in patch); from
#                          scratch when the patch has another sensor count than the shipped
#                          model's 16; when its sensors form no grid, an MLP (512-512-256) on
#                          four times as many simulated presses, its epochs cheap: --epochs
#                          (400) at most, 8 minutes at most unless --epochs is given)
#   train.log            its training
#   correction.json      the unit's learned correction of the refined estimate (skinbus-evaluate
#                        --fit-correction on PRESSES.csv), written only if it lowers the error on
#                        presses it was not fitted on (five folds of press places), and with
#                        HELD.csv kept only if it does not raise the refined XY or depth mean there
#                        by more than 1 % (else correction_not_kept.json, named in the report)
#   report.md            the residuals, the network's errors per depth bin next to the design's
#                        Cramer-Rao bound, the correction's held-out check, and the network refined
#                        on the unit as the host runs them (skinbus-evaluate; with the correction
#                        too, on HELD.csv) next to the unit's bound at the same presses
#   skin_map_entry.yaml  the entry for the skin map (position and orientation: skinbus-calibrate)
# A unit the design's model class cannot explain, even with its field correction (skinbus-identify
# refuses it, naming why: the design file is not the patch, or its physics lie too far outside the
# class) takes the network route instead: no unit.json and no correction; the network is trained
# on the unit's own presses, measured on HELD.csv when given, and the entry names the network
# alone (skinbus-host then publishes the network's contacts, unrefined). When identification
# made a fit it refused (refused_fit.json: the class's nearest model of the unit, never refined
# on; none when a global ran to its bound), two ways are trained and the one with the lower
# error on the unit's presses held out of training is kept (choice.log): --synthetic simulated
# presses of the refused fit, then the unit's own from that network (network_from_refused); the
# unit's own alone (network_own). The report says which, and why.
# Progress: one line per step on standard error; each tool's own progress in its log.
# Exit status: 0 done, 1 a step failed (its log says why), 2 bad arguments.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bin=${SKINBUS_BIN:-$root/build/tools}
usage() {
  sed -n '6,9p' "$0" | sed 's/^# //' >&2
  exit 2
}
presses="" out="" held="" design="" node=1 uid="" link="LINK" epochs="" synthetic=2000 base_given=0
max_residual=()
base=$root/estimators/models/nominal_seed_cnn
while (($#)); do
  case $1 in
    -o) out=${2:?}; shift 2 ;;
    --held-out) held=${2:?}; shift 2 ;;
    --design) design=${2:?}; shift 2 ;;
    --node) node=${2:?}; shift 2 ;;
    --uid) uid=${2:?}; shift 2 ;;
    --link) link=${2:?}; shift 2 ;;
    --epochs) epochs=${2:?}; shift 2 ;;
    --synthetic) synthetic=${2:?}; shift 2 ;;
    --base) base=${2:?}; base_given=1; shift 2 ;;
    --max-residual) max_residual=(--max-residual "${2:?}"); shift 2 ;;
    -h | --help) sed -n '2,61p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "calibrate_unit: unknown option $1" >&2; usage ;;
    *) [[ -z $presses ]] || usage; presses=$1; shift ;;
  esac
done
[[ -n $presses && -n $out ]] || usage
[[ -f $presses ]] || { echo "calibrate_unit: $presses: no such file" >&2; exit 2; }
[[ -z $held || -f $held ]] || { echo "calibrate_unit: $held: no such file" >&2; exit 2; }
[[ -z $design || -f $design ]] || { echo "calibrate_unit: $design: no such file" >&2; exit 2; }
for tool in skinbus-identify skinbus-dataset skinbus-train skinbus-crlb skinbus-evaluate; do
  [[ -x $bin/$tool ]] || { echo "calibrate_unit: $bin/$tool missing: scripts/build.sh" >&2; exit 1; }
done
mkdir -p "$out"
design_opt=()
[[ -n $design ]] && design_opt=(--design "$design")
step() { echo "calibrate_unit: [$1/5] $2 ($(date +%T))" >&2; }
failed() { echo "calibrate_unit: $1 failed; see $2" >&2; exit 1; }

step 1 "identifying the unit's physics from $presses"
held_opt=()
[[ -n $held ]] && held_opt=(--held-out "$held")
rm -f "$out/unit.json" "$out/refused_fit.json" "$out/correction.json" \
  "$out/correction_not_kept.json" "$out/evaluate.log" "$out/evaluate_corrected.log" \
  "$out/choice.log" "$out"/network_{refused_fit,from_refused,own,finetuned,scratch}.* \
  "$out"/train_{refused_fit,from_refused,own,finetuned,scratch}.log
# A unit the design's model class cannot explain (identification refuses it, naming why) is
# calibrated by the network route instead: the unit's network trained on its own presses (alone,
# and after the refused fit's simulated ones when there is one: the better kept), no unit file,
# and so no physics refinement in the host.
network_route=0
if ! "$bin/skinbus-identify" "$presses" -o "$out/unit.json" "${design_opt[@]}" "${held_opt[@]}" \
  "${max_residual[@]}" --field-correction --refused-out "$out/refused_fit.json" \
  >"$out/identify.log" 2>&1; then
  grep -q "not_converged" "$out/identify.log" || failed "identification" "$out/identify.log"
  network_route=1
  grep -o "not_converged: .*" "$out/identify.log" | cut -c1-400 >&2 || true
  echo "calibrate_unit: identification refused this unit: the network route instead (the" \
    "unit's network trained on its own presses$([[ -f $out/refused_fit.json ]] &&
      echo ", alone and after the refused fit's simulated ones, the better kept"); no unit" \
    "file, no physics refinement)" >&2
fi
# Lab presses deeper than the model's lattice takes, left out of the fit.
grep "deeper than .*: left out" "$out/identify.log" >&2 || true
grep -i "residual\|note:" "$out/identify.log" | grep -v "^note: the lag" | head -4 >&2 || true
# A lag chosen on ramps alone on a unit that crushes: the lab should record held presses.
grep "^note: the lag" "$out/identify.log" >&2 || true

from_refused=0  # the network route, started from the refused fit's simulated presses
simulated_unit=""  # the unit file synthetic.csv simulates
mlp=0  # the sensors form no grid: every network is an MLP
most_epochs() { if ((mlp)); then echo "${epochs:-400}"; else echo "${epochs:-30}"; fi; }
# The simulated presses go as deep as the lab's deepest (to 0.1 mm; 4 mm when the recording says
# no depth): a network trained shallower than the unit is pressed misplaces the deepest presses.
deepest_mm=$(awk -F, '/^#/ {next} !n {for (i = 1; i <= NF; i++) c[$i] = i; n = 1; next}
  c["depth_mm"] && $c["depth_mm"] + 0 > d {d = $c["depth_mm"] + 0}
  END {printf "%.1f", (d < 1 ? 4 : (d > 9 ? 9 : d))}' "$presses")
# They cover the patch's whole surface (and wherever the lab pressed beyond it): the robot is
# touched anywhere on it, and a network trained on a smaller area misplaces presses outside it.
simulate() {  # COUNT: synthetic.csv, COUNT ramps of $simulated_unit at Halton points, 8 Hz
  "$bin/skinbus-dataset" --plan halton --count "$1" --rate 8 --max-depth "$deepest_mm" \
    --area surface --unit "$simulated_unit" "${design_opt[@]}" -o "$out/synthetic.csv" \
    >"$out/dataset.log" 2>&1 ||
    failed "the synthetic presses" "$out/dataset.log"
  # No deeper than 10 % short of the lattice's stop in the model (skinbus-dataset says so).
  grep "not --max-depth" "$out/dataset.log" >&2 || true
}
if ((network_route)); then
  train_set=$presses
  test_set=$held
  if [[ -f $out/refused_fit.json ]]; then
    from_refused=1
    step 2 "simulating $synthetic presses of the refused fit (the class's nearest model of the unit, to start its network from; never refined on)"
    simulated_unit=$out/refused_fit.json
    simulate "$synthetic"
  else
    step 2 "no presses simulated: identification kept no fit to simulate"
  fi
else
  step 2 "simulating $synthetic presses of the identified unit over its surface (ramps to $deepest_mm mm sampled at 8 Hz)"
  simulated_unit=$out/unit.json
  simulate "$synthetic"
  "$bin/skinbus-dataset" --plan random-test --count 500 --seed 7 --max-depth "$deepest_mm" \
    --area pressed --unit "$out/unit.json" "${design_opt[@]}" -o "$out/synthetic_test.csv" \
    >>"$out/dataset.log" 2>&1 ||
    failed "the synthetic test presses" "$out/dataset.log"
  train_set=$out/synthetic.csv
  test_set=${held:-$out/synthetic_test.csv}
fi

# The shipped network reads the built-in design's 16 sensors: a patch with another count trains
# from scratch (a --base given by hand is used as given, and skinbus-train names a mismatch).
if [[ $base_given == 0 ]]; then
  base_sensors=$(python3 -c 'import json, sys; print(len(json.load(open(sys.argv[1] + ".json"))["sensors_uvh_mm"]))' "$base" 2>/dev/null || true)
  unit_sensors=$(sed -n 's/^# sensors: \([0-9]*\).*/\1/p' "$train_set" | head -1)
  if [[ -n $base_sensors && $base_sensors != "$unit_sensors" ]]; then
    echo "calibrate_unit: the shipped network reads $base_sensors sensors, this patch has" \
      "${unit_sensors:-?}: training from scratch (--base none)" >&2
    base=none
  fi
fi
from="from $(basename "$base")"
[[ $base == none ]] && from="from scratch"
on="simulated presses of the identified unit"
((network_route)) && on="the unit's own presses"
((from_refused)) && on="the refused fit's simulated presses"
step 3 "training the unit's network on $on ($(most_epochs) epochs at most, $from)"
base_opt=()
# Fine-tuning starts from a trained network: a smaller step than training from scratch.
[[ -n $base && $base != none ]] && base_opt=(--base "$base" --lr 3e-4)
test_opt=()
[[ -n $test_set ]] && test_opt=(--test "$test_set")
train() {  # DATASET OUTPUT LOG [skinbus-train options...]
  local data=$1 output=$2 log=$3
  shift 3
  # An MLP's epoch costs a fraction of the CNN's: more of them, within about the CNN's time.
  local budget=(--epochs "$(most_epochs)")
  ((mlp)) && [[ -z $epochs ]] && budget+=(--max-minutes 8)
  "$bin/skinbus-train" "$data" -o "$output" "${test_opt[@]}" "${budget[@]}" "$@" >"$log" 2>&1
}
train_or_mlp() {  # DATASET OUTPUT LOG [skinbus-train options...]
  if ((mlp)) || ! train "$@"; then
    # The seed CNN places each sensor in a grid cell; sensors that form no grid need the MLP.
    # Without the CNN's shared filters it needs more presses: simulated ones are cheap.
    ((mlp)) || grep -q "use an MLP" "$3" || failed "training" "$3"
    if ((!mlp)); then
      mlp=1
      echo "calibrate_unit: the sensors do not form a grid: training an MLP instead (--arch" \
        "mlp --hidden 512,512,256, $(most_epochs) epochs at most$([[ -z $epochs ]] &&
          echo ", 8 minutes at most"))" >&2
    fi
    if [[ $1 == "$out/synthetic.csv" && -n $simulated_unit ]]; then
      echo "calibrate_unit: [2/5] ... simulating $((4 * synthetic)) presses for the MLP" >&2
      simulate $((4 * synthetic))
    fi
    train "$1" "$2" "$3" --arch mlp --hidden 512,512,256 || failed "training" "$3"
  fi
  tail -1 "$3" >&2
}
adopt() {  # NAME: NAME's network and its training log become the unit's network
  cp "$out/$1.safetensors" "$out/network.safetensors"
  python3 - "$out" "$1" <<'PY' || failed "keeping $1" "$out/$1.json"
import json, sys
out, name = sys.argv[1:3]
meta = json.load(open(f"{out}/{name}.json"))
meta.update(name="network", weights="network.safetensors")
json.dump(meta, open(f"{out}/network.json", "w"), indent=2)
PY
  cp "$out/train_${1#network_}.log" "$out/train.log"
}
# Keeps the better of two trained ways as network (choice.log): NAME1 WHAT1 NAME2 WHAT2, each
# NAME's network and train_${NAME#network_}.log written. The score each training kept its epoch
# by (its metadata's val_score: XY of the held-out presses at least 1 mm deep plus their depth
# error, estimators/include/skinbus/estimators/training.h); both trainings split the same
# presses with the same seed, so the two scores are on the same held-out places, and the lower
# one is kept.
keep_better() {
  local kept
  kept=$(python3 - "$out" "$@" <<'PY'
import json, sys
out, ways = sys.argv[1], list(zip(sys.argv[2::2], sys.argv[3::2]))
rows, scores = [], {}
for name, what in ways:
    m = json.load(open(f"{out}/{name}.json"))
    m = m.get("metrics", m.get("meta", {}).get("metrics", {}))
    xy, depth, scores[name] = m["val_xy_deep_mean_mm"], m["val_depth_mean_mm"], m["val_score"]
    rows.append(f"| {what} ({name}) | {xy:.3f} | {depth:.3f} | {scores[name]:.3f} |")
best = min(scores, key=scores.get)
with open(f"{out}/choice.log", "w") as f:
    f.write("| way | held-out XY, >= 1 mm deep (mm) | held-out depth (mm) | score |\n"
            "|---|---:|---:|---:|\n" + "\n".join(rows) + "\n\n")
    f.write(f"Kept: {best} (the lower score), as network.\n")
print(best, "(held-out scores: " + ", ".join(f"{n} {s:.3f}" for n, s in scores.items()) + ")")
PY
  ) || failed "the choice between the two ways" "$out/choice.log"
  echo "calibrate_unit: [3/5] kept $kept" >&2
  adopt "${kept%% *}"
}
if ((from_refused)); then
  # Two ways, chosen by held-out error. First the refused fit's presses (what the class gets
  # right of the unit), then the unit's own from that network (what it gets wrong); and the
  # unit's own presses alone. Each keeps its best epoch on its validation split of the unit's
  # press places.
  train_or_mlp "$out/synthetic.csv" "$out/network_refused_fit" "$out/train_refused_fit.log" \
    "${base_opt[@]}"
  echo "calibrate_unit: [3/5] ... then on the unit's own presses, from that network" \
    "($(most_epochs) epochs at most)" >&2
  train "$train_set" "$out/network_from_refused" "$out/train_from_refused.log" \
    --base "$out/network_refused_fit" --lr 3e-4 || failed "training" "$out/train_from_refused.log"
  tail -1 "$out/train_from_refused.log" >&2
  echo "calibrate_unit: [3/5] ... and on the unit's own presses alone ($(most_epochs) epochs at most," \
    "$from), to choose between the two by held-out error" >&2
  train_or_mlp "$train_set" "$out/network_own" "$out/train_own.log" "${base_opt[@]}"
  keep_better network_from_refused "the refused fit's simulated presses, then the unit's own" \
    network_own "the unit's own presses alone"
elif ((!network_route && ${#design_opt[@]} && !base_given && ${#base_opt[@]})); then
  # Another design than the shipped network's: its weights and scaling were learned on the
  # built-in patch (140 mm, fields of hundreds of uT) and can be a worse start than none (a 48 mm
  # fingertip read at thousands of uT: 0.39 mm fine-tuned, 0.11 mm from scratch, 30 epochs
  # each). Both ways, the better by the simulated presses held out of training.
  train_or_mlp "$train_set" "$out/network_finetuned" "$out/train_finetuned.log" "${base_opt[@]}"
  if ((!mlp)); then
    echo "calibrate_unit: [3/5] ... and from scratch ($(most_epochs) epochs at most), to choose" \
      "between the two by held-out error" >&2
    train_or_mlp "$train_set" "$out/network_scratch" "$out/train_scratch.log"
    keep_better network_finetuned "fine-tuned $from" network_scratch "from scratch"
  else
    adopt network_finetuned  # an MLP (the sensors form no grid): from scratch already
  fi
else
  train_or_mlp "$train_set" "$out/network" "$out/train.log" "${base_opt[@]}"
fi

if ((network_route)); then
  step 4 "no learned correction: it corrects an identified unit's refined estimates"
  echo "The network route: no identified unit, so no correction of its refined estimates." \
    >"$out/correction.log"
else
  step 4 "learning what the unit's model misses from its presses (kept if it helps held-out ones)"
  "$bin/skinbus-evaluate" "$presses" --model "$out/network" --unit "$out/unit.json" \
    "${design_opt[@]}" --fit-correction "$out/correction.json" >"$out/correction.log" 2>&1 ||
    failed "the learned correction" "$out/correction.log"
  grep "^Learned correction" "$out/correction.log" >&2 || true
fi

step 5 "writing the report and the skin-map entry"
"$bin/skinbus-crlb" --depths 1.5 2.5 3.5 --ambient --area surface "${design_opt[@]}" >"$out/crlb.log" 2>&1 ||
  failed "the Cramer-Rao bound" "$out/crlb.log"
# The network refined on the unit, as the host runs them, on the same presses.
if ((!network_route)); then
  "$bin/skinbus-evaluate" "$test_set" --model "$out/network" --unit "$out/unit.json" \
    "${design_opt[@]}" >"$out/evaluate.log" 2>&1 || failed "the evaluation" "$out/evaluate.log"
fi
# With held-out lab presses and a correction, the same refined on the unit and corrected (on
# simulated presses of the identified unit a correction of what the model misses means nothing).
if [[ -n $held && -f $out/correction.json ]]; then
  "$bin/skinbus-evaluate" "$test_set" --model "$out/network" --unit "$out/unit.json" \
    "${design_opt[@]}" --correction "$out/correction.json" >"$out/evaluate_corrected.log" 2>&1 ||
    failed "the corrected evaluation" "$out/evaluate_corrected.log"
  # Kept only if the unit's own held-out presses agree: its check on PRESSES.csv's places can
  # pass a correction that moves presses elsewhere on the patch the wrong way. The refined XY
  # and depth means over every press at least 1 mm deep (the first table: every press).
  read -r xy_plain xy_corr d_plain d_corr verdict < <(python3 - "$out/evaluate.log" \
    "$out/evaluate_corrected.log" <<'PY'
import re, sys
row = re.compile(r"^\| \d+-\d+ \| (\d+) \| [0-9.]+ \| ([0-9.]+) \| [0-9.]+ \| [0-9.]+ \| "
                 r"[0-9.]+ \| ([0-9.]+) \|")
def means(path):
    rows = []
    for line in open(path):
        m = row.match(line)
        if m:
            rows.append([float(g) for g in m.groups()])
        elif rows:
            break
    n = sum(r[0] for r in rows)
    if not n:
        return float("nan"), float("nan")
    return sum(r[0] * r[1] for r in rows) / n, sum(r[0] * r[2] for r in rows) / n
(xy0, d0), (xy1, d1) = means(sys.argv[1]), means(sys.argv[2])
keep = xy1 <= 1.01 * xy0 and d1 <= 1.01 * d0
print(f"{xy0:.3f} {xy1:.3f} {d0:.3f} {d1:.3f} {'keep' if keep else 'drop'}")
PY
  )
  if [[ $verdict != keep ]]; then
    mv "$out/correction.json" "$out/correction_not_kept.json"
    why="on the held-out presses ($held) it moved the refined presses the wrong way (XY mean"
    why+=" $xy_plain -> $xy_corr mm, depth mean $d_plain -> $d_corr mm, presses >= 1 mm deep)"
    echo "Not kept: $why; left in correction_not_kept.json, out of the skin-map entry." \
      >>"$out/correction.log"
    echo "calibrate_unit: the learned correction is not kept: $why" >&2
  fi
fi
python3 - "$out" "$presses" "$test_set" "${held:+held-out lab presses}" "$network_route" <<'PY'
import json, os, re, sys
out, presses, test_set, held, network_route = sys.argv[1:6]
network_route = network_route == "1"
meta = json.load(open(f"{out}/network.json"))
metrics = meta.get("metrics", meta.get("meta", {}).get("metrics", {}))
bound = {}
for line in open(f"{out}/crlb.log"):
    m = re.match(r"\| ([0-9.]+) \| ([0-9.]+) \|", line)
    if m:
        bound[float(m.group(1))] = float(m.group(2))
ident = [l.rstrip() for l in open(f"{out}/identify.log") if l.strip()]
rows = []
for name, mid in (("1-2", 1.5), ("2-3", 2.5), ("3-4", 3.5)):
    xy = metrics.get(f"test_xy_mean_mm_depth_{name}")
    d = metrics.get(f"test_depth_mean_mm_depth_{name}")
    b = bound.get(mid)
    ratio = f"{xy / b:.2f}" if xy is not None and b else "-"
    fmt = lambda v: f"{v:.3f}" if isinstance(v, (int, float)) else "-"
    rows.append(f"| {name} | {fmt(xy)} | {fmt(b)} | {ratio} | {fmt(d)} |")
with open(f"{out}/report.md", "w") as f:
    f.write(f"# Unit calibration: {presses}\n\n")
    f.write("## Identification (skinbus-identify)\n\n```\n" + "\n".join(ident[-24:]) + "\n```\n\n")
    f.write("A residual near 1 noise unit: the model explains the unit to its noise; clearly above"
            " (> 1.1): the unit has physics the model class lacks.\n\n")
    choice_log = f"{out}/choice.log"
    choice = open(choice_log).read() if os.path.exists(choice_log) else ""
    from_refused = "Kept: network_from_refused" in choice
    if network_route:
        f.write("**Identification refused this unit** (above): the design's model class does not "
                "explain its presses, so there is no unit file and skinbus-host will not refine "
                "its contacts. The network route instead: the unit's network, trained on the "
                + ("simulated presses of the refused fit (refused_fit.json, the class's nearest "
                   "model of the unit: never refined on), then on the "
                   if from_refused else "")
                + f"unit's own presses ({presses}). Check the design file against the patch; a "
                "unit the class explains is calibrated better (refined on the identified "
                "unit).\n\n")
    if choice:
        f.write("## The way kept, by held-out error\n\nEach way's network on the presses of "
                "its training set held out of its training (the same press places for both: "
                "skinbus-train's validation split), scored as training keeps its epochs:\n\n"
                + choice + "\n")
    tested_on = held or ("simulated test presses of the identified unit" if not network_route
                         else "no presses it was not trained on: give --held-out to measure it")
    f.write(f"## The unit's network on {tested_on}" + (f" ({test_set})" if test_set else "")
            + "\n\n")
    f.write("| depth (mm) | XY mean (mm) | design's CRLB, map mean (mm) | x CRLB | depth mean (mm) |\n")
    f.write("|---|---:|---:|---:|---:|\n" + "\n".join(rows) + "\n\n")
    f.write(f"Overall: XY mean {metrics.get('test_xy_mean_mm', float('nan')):.3f} mm, depth mean "
            f"{metrics.get('test_depth_mean_mm', float('nan')):.3f} mm. The bound is the design's"
            " (nominal unit, ambient field estimated) averaged over the patch at 1.5, 2.5 and 3.5 mm"
            ", not at the test presses themselves.\n\n")
    # Depths the design's lattice does not reach in the model: no bound, and presses there read
    # as its deepest (skinbus-crlb says so).
    f.write("".join(l.strip() + " A row there is not a figure of the patch.\n\n"
                    for l in open(f"{out}/crlb.log") if "lattice compresses" in l))
    f.write(f"## The learned correction ({presses})\n\n")
    f.write("".join(l for l in open(f"{out}/correction.log")
                    if l.startswith(("Learned", "Written", "It helps", "The network route",
                                     "Not kept")))
            + "\n")
    if os.path.exists(f"{out}/evaluate.log"):
        f.write(f"## The network refined on the unit, as skinbus-host runs them ({test_set})\n\n")
        f.write(open(f"{out}/evaluate.log").read() + "\n")
    if os.path.exists(f"{out}/evaluate_corrected.log"):
        f.write(f"## The same, corrected by the learned correction ({test_set})\n\n"
                if os.path.exists(f"{out}/correction.json") else
                f"## The same with the learned correction not kept ({test_set})\n\n")
        f.write(open(f"{out}/evaluate_corrected.log").read() + "\n")
PY
design_line=""
[[ -n $design ]] && design_line="    design: $(realpath "$design")"$'\n'
uid_line=""
[[ -n $uid ]] && uid_line="    uid: $uid"$'\n'
{
  echo "  - node: $node"
  printf '%s' "$uid_line"
  echo "    link: $link"
  echo "    position_mm: [0, 0, 0]     # where the patch sits on its link: skinbus-calibrate"
  echo "    model: $(realpath "$out")/network"
  if ((!network_route)); then
    echo "    unit: $(realpath "$out")/unit.json"
    printf '%s' "$design_line"
  fi
  [[ -f $out/correction.json ]] && echo "    correction: $(realpath "$out")/correction.json"
} >"$out/skin_map_entry.yaml"
echo "calibrate_unit: done: $out/report.md, $out/skin_map_entry.yaml" >&2
