#!/usr/bin/env bash
# The benchmark on a machine with a GPU and no network (issue 11): packed here, run there.
#
#   bash scripts/gpu-bench.sh pack
#       Here, with a network: builds the release binary, puts a stripped copy, the scans the
#       bench reads (bunny, horse, igea from ../shared/data) and the Vulkan loader's Debian
#       packages into .gpubench/ (ignored by git; ~17 MB), and prints how to run it there.
#
#   bash scripts/gpu-bench.sh run OUT [MESHES] [CONFIGS] [LIMIT_S]
#       There, from the repository root with .gpubench/ beside the scripts: installs the
#       loader if the machine has none, points it at NVIDIA's driver where that is installed
#       outside the loader's search path, then runs
#       `dispdec bench --meshes M --configs CONFIGS --runs 1 --json OUT/bench-M-CONFIGS.json` for each
#       mesh M of MESHES (default: bunny,horse; CONFIGS default cpu,gpu), all within LIMIT_S
#       seconds (default 420), and writes OUT/env.txt (machine, driver, the adapter that
#       `--backend auto` picks) and OUT/bench.log (with each base's sha256, and whether the
#       paths' bases are the same bytes).
#       With BATCH=N in the environment, every run decimates at that round width (`--batch`;
#       default 16), and the JSON's name ends in -batch-N. With RING=keep, every run keeps the
#       ring's directions (`--ring-directions keep`, README Results: 2–2.4x less time here),
#       and the JSON's name ends in -keep.
#       The 1M sample (`sample1m`) is generated there by the binary itself. Exit status: 0,
#       or the last failing bench's (124 when the limit stopped it; what finished of that mesh
#       is in the log).
#
# Tested on lavapipe (`run` on this machine, where the loader and Mesa are installed).
set -euo pipefail
cd "$(dirname "$0")/.."
pack=.gpubench

case "${1:-}" in
pack)
  data=${DISPDEC_DATA:-../shared/data}
  # For another machine: x86-64-v3 (AVX2, FMA: any GPU host of the last decade), not this
  # CPU's own set (.cargo/config.toml), in a folder of its own so target/release stays as built.
  RUSTFLAGS="-C target-cpu=x86-64-v3" CARGO_TARGET_DIR=target/carried cargo build --release
  rm -rf "$pack"
  mkdir -p "$pack/data" "$pack/gl"
  grep -qx "/$pack/" .git/info/exclude 2>/dev/null || echo "/$pack/" >>.git/info/exclude
  cp target/carried/release/dispdec "$pack/dispdec"
  echo "$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- src shaders Cargo.toml Cargo.lock || echo ' (with uncommitted changes)')" >"$pack/commit.txt"
  strip "$pack/dispdec"
  for f in bunny.ply.gz horse.ply.gz igea.ply.gz; do
    cp "$data/$f" "$pack/data/"
  done
  # The Vulkan loader for an amd64 machine, whatever this one is (the device notes' recipe).
  lists=$(mktemp -d)
  mkdir -p "$lists/partial"
  o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
  apt-get "${o[@]}" update -qq
  # libGLX_nvidia, which NVIDIA's Vulkan driver file names, needs glvnd (libGLdispatch).
  (cd "$pack/gl" && apt-get "${o[@]}" download libvulkan1 libglvnd0 libglx0 libegl1 libgl1 libopengl0 libgles2 >/dev/null)
  rm -rf "$lists"
  du -sh "$pack"
  echo "carry: $pack    command: bash scripts/gpu-bench.sh run \$OUT bunny,horse cpu,gpu 420"
  ;;
