#!/usr/bin/env bash
# Regenerates README's results and modes tables: decimates every scan of ../shared/data, the
# shipped sample and the 6k generated sample (in its three modes), the bunny and the horse in
# --strict and --normals constant, with the release binary, one run each with --report, then
# prints the table rows from the reports.
#   bash scripts/results.sh [OUTDIR]     (default target/results)
# Runs LANES decimations at a time (default: the number of cores), each with --threads 1 — the
# bytes are the same for any thread count, and one thread a run wastes no core on a run's
# serial parts —, longest first. A run whose report exists is not run again, so an interrupted
# regeneration resumes. The whole set took 14.5 minutes on this 2-core machine on 2026-12-06
# (the horse's constant-mode run alone 11.6 minutes; the VM's speed varies by tens of percent).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/results}
mkdir -p "$out"
bin=${DISPDEC_BIN:-target/release/dispdec}
[ -x "$bin" ] || cargo build --release
bin=$(realpath "$bin")
data=${DISPDEC_DATA:-../shared/data}
lanes=${LANES:-$(nproc)}
[ -f "$out/s6k.obj" ] || "$bin" sample --faces 6000 --seed 7 -o "$out/s6k.obj" >/dev/null
# Longest first (times of the last regeneration), so that the lanes end together.
runs=(
  "horse-constant $data/horse.ply.gz --normals constant"
  "dragon $data/dragon.obj.gz"
  "igea $data/igea.ply.gz"
  "turbineblade $data/turbineblade.ply.gz"
  "bunny-constant $data/bunny.ply.gz --normals constant"
  "horse-strict $data/horse.ply.gz --strict"
  "lucy $data/lucy.ply"
  "sample data/sample.obj.gz"
  "bunny-strict $data/bunny.ply.gz --strict"
  "nefertiti $data/nefertiti.obj.gz"
  "horse $data/horse.ply.gz"
  "armadillo $data/armadillo.obj.gz"
  "bunny $data/bunny.ply.gz"
  "sample6k-constant $out/s6k.obj --normals constant"
  "sample6k-strict $out/s6k.obj --strict"
  "sample6k $out/s6k.obj"
)
one() {
  local name=$1 input=$2
  shift 2
  [ -f "$out/$name.json" ] && return 0
  "$bin" decimate "$input" -o "$out/$name.obj" --map "$out/$name.map" --report "$out/$name.json" \
    --backend cpu --threads 1 --quiet "$@" || echo "results.sh: $name failed (exit $?)" >&2
}
export -f one
export out bin
printf '%s\n' "${runs[@]}" | xargs -P "$lanes" -L 1 bash -c 'one "$@"' _
python3 - "$out" <<'PY'
import json, sys, os
out = sys.argv[1]
def load(name):
    p = os.path.join(out, name + ".json")
    return json.load(open(p)) if os.path.exists(p) else None
def verdict(g):
    ch = g["checks"]
    return f"{'valid' if g['valid'] else 'INVALID'}: {g['unmapped']} / {g['flipped']} / {g['torn']} / {ch['jump_edges']} ({ch['max_jump']:.2g})"
print("| run | faces in | faces out | time (s) | local re-check | global check: unmapped / flipped / torn / jump edges (largest) | straddling triangles judged in charts | exempt | deferred |")
print("|---|---:|---:|---:|---|---|---:|---:|---:|")
for name in ["bunny", "horse", "armadillo", "nefertiti", "lucy", "sample", "turbineblade", "igea", "dragon"]:
    r = load(name)
    if r is None:
        continue
    g, c = r["global"], r["recheck"]
    label = "data/sample.obj.gz (shipped)" if name == "sample" else name
    print(f"| {label} | {r['faces_in']:,} | {r['faces_out']:,} | {r['time']['total_s']:.1f} | {'valid' if c['valid'] else 'INVALID'} | {verdict(g)} | {g['checks']['straddling']:,} | {g['pinched']} | {r['collapses'].get('deferred', 0):,} |")
print()
print("| run | faces out | time (s) | local re-check | global check: unmapped / flipped / torn / jump edges (largest) | ambiguous (strict) | exempt vertices / edges |")
print("|---|---:|---:|---|---|---:|---|")
for name in ["sample6k", "sample6k-strict", "sample6k-constant", "bunny-strict", "horse-strict", "bunny-constant", "horse-constant"]:
    r = load(name)
    if r is None:
        continue
    g, c = r["global"], r["recheck"]
    amb = g["ambiguous"] if g["strict"] else "–"
    print(f"| {name} | {r['faces_out']:,} | {r['time']['total_s']:.1f} | {'valid' if c['valid'] else 'INVALID'} | {verdict(g)} | {amb} | {g['pinched']} / {g.get('exempt_edges', 0)} |")
PY
