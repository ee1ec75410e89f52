#!/usr/bin/env bash
# Latency of `gardefou monitor` at 10,000 events/s, in a release build.
#
# 1. One simulated day of the sorting line (about 196,000 events) is replayed
#    at the speed that makes 10,000 events per second. The monitor times every
#    scan and every deadline, from its evidence (the instant the scan is due,
#    the instant the deadline expires) to the diagnosers done with it.
# 2. The twelve shipped fault runs are replayed at the same speed, for the
#    latency of the verdict lines themselves (evidence to line written).
#
# Usage: scripts/bench-monitor.sh   (prints the monitor's own figures)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q
bin=target/release/gardefou
model=diagnoser/tests/fixtures/diagnosis/sorting-model.json
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT

"$bin" simulate --duration 24h --seed 8 --out "$dir/day" 2>/dev/null
events=$(($(wc -l < "$dir/day/events.csv") - 1))
speed=$(python3 -c "print(round(10000 * 86400 / $events))")
echo "day: $events events, replayed at --speed $speed (10,000 events/s)"
/usr/bin/time -f "wall %e s, peak RSS %M KB" "$bin" monitor \
  --plant "$dir/day/plant.toml" --model "$model" \
  --replay "$dir/day/events.csv" --speed "$speed" > /dev/null

echo "fault runs F1-F12 at --speed $speed:"
for f in F1 F2 F3 F4 F5 F6 F7 F8 F9 F10 F11 F12; do
  run=datasets/data/sorting/$f
  "$bin" monitor --plant "$run/plant.toml" --model "$model" \
    --replay "$run/events.csv" --speed "$speed" 2>&1 > /dev/null | grep latency | sed "s/^/$f /"
done
