#!/usr/bin/env bash
# Replays one faulty run of the generality benchmark with the command line
# alone: the generated plant, its learning logs, the model, the faulty log with
# its ground truth, the verdicts and what `check` says of the fault.
#
# Usage: bash benches/generality-rerun.sh PLANT_SEED SIZE LABEL ONSET_MS END_MS \
#            [LEARN_RUNS] [LEARN_MS] [OUT_DIR]
# (the benchmark prints this line for each disagreement). Set GARDEFOU to a
# gardefou binary to use it instead of building the release binary; FAMILY
# to a plant family other than assembly, FACTOR to a slow fault's factor.
set -euo pipefail
if [ $# -lt 5 ]; then
  sed -n '2,10p' "$0" >&2
  exit 2
fi
seed=$1 size=$2 label=$3 onset=$4 end=$5
runs=${6:-3} learn_ms=${7:-3600000}
out=${8:-$(mktemp -d)}
root=$(cd "$(dirname "$0")/.." && pwd)
g=${GARDEFOU:-}
if [ -z "$g" ]; then
  cargo build --release --quiet --manifest-path "$root/Cargo.toml"
  g=$root/target/release/gardefou
fi

# The learning logs use run seeds 1, 2, ...; the faulty run uses run seed 200
# (see evaluation/src/evaluate.rs).
logs=()
for r in $(seq 1 "$runs"); do
  "$g" simulate --plant generated --family "${FAMILY:-assembly}" --plant-seed "$seed" --size "$size" --seed "$r" \
    --duration "${learn_ms}ms" --out "$out/learn$r" 2>/dev/null
  logs+=("$out/learn$r/events.csv")
done
"$g" learn -q --plant "$out/learn1/plant.toml" "${logs[@]}" -o "$out/model.json"
"$g" simulate --plant generated --family "${FAMILY:-assembly}" --plant-seed "$seed" --size "$size" --seed 200 \
  --duration "${end}ms" --fault "$label@${onset}ms${FACTOR:+:x$FACTOR}" --out "$out/fault" 2>/dev/null
echo "== truth ($out/fault/truth.json)"
cat "$out/fault/truth.json"
echo "== verdicts (gardefou diagnose --end $end)"
"$g" diagnose --plant "$out/fault/plant.toml" --model "$out/model.json" \
  "$out/fault/events.csv" --end "$end"
echo "== check"
"$g" check --plant "$out/fault/plant.toml" --model "$out/model.json" | grep -F -A4 "  $label " || true
echo "== files in $out"
