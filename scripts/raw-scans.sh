#!/usr/bin/env bash
# Decimates the raw public scans of README "Scans as they come" with --repair, checks each base
# again with `dispdec validate` against the repaired scan it wrote, and prints one line per scan.
# The scans are not in this repository (see README for their sources and checksums):
#   scripts/raw-scans.sh DIR [OUT]    DIR holds bunny000.ply, lato000.ply, brain.ply, ...
# OUT (default: a temporary folder) receives base meshes, maps, repaired scans and reports.
set -euo pipefail
dir=${1:?usage: scripts/raw-scans.sh DIR [OUT]}
out=${2:-$(mktemp -d)}
mkdir -p "$out"
cd "$(dirname "$0")/.."
cargo build --release --quiet
bin=target/release/dispdec
status=0
for scan in bunny000 bunny045 lato000 non_manif_hole many_small_holes brain brain:--strict; do
  name=${scan%%:*}
  extra=""
  [ "$scan" != "$name" ] && extra=${scan#*:}
  tag=$name${extra//-/_}
  f="$dir/$name.ply"
  if [ ! -f "$f" ]; then echo "$name: not in $dir, skipped"; continue; fi
  set +e
  $bin decimate "$f" -o "$out/$tag-base.obj" --map "$out/$tag.map" --report "$out/$tag.json" \
    --repair --repaired "$out/$tag-repaired.obj" --backend cpu $extra 2>"$out/$tag.log"
  code=$?
  $bin validate "$out/$tag-repaired.obj" "$out/$tag-base.obj" --backend cpu --json "$out/$tag-validate.json" 2>>"$out/$tag.log"
  vcode=$?
  set -e
  echo "== $name $extra: decimate exit $code, validate (against the repaired scan) exit $vcode"
  grep -v '^  ' "$out/$tag.log" | sed 's/^/   /'
  [ $code -le 1 ] || status=2
done
echo "outputs in $out"
exit $status
