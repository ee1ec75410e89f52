#!/usr/bin/env bash
# Learning speed and memory, end to end (`gardefou learn`, whole process), on long
# events logs of the sorting line.
# Usage: bash benches/learn.sh [WORKDIR]
#   HOURS="131 1310 13100"  simulated hours (about 1 M, 10 M and 100 M events;
#                           13100 h need about 2 GB of disk in WORKDIR)
#   RUNS=3                  runs of each; the median wall time and the largest
#                           peak resident size are given
# Figures are reported in docs/performance.md.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
work=${1:-/tmp/gardefou-learn-bench}
hours=${HOURS:-131 1310 13100}
runs=${RUNS:-3}
cargo build --release --quiet --manifest-path "$root/Cargo.toml"
g=$root/target/release/gardefou
plant=$root/datasets/data/sorting/normal/plant.toml
mkdir -p "$work"
printf '%-10s %12s %8s %12s %8s\n' hours events "wall s" "events/s" "RSS MB"
for h in $hours; do
  log=$work/h$h/events.csv
  [ -f "$log" ] || "$g" simulate --duration "${h}h" --seed 11 --out "$work/h$h" 2>/dev/null
  events=$(($(wc -l <"$log") - 1))
  walls=() rss=0
  for _ in $(seq "$runs"); do
    /usr/bin/time -f "%e %M" -o "$work/time.txt" "$g" learn -q --plant "$plant" "$log" -o "$work/model-$h.json"
    read -r w r <"$work/time.txt"
    walls+=("$w")
    [ "$r" -gt "$rss" ] && rss=$r
  done
  wall=$(printf '%s\n' "${walls[@]}" | sort -g | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }')
  awk -v h="$h" -v e="$events" -v w="$wall" -v r="$rss" \
    'BEGIN { printf "%-10s %12d %8.2f %12.0f %8.1f\n", h, e, w, (w > 0 ? e / w : 0), r / 1024 }'
done
