#!/usr/bin/env bash
# Cost of `gardefou report` on a day-long log, in a release build.
#
# 1. One simulated day of the sorting line, F2 injected at 23:00, is diagnosed
#    with the model learned from the shipped normal run and written as the HTML
#    report: wall time and peak RSS of that, and the report's size.
# 2. The report is opened five times in headless Chromium
#    (tests/browser/check-report.mjs): time until every timeline is drawn, as the
#    page measures it (rendered_ms, from navigation start) and as seen from
#    outside (load_ms, from the navigation request), per run and the worst.
#
# Usage: scripts/bench-report.sh [OUT_DIR]
#   OUT_DIR keeps the simulated day, the report and the screenshots
#   (by default a temporary directory, removed at the end).
# Needs Chromium (apt-get install chromium) and `npm ci --prefix tests/browser`.
set -euo pipefail
cd "$(dirname "$0")/.."

die() {
  echo "bench-report: $*" >&2
  exit 1
}

if [ -x /usr/bin/chromium ]; then
  chromium=/usr/bin/chromium
else
  chromium=$(command -v chromium) || die "Chromium is missing (apt-get install chromium)"
fi
command -v node >/dev/null || die "Node.js is missing (apt-get install nodejs npm)"
[ -d tests/browser/node_modules/playwright-core ] ||
  die "playwright-core is missing (npm ci --prefix tests/browser)"

if [ $# -ge 1 ]; then
  dir=$1
  mkdir -p "$dir"
else
  dir=$(mktemp -d)
  trap 'rm -rf "$dir"' EXIT
fi

# Runs a command with its stderr kept aside, shown only if it fails.
quiet() {
  if ! "$@" 2>"$dir/stderr.txt"; then
    cat "$dir/stderr.txt" >&2
    die "failed: $*"
  fi
}

cargo build --release -q
bin=target/release/gardefou

quiet "$bin" simulate --plant sorting --duration 24h --seed 7 --fault F2@82800s --out "$dir/day"
events=$(($(wc -l <"$dir/day/events.csv") - 1))
echo "day: $events events (sorting line, 24 h, seed 7, F2 at 23:00)"

quiet "$bin" learn --plant datasets/data/sorting/normal/plant.toml -q \
  -o "$dir/model.json" datasets/data/sorting/normal/events.csv

report=$dir/report.html
if ! /usr/bin/time -v "$bin" report --plant "$dir/day/plant.toml" --model "$dir/model.json" \
  --end 86400000 "$dir/day/events.csv" -o "$report" 2>"$dir/time.txt" >/dev/null; then
  cat "$dir/time.txt" >&2
  die "gardefou report failed"
fi
wall=$(sed -n 's/^\s*Elapsed (wall clock) time (h:mm:ss or m:ss): //p' "$dir/time.txt")
rss=$(sed -n 's/^\s*Maximum resident set size (kbytes): //p' "$dir/time.txt")
[ -n "$wall" ] && [ -n "$rss" ] || die "could not read /usr/bin/time -v's figures"
echo "report: wall $wall, peak RSS $rss KB ($((rss / 1024)) MB)"
bytes=$(stat -c %s "$report")
awk -v b="$bytes" 'BEGIN { printf "report size: %d bytes (%.2f MB)\n", b, b / 1048576 }'

echo "browser ($chromium), 5 loads:"
for run in 1 2 3 4 5; do
  CHROMIUM_PATH=$chromium node tests/browser/check-report.mjs "$report" "$dir/shot$run.png" \
    >"$dir/run$run.json"
done
# One line per run, then the worst; any render error, console error, uncaught
# exception or network request is a failure.
node --input-type=module - "$dir" <<'EOF'
import fs from 'node:fs';
const dir = process.argv[2];
const runs = [1, 2, 3, 4, 5].map((i) => JSON.parse(fs.readFileSync(`${dir}/run${i}.json`, 'utf8')));
let bad = false;
runs.forEach((r, i) => {
  const s = r.screenshot;
  console.log(
    `  run ${i + 1}: rendered_ms ${r.rendered_ms}, load_ms ${r.load_ms}` +
      ` (screenshot ${s.width}x${s.height}, ${(100 * s.non_background_fraction).toFixed(1)}% drawn)`,
  );
  for (const [what, list] of [
    ['render error', r.render_error ? [r.render_error] : []],
    ['console error', r.console_errors],
    ['page error', r.page_errors],
    ['network request', r.network],
  ]) {
    for (const m of list) {
      console.error(`bench-report: run ${i + 1}: ${what}: ${m}`);
      bad = true;
    }
  }
  if (r.rendered_ms === null) bad = true;
});
const max = (k) => Math.max(...runs.map((r) => r[k] ?? Infinity));
console.log(`  max: rendered_ms ${max('rendered_ms')}, load_ms ${max('load_ms')}`);
if (bad) process.exit(1);
EOF
