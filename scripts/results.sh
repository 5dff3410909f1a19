#!/usr/bin/env bash
# Regenerates README's results table: decimates every scan of ../shared/data and the shipped
# sample with the release binary, one run each with --report, then prints the table rows.
#   bash scripts/results.sh [OUTDIR]     (default target/results; takes ~20 min on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/results}
mkdir -p "$out"
bin=target/release/dispdec
[ -x "$bin" ] || cargo build --release
data=${DISPDEC_DATA:-../shared/data}
runs=(
  "bunny $data/bunny.ply.gz"
  "horse $data/horse.ply.gz"
  "armadillo $data/armadillo.obj.gz"
  "dragon $data/dragon.obj.gz"
  "nefertiti $data/nefertiti.obj.gz"
  "lucy $data/lucy.ply"
  "turbineblade $data/turbineblade.ply.gz"
  "igea $data/igea.ply.gz"
  "sample data/sample.obj.gz"
  "bunny-strict $data/bunny.ply.gz --strict"
  "bunny-constant $data/bunny.ply.gz --normals constant"
  "horse-constant $data/horse.ply.gz --normals constant"
)
for r in "${runs[@]}"; do
  set -- $r
  name=$1; input=$2; shift 2
  if [ ! -f "$out/$name.json" ]; then
    "$bin" decimate "$input" -o "$out/$name.obj" --map "$out/$name.map" --report "$out/$name.json" --backend cpu --quiet "$@" || true
  fi
done
python3 - "$out" <<'PY'
import json, sys, os
out = sys.argv[1]
print("| run | faces in | faces out | time (s) | local re-check | global check: unmapped / flipped / torn / jump edges (largest) | ambiguous (strict) | straddling triangles judged in charts | exempt | deferred |")
print("|---|---:|---:|---:|---|---|---:|---:|---:|---:|")
for name in ["bunny", "horse", "armadillo", "dragon", "nefertiti", "lucy", "turbineblade", "igea", "sample", "bunny-strict", "bunny-constant", "horse-constant"]:
    p = os.path.join(out, name + ".json")
    if not os.path.exists(p):
        continue
    r = json.load(open(p))
    g, c = r["global"], r["recheck"]
    ch = g["checks"]
    verdict = "valid" if g["valid"] else "INVALID"
    print(f"| {name} | {r['faces_in']:,} | {r['faces_out']:,} | {r['time']['total_s']:.1f} | {'valid' if c['valid'] else 'INVALID'} | {verdict}: {g['unmapped']} / {g['flipped']} / {g['torn']} / {ch['jump_edges']} ({ch['max_jump']:.2g}) | {g['ambiguous'] if g['strict'] else '–'} | {ch['straddling']:,} | {g['pinched']} | {r['collapses'].get('deferred', 0):,} |")
PY
