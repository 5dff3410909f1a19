#!/usr/bin/env bash
# Regenerates README's results and modes tables: decimates every scan of ../shared/data, the
# shipped sample and the 6k generated sample (in its three modes), the bunny and the horse in
# --strict and --normals constant, with the release binary, one run each with --report, then
# prints the table rows from the reports.
#   bash scripts/results.sh [OUTDIR] [--readme]     (default target/results)
# With --readme it also writes the two tables into README.md, between the markers
# `<!-- results.sh: results -->` / `<!-- results.sh: modes -->` and `<!-- /results.sh -->` (each
# pair once; nothing is written unless both are found and every run has its report), and
# touches nothing else there.
# Runs LANES decimations at a time (default: the number of cores), each with --threads 1 — the
# bytes are the same for any thread count, and one thread a run wastes no core on a run's
# serial parts —, longest first. A run whose report exists is not run again, so an interrupted
# regeneration resumes. The whole set took 14.5 minutes on this 2-core machine on 2026-12-06
# (the horse's constant-mode run alone 11.6 minutes; the VM's speed varies by tens of percent).
# FLAGS is added to every run: FLAGS="--ring-directions keep" bash scripts/results.sh DIR
# printed README's table of that rule (12 minutes, 2026-12-07).
set -euo pipefail
cd "$(dirname "$0")/.."
out=target/results
readme=
for arg in "$@"; do
  case "$arg" in
  --readme) readme=README.md ;;
  *) out=$arg ;;
  esac
done
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
    --backend cpu --threads 1 --quiet "$@" $FLAGS || echo "results.sh: $name failed (exit $?)" >&2
}
export -f one
FLAGS=${FLAGS:-}
export out bin FLAGS
printf '%s\n' "${runs[@]}" | xargs -P "$lanes" -L 1 bash -c 'one "$@"' _
python3 - "$out" "$readme" <<'PY'
import json, sys, os
out, readme = sys.argv[1], sys.argv[2]
tables = {"results": [], "modes": []}
RESULTS = ["bunny", "horse", "armadillo", "nefertiti", "lucy", "sample", "turbineblade", "igea", "dragon"]
MODES = ["sample6k", "sample6k-strict", "sample6k-constant", "bunny-strict", "horse-strict", "bunny-constant", "horse-constant"]
def emit(kind, line):
    tables[kind].append(line)
def load(name):
    p = os.path.join(out, name + ".json")
    return json.load(open(p)) if os.path.exists(p) else None
def verdict(g):
    ch = g["checks"]
    return f"{'valid' if g['valid'] else 'INVALID'}: {g['unmapped']} / {g['flipped']} / {g['torn']} / {ch['jump_edges']} ({ch['max_jump']:.2g})"
emit("results", "| run | faces in | faces out | time (s) | local re-check | global check: unmapped / flipped / torn / jump edges (largest) | straddling triangles judged in charts | exempt | deferred |")
emit("results", "|---|---:|---:|---:|---|---|---:|---:|---:|")
for name in RESULTS:
    r = load(name)
    if r is None:
        continue
    g, c = r["global"], r["recheck"]
    label = "data/sample.obj.gz (shipped)" if name == "sample" else name
    emit("results", f"| {label} | {r['faces_in']:,} | {r['faces_out']:,} | {r['time']['total_s']:.1f} | {'valid' if c['valid'] else 'INVALID'} | {verdict(g)} | {g['checks']['straddling']:,} | {g['pinched']} | {r['collapses'].get('deferred', 0):,} |")
emit("modes", "| run | faces out | time (s) | local re-check | global check: unmapped / flipped / torn / jump edges (largest) | ambiguous (strict) | exempt vertices / edges |")
emit("modes", "|---|---:|---:|---|---|---:|---|")
for name in MODES:
    r = load(name)
    if r is None:
        continue
    g, c = r["global"], r["recheck"]
    amb = g["ambiguous"] if g["strict"] else "–"
    emit("modes", f"| {name} | {r['faces_out']:,} | {r['time']['total_s']:.1f} | {'valid' if c['valid'] else 'INVALID'} | {verdict(g)} | {amb} | {g['pinched']} / {g.get('exempt_edges', 0)} |")
print("\n".join(tables["results"]))
print()
print("\n".join(tables["modes"]))
if readme:
    missing = [n for n in RESULTS + MODES if load(n) is None]
    if missing:
        sys.exit(f"results.sh: no report for {', '.join(missing)} in {out}; README not written")
    text = open(readme).read()
    closer = "<!-- /results.sh -->\n"
    if text.count(closer) != len(tables):
        sys.exit(f"results.sh: {readme}: {text.count(closer)} closing markers, not {len(tables)}; nothing written")
    for kind, rows in tables.items():
        # The rows between this table's markers, and nothing else (a table regenerated by
        # matching rows elsewhere once overwrote another table's rows with these).
        opener = f"<!-- results.sh: {kind} -->\n"
        if text.count(opener) != 1:
            sys.exit(f"results.sh: {readme}: the {kind} table's opening marker is there {text.count(opener)} times, not once; nothing written")
        a = text.index(opener) + len(opener)
        b = text.find(closer, a)
        if b < 0 or any(not line.startswith("|") for line in text[a:b].splitlines()):
            sys.exit(f"results.sh: {readme}: the {kind} table's markers hold more than a table; nothing written")
        text = text[:a] + "\n".join(rows) + "\n" + text[b:]
    open(readme, "w").write(text)
    print(f"results.sh: wrote both tables into {readme}", file=sys.stderr)
PY
