#!/usr/bin/env bash
# Diagnosis speed and memory, end to end (`gardefou diagnose`, whole process), on
# long logs of the sorting line in two forms: events CSV and intervals Parquet.
#
# Usage: bash benches/diagnose.sh [WORKDIR]
#   HOURS="100 1000 5000"  simulated hours of the normal logs (default)
#   RUNS=3                 runs of each measurement; the table gives the median
#                          wall time and the largest peak sizes
#   THREADS=""             `--threads` of diagnose (default: the machine's cores)
#   FAULTY="1000"          simulated hours of logs with F7 (unexpected rises of C4)
#                          from minute 10, after which the line keeps running;
#                          empty for none
# The model is learned from one simulated hour with another seed. Simulated logs
# are kept in WORKDIR (default: a fresh temporary directory, removed at the end)
# and reused when the script is run again on the same WORKDIR. 5000 h take about
# 1.8 GB of disk and a few minutes to simulate.
#
# Columns: events in the log (rows of events.csv), wall time and maximum resident
# size of the whole process (/usr/bin/time -v), events per second, the largest
# anonymous resident size sampled during the run (anon MB: the resident size
# less memory-mapped file pages), and verdict lines written.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
hours=${HOURS:-100 1000 5000}
runs=${RUNS:-3}
threads=()
[ -n "${THREADS:-}" ] && threads=(--threads "$THREADS")
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

# anon PID: largest anonymous resident size (KB) of PID's child while PID runs,
# sampled every 20 ms. The whole resident size also counts the pages of
# memory-mapped files (the binary), which are the page
# cache's and reclaimable; this is the part that is the process's own.
anon() {
  local pid=$1 child="" max=0 key value _
  while kill -0 "$pid" 2>/dev/null; do
    [ -n "$child" ] || read -r child _ <"/proc/$pid/task/$pid/children" 2>/dev/null || true
    if [ -n "$child" ]; then
      while read -r key value _; do
        [ "$key" = RssAnon: ] && [ "$value" -gt "$max" ] && max=$value
      done <"/proc/$child/status" 2>/dev/null || true
    fi
    sleep 0.02
  done
  echo "$max"
}

rows=()
# once NAME FILE: one run; prints "wall rss anon".
once() {
  local dir=$work/$1 log=$2
  /usr/bin/time -v -o "$work/time.txt" "$g" diagnose "${threads[@]}" --plant "$plant" \
    --model "$work/model.json" "$dir/$log" >"$work/verdicts.jsonl" &
  local pid=$!
  local anon
  anon=$(anon "$pid")
  wait "$pid"
  echo "$(seconds "$(sed -n 's/.*Elapsed (wall clock) time.*: //p' "$work/time.txt")")" \
    "$(sed -n 's/.*Maximum resident set size (kbytes): //p' "$work/time.txt")" "$anon"
}

# measure NAME FILE: one row of the table (median wall of $runs runs).
measure() {
  local dir=$work/$1 log=$2
  local events=$(($(wc -l <"$dir/events.csv") - 1))
  local samples=() wall rss=0 anon=0 w r a verdicts
  for _ in $(seq "$runs"); do
    read -r w r a < <(once "$1" "$2")
    samples+=("$w")
    [ "$r" -gt "$rss" ] && rss=$r
    [ "$a" -gt "$anon" ] && anon=$a
  done
  wall=$(printf '%s\n' "${samples[@]}" | sort -g | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }')
  verdicts=$(wc -l <"$work/verdicts.jsonl")
  rows+=("$(awk -v n="$1/$log" -v e="$events" -v w="$wall" -v r="$rss" -v a="$anon" -v v="$verdicts" \
    'BEGIN { printf "%-30s %11d %7.2f %11.0f %9.1f %9.1f %8d", n, e, w, (w > 0 ? e / w : 0), r / 1024, a / 1024, v }')")
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

printf '%-30s %11s %7s %11s %9s %9s %8s\n' log events "wall s" events/s "RSS MB" "anon MB" verdicts
printf '%s\n' "${rows[@]}"
