#!/usr/bin/env bash
# Regenerates README's "Quadric-error bases" table and the fold images in data/figures: the
# bunny and horse bases of scripts/results.sh (run it first) against meshoptimizer bases of the
# same face count, each judged by `dispdec validate` at the default 1024² fold image; each
# base's failing triangles go to RESULTS_DIR/SCAN-KIND-failures.obj, and those of the bunny's
# meshoptimizer base, drawn over the scan, to data/figures/bunny-qem-failures.png.
#   bash scripts/validation-table.sh [RESULTS_DIR]   (default target/results)
set -euo pipefail
cd "$(dirname "$0")/.."
res=${1:-target/results}
data=${DISPDEC_DATA:-../shared/data}
bin=target/release/dispdec
cargo build --release --example qem -q
echo "| base | faces | unmapped | flipped | torn | jump edges | ambiguous | far hits | validate time |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|"
for scan in bunny horse; do
  faces=$(python3 -c "import json;print(json.load(open('$res/$scan.json'))['faces_out'])")
  target/release/examples/qem "$data/$scan.ply.gz" "$faces" "$res/$scan-qem.obj" >/dev/null
  for kind in dispdec meshoptimizer; do
    if [ $kind = dispdec ]; then base=$res/$scan.obj; img=data/figures/$scan-fold.png; else base=$res/$scan-qem.obj; img=data/figures/$scan-qem-fold.png; fi
    "$bin" validate "$data/$scan.ply.gz" "$base" --backend cpu --json "$res/$scan-$kind-v.json" --fold-image "$img" \
      --failures "$res/$scan-$kind-failures.obj" --quiet || true
    python3 - "$res/$scan-$kind-v.json" "$scan, $kind" <<'PY'
import json, sys
r = json.load(open(sys.argv[1])); v = r["verdict"]
print(f"| {sys.argv[2]} | {r['base_faces']} | {v['unmapped']} | {v['flipped']} | {v['torn']} | {v['checks']['jump_edges']} | {v['ambiguous']} | {v['far_hits']} | {r['time_s']:.1f} s |")
PY
  done
done
NODEVICE_SELECT=1 "$bin" render "$data/bunny.ply.gz" "$res/bunny-qem.obj" --mark "$res/bunny-meshoptimizer-failures.obj" \
  --yaw 180 --size 400 -o data/figures/bunny-qem-failures.png --quiet
