#!/usr/bin/env bash
# Regenerates every log shipped in datasets/data with gardefou.
# Usage (from anywhere): bash datasets/regenerate.sh [OUTPUT_DIR]
# OUTPUT_DIR defaults to datasets/data. Set GARDEFOU to a gardefou binary to use
# it instead of building the release binary (the tests do this).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
d=${1:-$root/datasets/data}
g=${GARDEFOU:-}
if [ -z "$g" ]; then
  cargo build --release --quiet --manifest-path "$root/Cargo.toml"
  g=$root/target/release/gardefou
fi

rm -rf "$d"
"$g" simulate --plant sorting --duration 1h --seed 7 --out "$d/sorting/normal"
# One run per seed 002 turntable fault. At 602 s the turntable has just come back
# to the loading position, so each fault starts from a quiet, known state.
for f in F1 F2 F3 F4 F5 F6 F7 F8 F9 F10 F11 F12; do
  "$g" simulate --plant sorting --duration 20min --seed 7 --fault "$f@602s" --out "$d/sorting/$f"
done
"$g" simulate --plant cylinders --duration 1h --seed 7 --out "$d/cylinders/normal"
"$g" simulate --plant cylinders --duration 20min --seed 7 --fault "stuck1(Se0)@600s" --out "$d/cylinders/Se0-stuck1"
"$g" simulate --plant cylinders --duration 20min --seed 7 --fault "blocked_between(V1, Se0, Se1)@600s" --out "$d/cylinders/V1-blocked-between"
