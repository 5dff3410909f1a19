#!/usr/bin/env bash
# Compares two dispdec binaries on one scan, on a machine whose speed drifts by tens of percent
# within minutes (this VM): each round runs the two at the same time, one thread each, each
# pinned to its own core, then again with the cores swapped, so that both see the same drift
# and the same cores. Prints every time and a JSON summary: per pair the ratio new / old, their
# geometric mean and median, the faces each wrote, and whether every base and map the two wrote
# are identical. OLD_ARGS / NEW_ARGS (environment) add options to one side only, so that one
# binary can be compared with itself under another option.
#   bash scripts/ab.sh OLD_BIN NEW_BIN SCAN [ROUNDS] [-- more decimate options]
#   e.g. bash scripts/ab.sh /tmp/dispdec-before target/release/dispdec ../shared/data/bunny.ply.gz 2
#        NEW_ARGS="--near-rule triangles" bash scripts/ab.sh target/release/dispdec target/release/dispdec SCAN
# Needs two cores and `taskset` (util-linux); writes into a temporary folder it removes.
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n 2,9p "$0" >&2
  exit 2
fi
old=$(realpath "$1"); new=$(realpath "$2"); scan=$(realpath "$3"); rounds=${4:-1}
shift $(( $# >= 4 ? 4 : 3 ))
[ "${1:-}" = "--" ] && shift
extra=("$@")
read -r -a old_args <<< "${OLD_ARGS:-}"
read -r -a new_args <<< "${NEW_ARGS:-}"
for f in "$old" "$new" "$scan"; do
  [ -e "$f" ] || { echo "ab.sh: $f: no such file" >&2; exit 2; }
done
command -v taskset >/dev/null || { echo "ab.sh: taskset not found (util-linux)" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# One timed, pinned decimation: run NAME BIN CORE [ARGS] -> "NAME CORE SECONDS FACES" in
# $work/times.
run() {
  local s e name=$1 bin=$2 core=$3
  shift 3
  s=$(date +%s.%N)
  taskset -c "$core" "$bin" decimate "$scan" -o "$work/$name.obj" --map "$work/$name.map" --backend cpu --threads 1 -q "${extra[@]}" "$@"
  e=$(date +%s.%N)
  echo "$name $core $(echo "$e - $s" | bc) $(grep -c '^f ' "$work/$name.obj")" | tee -a "$work/times"
}
same=true
for r in $(seq "$rounds"); do
  for cores in "0 1" "1 0"; do
    set -- $cores
    run old "$old" "$1" "${old_args[@]}" & run new "$new" "$2" "${new_args[@]}" & wait
    if ! cmp -s "$work/old.obj" "$work/new.obj" || ! cmp -s "$work/old.map" "$work/new.map"; then
      same=false
    fi
  done
done
python3 - "$work/times" "$same" "$old" "$new" "$scan" <<'PY'
import json, math, platform, statistics, sys, os
times, same, old, new, scan = sys.argv[1:6]
rows = [l.split() for l in open(times)]
pairs = []
for i in range(0, len(rows), 2):
    t = {name: float(sec) for name, _, sec, _ in rows[i:i + 2]}
    cores = {name: int(core) for name, core, _, _ in rows[i:i + 2]}
    faces = {name: int(f) for name, _, _, f in rows[i:i + 2]}
    pairs.append({"old_s": t["old"], "new_s": t["new"], "old_core": cores["old"], "ratio": t["new"] / t["old"],
                  "old_faces": faces["old"], "new_faces": faces["new"]})
ratios = [p["ratio"] for p in pairs]
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.machine())
print(json.dumps({
    "machine": f"{cpu}, {os.cpu_count()} cores",
    "scan": scan, "old": old, "new": new,
    "old_args": os.environ.get("OLD_ARGS", ""), "new_args": os.environ.get("NEW_ARGS", ""),
    "pairs": pairs,
    "ratio_geomean": math.exp(sum(map(math.log, ratios)) / len(ratios)),
    "ratio_median": statistics.median(ratios),
    "identical_outputs": same == "true",
}, indent=1))
PY
