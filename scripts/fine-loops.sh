#!/usr/bin/env bash
# Regenerates README's "Walked finer" table: every base of scripts/results.sh (run it first)
# judged by `dispdec validate --fine-loops` (every image loop that passes as sampled walked
# again at 8 pieces an edge, and at 64 where that is negative), one after the other on all
# cores; prints the Markdown rows and leaves each report in RESULTS_DIR/NAME-fine.json.
#   bash scripts/fine-loops.sh [RESULTS_DIR]   (default target/results)
set -euo pipefail
cd "$(dirname "$0")/.."
res=${1:-target/results}
data=${DISPDEC_DATA:-../shared/data}
bin=${DISPDEC_BIN:-target/release/dispdec}
[ -x "$bin" ] || cargo build --release
echo "| base | faces | as sampled | fine: flipped | fine: torn (of them gaps) | largest fine jump (× diagonal) | time |"
echo "|---|---:|---|---:|---:|---:|---:|"
while read -r name input; do
  [ -f "$res/$name.obj" ] || { echo "fine-loops.sh: no $res/$name.obj (run scripts/results.sh first)" >&2; exit 2; }
  "$bin" validate "$input" "$res/$name.obj" --backend cpu --fine-loops --json "$res/$name-fine.json" --quiet || true
  python3 - "$res/$name-fine.json" "$res/$name.json" "$name" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); v = r["verdict"]; c = v["checks"]
run = json.load(open(sys.argv[2]))
# The verdict as sampled: the decimator's own global check of the same base.
g = run["global"]
sampled = "valid" if g["valid"] else "INVALID"
diag = run["dmax"] / 0.1 if "dmax" in run else float("nan")
jump = c["fine_max_jump"]
print(f"| {sys.argv[3]} | {r['base_faces']} | {sampled} | {c['fine_flipped']} | {c['fine_torn']} ({c['fine_gaps']}) | "
      f"{jump / diag:.1e} | {r['time_s']:.1f} s |" if jump > 0 else
      f"| {sys.argv[3]} | {r['base_faces']} | {sampled} | {c['fine_flipped']} | {c['fine_torn']} ({c['fine_gaps']}) | – | {r['time_s']:.1f} s |")
PY
done <<LIST
bunny $data/bunny.ply.gz
horse $data/horse.ply.gz
armadillo $data/armadillo.obj.gz
nefertiti $data/nefertiti.obj.gz
lucy $data/lucy.ply
sample data/sample.obj.gz
turbineblade $data/turbineblade.ply.gz
igea $data/igea.ply.gz
dragon $data/dragon.obj.gz
sample6k $res/s6k.obj
sample6k-strict $res/s6k.obj
sample6k-constant $res/s6k.obj
bunny-strict $data/bunny.ply.gz
horse-strict $data/horse.ply.gz
bunny-constant $data/bunny.ply.gz
horse-constant $data/horse.ply.gz
LIST