run)
  out=${2:?usage: gpu-bench.sh run OUT [MESHES] [CONFIGS] [LIMIT_S]}
  meshes=${3:-bunny,horse}
  configs=${4:-cpu,gpu}
  limit=${5:-420}
  [ -x "$pack/dispdec" ] || { echo "gpu-bench: $pack/dispdec missing: run 'bash scripts/gpu-bench.sh pack' first" >&2; exit 2; }
  mkdir -p "$out"
  if ! ldconfig -p | grep -q 'libvulkan\.so\.1'; then
    for f in "$pack"/gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
  fi
  # NVIDIA's driver file, only where none lies in the loader's standard folders: the one the
  # lent machines keep outside them, else wherever the image keeps one.
  nv=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  std_icd() { ls /usr/share/vulkan/icd.d/*nvidia* >/dev/null 2>&1 || ls /etc/vulkan/icd.d/*nvidia* >/dev/null 2>&1; }
  if [ -z "${VK_DRIVER_FILES:-}" ] && ! std_icd; then
    icd=$nv
    [ -f "$icd" ] || icd=$(find /usr /etc /opt -name 'nvidia_icd*.json' 2>/dev/null | head -1 || true)
    [ -n "$icd" ] && export VK_DRIVER_FILES=$icd
  fi
  loaders() { ldconfig -p | grep -i 'libvulkan' | tr -s ' \t' ' ' | tr '\n' ';'; }
  export NODEVICE_SELECT=1
  {
    echo "date: $(date -u +%FT%TZ)"
    echo "machine: $(uname -srm), $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2 / 1048576}' /proc/meminfo)"
    echo "cpu: $(awk -F': ' '/model name/ {print $2; exit}' /proc/cpuinfo)"
    command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | sed 's/^/gpu: /'
    echo "VK_DRIVER_FILES=${VK_DRIVER_FILES:-}  LD_LIBRARY_PATH=${LD_LIBRARY_PATH:-}"
    echo "vulkan drivers: $(ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null | tr '\n' ' ')"
    echo "binary: $("$pack/dispdec" --version), commit $(cat "$pack/commit.txt" 2>/dev/null || echo unknown)"
    echo "loader: $(loaders)"
    # Can the GPU path open an adapter? (a 1k-face sample, a few seconds). When it cannot, the
    # packed loader is installed over whatever the image has, then the driver file is tried
    # from the standard folders, and the loader's own account is kept.
    probe=$(mktemp -d)
    "$pack/dispdec" -q sample --faces 1000 --seed 1 -o "$probe/s1k.obj"
    gpu_ok() { "$pack/dispdec" -q decimate "$probe/s1k.obj" -o "$probe/g.obj" --backend gpu >"$probe/gpu.log" 2>&1; }
    # Why not, in the loader's words.
    loader_account() {
      echo "gpu: $1: $(tail -c 400 "$probe/gpu.log")"
      VK_LOADER_DEBUG=error,warn,driver "$pack/dispdec" -q decimate "$probe/s1k.obj" -o "$probe/g.obj" --backend gpu 2>&1 | tail -c 3000
    }
    if ! gpu_ok; then
      loader_account "no adapter"
      for f in "$pack"/gl/*.deb; do dpkg -x "$f" /; done
      ldconfig
      echo "loader after installing the packed one: $(loaders)"
      gpu_ok || for icd in /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json "$nv"; do
        [ -f "$icd" ] || continue
        export VK_DRIVER_FILES=$icd
        gpu_ok && break
      done
      if gpu_ok; then echo "gpu: opened with VK_DRIVER_FILES=${VK_DRIVER_FILES:-}"; else loader_account "still no adapter"; fi
    fi
    # What `--backend auto` picks there.
    "$pack/dispdec" --verbose decimate "$probe/s1k.obj" -o "$probe/b.obj" --backend auto
  } >"$out/env.txt" 2>&1 || true
  cat "$out/env.txt"
  # One bench a mesh, each with its own JSON, so that the limit loses only the mesh it stops.
  end=$((SECONDS + limit))
  rc=0
  set +e
  for mesh in ${meshes//,/ }; do
    left=$((end - SECONDS))
    if [ "$left" -le 0 ]; then
      echo "gpu-bench: no time left for $mesh" | tee -a "$out/bench.log"
      rc=124
      break
    fi
    name=$(basename "$mesh" | sed 's/[^A-Za-z0-9_.-]/_/g')
    json="bench-$name-${configs//,/_}$([ "${BATCH:-16}" = 16 ] || echo "-batch-$BATCH")$([ "${RING:-recompute}" = recompute ] || echo "-$RING").json"
    work=$(mktemp -d)
    timeout "$left" "$pack/dispdec" bench --verbose --data "$pack/data" --meshes "$mesh" --configs "$configs" \
      --batch "${BATCH:-16}" --ring-directions "${RING:-recompute}" --runs 1 --work "$work" --json "$out/$json" 2>&1 | tee -a "$out/bench.log"
    r=${PIPESTATUS[0]}
    echo "gpu-bench: $mesh: exit $r; $out/$json $([ -f "$out/$json" ] && echo written || echo 'not written')" | tee -a "$out/bench.log"
    # The bases each path wrote (the bench keeps the last run's as WORK/MESH-Config.obj): the same bytes?
    (cd "$work" && sha256sum -- *.obj 2>/dev/null | grep -v 'sample-1m' | sed "s|^|gpu-bench: $mesh: sha256 |") | tee -a "$out/bench.log" || true
    bases=()
    for f in "$work"/*-Cpu1.obj "$work"/*-Cpu.obj "$work"/*-Gpu.obj; do [ -f "$f" ] && bases+=("$f"); done
    if [ "${#bases[@]}" -ge 2 ]; then
      same="identical bytes"
      for f in "${bases[@]:1}"; do cmp -s "${bases[0]}" "$f" || same="DIFFERENT bytes"; done
      echo "gpu-bench: $mesh: the ${#bases[@]} paths' bases ($configs): $same" | tee -a "$out/bench.log"
    fi
    [ "$r" = 0 ] || rc=$r
  done
  set -e
  exit "$rc"
  ;;
*)
  sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
  ;;
esac
