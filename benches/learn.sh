#!/usr/bin/env bash
# Learning speed and memory on 1 M, 10 M and 100 M events of the sorting line.
# Usage: bash benches/learn.sh [WORKDIR]   (needs about 2 GB of disk in WORKDIR)
# Figures are reported in docs/performance.md.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
work=${1:-/tmp/gardefou-learn-bench}
cargo build --release --quiet --manifest-path "$root/Cargo.toml"
g=$root/target/release/gardefou
plant=$root/datasets/data/sorting/normal/plant.toml
mkdir -p "$work"
for hours in 131 1310 13100; do
  [ -f "$work/h$hours/events.csv" ] || "$g" simulate --duration "${hours}h" --seed 11 --out "$work/h$hours"
  echo "== $(($(wc -l < "$work/h$hours/events.csv") - 1)) rows ($hours simulated hours)"
  /usr/bin/time -v "$g" learn -q --plant "$plant" "$work/h$hours/events.csv" -o "$work/model-$hours.json" 2>&1 \
    | grep -E "Elapsed|Maximum resident"
done
