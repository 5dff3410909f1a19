#!/usr/bin/env bash
# Times two dispdec binaries on one scan the way a user runs them: all threads (or THREADS),
# alone, one after the other, old then new, ROUNDS times. On this VM the speed drifts by tens of
# percent within minutes, so each ratio is new / the old run just before it. Prints every run and
# a JSON summary (each pair's seconds, faces and ratio; the ratios' median).
#   bash scripts/alternate.sh OLD_BIN NEW_BIN SCAN [ROUNDS]
#   e.g. bash scripts/alternate.sh /tmp/dispdec-14a96fd target/release/dispdec ../shared/data/bunny.ply.gz 3
# Writes into a temporary folder it removes.
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n 2,7p "$0" >&2
  exit 2
fi
old=$(realpath "$1"); new=$(realpath "$2"); scan=$(realpath "$3"); rounds=${4:-3}
threads=${THREADS:-$(nproc)}
for f in "$old" "$new" "$scan"; do
  [ -e "$f" ] || { echo "alternate.sh: $f: no such file" >&2; exit 2; }
done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# One timed decimation: run BIN -> "SECONDS FACES"
run() {
  local s e
  s=$(date +%s.%N)
  "$1" decimate "$scan" -o "$work/b.obj" --map "$work/b.map" --backend cpu --threads "$threads" -q
  e=$(date +%s.%N)
  echo "$(echo "$e - $s" | bc) $(grep -c '^f ' "$work/b.obj")"
}
pairs=()
for ((r = 1; r <= rounds; r++)); do
  read -r to fo < <(run "$old")
  echo "old $to s, $fo faces" >&2
  read -r tn fn < <(run "$new")
  echo "new $tn s, $fn faces" >&2
  pairs+=("$to $fo $tn $fn")
done
printf '%s\n' "${pairs[@]}" | python3 -c '
import json, statistics, sys
pairs = [l.split() for l in sys.stdin if l.strip()]
out = [{"old_s": float(a), "old_faces": int(b), "new_s": float(c), "new_faces": int(d), "ratio": float(c) / float(a)} for a, b, c, d in pairs]
print(json.dumps({"machine": sys.argv[1], "scan": sys.argv[2], "old": sys.argv[3], "new": sys.argv[4], "threads": int(sys.argv[5]),
                  "pairs": out, "ratio_median": statistics.median(p["ratio"] for p in out)}, indent=1))
' "$(lscpu | sed -n 's/^Model name: *//p' | head -1), $(nproc) cores" "$scan" "$old" "$new" "$threads"
