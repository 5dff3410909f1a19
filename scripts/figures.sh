#!/usr/bin/env bash
# Regenerates README's figures made from the results bases (run scripts/results.sh first): the
# bunny's Fig. 6 (data/figures/bunny-levels.png), the horse's error plot
# (data/figures/horse-error.png) and its glTF render (data/figures/horse-glb.png), and prints
# what README quotes of them: each bake's agreement with the decimator's map, the horse's
# reconstruction at levels 0..5 against the scan, and the .glb's size.
#   bash scripts/figures.sh [RESULTS_DIR]     (default target/results)
# (The fold images and the quadric-error table are scripts/validation-table.sh's; the bunny's
# reconstruction table and Blender's figures are printed by
# `cargo test --release --test blender -- --ignored`.)
set -euo pipefail
cd "$(dirname "$0")/.."
res=${1:-target/results}
data=${DISPDEC_DATA:-../shared/data}
bin=${DISPDEC_BIN:-target/release/dispdec}
[ -x "$bin" ] || cargo build --release
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for scan in bunny horse; do
  [ -f "$res/$scan.obj" ] && [ -f "$res/$scan.map" ] || { echo "figures.sh: no $res/$scan.obj and .map: run scripts/results.sh first" >&2; exit 2; }
done

echo "== bunny: bake with its map (agreement), Fig. 6"
"$bin" bake "$data/bunny.ply.gz" "$res/bunny.obj" --map "$res/bunny.map" -o "$tmp/bunny-2048.pfm" --resolution 2048
"$bin" bake "$data/bunny.ply.gz" "$res/bunny.obj" -o "$tmp/bunny.pfm" >/dev/null
for l in 1 2 3 5; do
  "$bin" reconstruct "$res/bunny.obj" "$tmp/bunny.pfm" --levels "$l" -o "$tmp/L$l.obj" >/dev/null
done
"$bin" render "$data/bunny.ply.gz" "$res/bunny.obj" "$tmp/L1.obj" "$tmp/L2.obj" "$tmp/L3.obj" "$tmp/L5.obj" \
  -o data/figures/bunny-levels.png --size 300

echo "== horse: bake with its map (agreement), levels 0..5 against the scan, error plot"
"$bin" bake "$data/horse.ply.gz" "$res/horse.obj" --map "$res/horse.map" -o "$tmp/horse.pfm" --resolution 2048
"$bin" reconstruct "$res/horse.obj" "$tmp/horse.pfm" --levels 5 -o "$tmp/h5.obj" \
  --compare "$data/horse.ply.gz" --plot data/figures/horse-error.png

echo "== horse: glTF at level 3, its render"
"$bin" export "$res/horse.obj" "$tmp/horse.pfm" -o "$tmp/horse.glb" --levels 3
echo "horse.glb: $(stat -c %s "$tmp/horse.glb") bytes"
"$bin" render "$tmp/horse.glb" -o data/figures/horse-glb.png
