#!/usr/bin/env bash
# Diagnosis speed and memory, end to end (`gardefou diagnose`, whole process), on
# long logs of the sorting line in two forms: events CSV and intervals Parquet.
#
# Usage: bash benches/diagnose.sh [WORKDIR]
#   HOURS="100 1000 5000"  simulated hours of the normal logs (default)
#   FAULTY="1000"          simulated hours of logs with F7 (unexpected rises of C4)
#                          from minute 10, after which the line keeps running;
#                          empty for none
# The model is learned from one simulated hour with another seed. Simulated logs
# are kept in WORKDIR (default: a fresh temporary directory, removed at the end)
# and reused when the script is run again on the same WORKDIR. 5000 h take about
# 1.8 GB of disk and a few minutes to simulate.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
hours=${HOURS:-100 1000 5000}
faulty=${FAULTY-1000}
if [ $# -ge 1 ]; then
  work=$1
  mkdir -p "$work"
else
  work=$(mktemp -d "${TMPDIR:-/tmp}/gardefou-diagnose-bench.XXXXXX")
  trap 'rm -rf "$work"' EXIT
fi

cargo build --release --quiet --manifest-path "$root/Cargo.toml"
g=$root/target/release/gardefou
plant=$root/datasets/plants/sorting.toml

if [ ! -f "$work/model.json" ]; then
  "$g" simulate --duration 1h --seed 3 --out "$work/learn" 2>/dev/null
  "$g" learn -q --plant "$plant" "$work/learn/events.csv" -o "$work/model.json"
fi

# simulate NAME DURATION [FAULT]: events.csv and intervals.parquet in $work/NAME.
simulate() {
  local dir=$work/$1
  [ -f "$dir/intervals.parquet" ] && return
  local fault=()
  [ $# -ge 3 ] && fault=(--fault "$3")
  "$g" simulate --duration "$2" --seed 7 "${fault[@]}" --parquet --out "$dir" 2>/dev/null
  rm -f "$dir/intervals.csv"
}

# seconds H:MM:SS.ss|M:SS.ss -> seconds.
seconds() {
  awk -F: '{ s = 0; for (i = 1; i <= NF; i++) s = s * 60 + $i; printf "%.2f", s }' <<<"$1"
}

rows=()
# measure NAME FILE: one row of the table.
measure() {
  local dir=$work/$1 log=$2
  local events=$(($(wc -l <"$dir/events.csv") - 1))
  local report
  report=$( { /usr/bin/time -v "$g" diagnose --plant "$plant" --model "$work/model.json" \
    "$dir/$log" >"$work/verdicts.jsonl"; } 2>&1 )
  local wall rss verdicts
  wall=$(seconds "$(sed -n 's/.*Elapsed (wall clock) time.*: //p' <<<"$report")")
  rss=$(sed -n 's/.*Maximum resident set size (kbytes): //p' <<<"$report")
  verdicts=$(wc -l <"$work/verdicts.jsonl")
  rows+=("$(awk -v n="$1/$log" -v e="$events" -v w="$wall" -v r="$rss" -v v="$verdicts" \
    'BEGIN { printf "%-34s %12d %8.2f %14.0f %11.1f %9d", n, e, w, (w > 0 ? e / w : 0), r / 1024, v }')")
}

for h in $hours; do
  simulate "normal-${h}h" "${h}h"
done
for h in $faulty; do
  simulate "f7-${h}h" "${h}h" F7@10min
done
for h in $hours; do
  measure "normal-${h}h" events.csv
  measure "normal-${h}h" intervals.parquet
done
for h in $faulty; do
  measure "f7-${h}h" events.csv
  measure "f7-${h}h" intervals.parquet
done

printf '%-34s %12s %8s %14s %11s %9s\n' log events "wall s" events/s "max RSS MB" verdicts
printf '%s\n' "${rows[@]}"
