#!/usr/bin/env bash
# Faces out and time against the round width (`--batch`): decimates each SCAN at each width,
# alone, on all threads (or THREADS), and prints one row per run from its report — faces out,
# whether the global check says valid, rounds and the widest of them, candidates tried,
# deferred (and the seconds of passing tests they threw away), wall seconds of the decimation
# and of its pick / evaluate / commit phases, the sum of each round's slowest candidate (what
# more threads could not take off the evaluation), the candidate test's CPU seconds — then the
# whole as JSON (a list of rows).
# The measurement behind the round width README documents (Decisions, "Batches").
#   bash scripts/width.sh BIN "WIDTHS" SCAN...
#   e.g. bash scripts/width.sh target/release/dispdec "1 16 64 256" ../shared/data/bunny.ply.gz
# Writes into a temporary folder it removes.
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n 2,11p "$0" >&2
  exit 2
fi
bin=$(realpath "$1"); read -r -a widths <<< "$2"; shift 2
threads=${THREADS:-$(nproc)}
[ -x "$bin" ] || { echo "width.sh: $bin: not an executable" >&2; exit 2; }
for s in "$@"; do
  [ -e "$s" ] || { echo "width.sh: $s: no such file" >&2; exit 2; }
done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for s in "$@"; do
  for w in "${widths[@]}"; do
    r="$work/$(basename "$s" | cut -d. -f1)-$w.json"
    "$bin" decimate "$s" -o "$work/b.obj" --map "$work/b.map" --report "$r" --backend cpu --threads "$threads" --batch "$w" -q
    python3 - "$r" <<'PY' | tee -a "$work/rows"
import json, sys
r = json.load(open(sys.argv[1]))
c, t = r["collapses"], r["time"]
row = {
    "scan": r["input"].split("/")[-1], "threads": r["threads"], "batch": r["batch"],
    "faces_out": r["faces_out"], "valid": r["global"]["valid"], "rounds": c["rounds"], "widest": c["widest_round"],
    "tried": c["tried"], "accepted": c["accepted"], "deferred": c["deferred"],
    "deferred_test_s": round(c["deferred_test_s"], 2), "decimate_s": round(t["decimate_s"], 2),
    "pick_s": round(t["pick_s"], 2), "evaluate_s": round(t["evaluate_s"], 2), "commit_s": round(t["commit_s"], 2),
    "slowest_s": round(c["time_slowest_candidates_s"], 2),
    "test_cpu_s": round(c["stages"]["accepted_cpu_s"] + c["stages"]["rejected_cpu_s"], 2),
}
print(json.dumps(row))
PY
  done
done
python3 - "$work/rows" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
print("\n| scan | batch | faces out | valid | rounds (widest) | tried | deferred (test s thrown away) | decimate s | pick / evaluate / commit s | rounds' slowest s | test CPU s |")
print("|---|---:|---:|---|---:|---:|---:|---:|---|---:|---:|")
for r in rows:
    print(f"| {r['scan']} | {r['batch']} | {r['faces_out']:,} | {'valid' if r['valid'] else 'NOT valid'} | {r['rounds']:,} ({r['widest']:,}) | {r['tried']:,} | {r['deferred']:,} ({r['deferred_test_s']}) | {r['decimate_s']} | {r['pick_s']} / {r['evaluate_s']} / {r['commit_s']} | {r['slowest_s']} | {r['test_cpu_s']} |")
print()
print(json.dumps(rows))
PY
