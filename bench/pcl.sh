#!/usr/bin/env bash
# PCL's ICP (point-to-point and point-to-plane) against sie on synthetic room scenes of growing
# size: time, iterations and error against the ground truth, as CSV on stdout.
#
#   bench/pcl.sh DIR [N,N,...]
#
# DIR holds room_N_source.pcd, room_N_target.pcd and room_N_gt.txt (4x4 row-major
# T_target_source, p_target = T * p_source) for each size N; without a list, every N that has a
# room_N_source.pcd, smallest first. Builds libsie (release) with CMake, installs it into a
# prefix and builds examples-cpp/compare_pcl against it, like scripts/ci-integration.sh, all
# under build/bench (override with SIE_BENCH_BUILD); nothing is downloaded.
#
# Per size: one compare_pcl run for PCL (both variants; single-threaded) and sie with 1 thread,
# one for sie alone with 2 threads, each method timed as the median of 3 runs for N <= 100000
# and of 1 run above. Both runs use --max-distance 0.5 (PCL only; sie has no such threshold;
# SIE_BENCH_MAX_DIST overrides it)
# and --iterations 100 (PCL's cap; sie keeps its defaults), from the identity. stdout: one CSV
# header and the rows of every run (columns: see examples-cpp/compare_pcl.cpp); diagnostics
# and build output go to stderr.
set -euo pipefail
if [ $# -lt 1 ] || [ $# -gt 2 ] || [ ! -d "$1" ]; then
  echo "usage: bench/pcl.sh DIR [N,N,...]" >&2
  exit 2
fi
dir=$(cd "$1" && pwd)
cd "$(dirname "$0")/.."
root=$PWD
build=${SIE_BENCH_BUILD:-$root/build/bench}
prefix=$build/install
jobs=$(nproc 2>/dev/null || echo 2)

if [ $# -eq 2 ]; then
  IFS=, read -r -a sizes <<<"$2"
else
  mapfile -t sizes < <(find "$dir" -maxdepth 1 -name 'room_*_source.pcd' -printf '%f\n' |
    sed -n 's/^room_\([0-9]*\)_source\.pcd$/\1/p' | sort -n)
fi
if [ ${#sizes[@]} -eq 0 ]; then
  echo "bench/pcl.sh: no room_N_source.pcd in $dir" >&2
  exit 2
fi
for n in "${sizes[@]}"; do
  for f in source.pcd target.pcd gt.txt; do
    if ! [[ $n =~ ^[0-9]+$ ]] || [ ! -f "$dir/room_${n}_$f" ]; then
      echo "bench/pcl.sh: missing $dir/room_${n}_$f" >&2
      exit 2
    fi
  done
done

mkdir -p "$build"
# One bench per build directory at a time (the working tree is shared).
exec 9>"$build/.lock"
flock 9

# ---- build: libsie (release, no ABI tests) into a prefix, then compare_pcl against it --------
{
  # The working tree is built as it is, uncommitted changes included: say which.
  echo ">> building libsie ($(git describe --always --dirty 2>/dev/null || echo "not a git checkout")) and" \
    "compare_pcl under $build"
  cmake -S . -B "$build/sie" -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX="$prefix" -DSIE_BUILD_TESTS=OFF
  cmake --build "$build/sie" -j "$jobs"
  rm -rf "$prefix"
  cmake --install "$build/sie"
  cmake -S examples-cpp -B "$build/examples" -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$prefix"
  cmake --build "$build/examples" -j "$jobs" --target compare_pcl
} >&2
compare=$build/examples/compare_pcl

header=library,method,points,threads,seconds,iterations,rotation_error_deg,translation_error_m,converged,note
echo "$header"
out=$(mktemp)
trap 'rm -f "$out"' EXIT

# Runs compare_pcl on one size with the given extra options; appends its rows to stdout.
run() {
  local n=$1
  shift
  local repeats=1
  if [ "$n" -le 100000 ]; then repeats=3; fi
  echo ">> N=$n: compare_pcl --repeats $repeats $*" >&2
  local start=$SECONDS status=0
  "$compare" --csv --max-distance "${SIE_BENCH_MAX_DIST:-0.5}" --iterations 100 --repeats "$repeats" "$@" \
    "$dir/room_${n}_source.pcd" "$dir/room_${n}_target.pcd" "$dir/room_${n}_gt.txt" >"$out" || status=$?
  # Exit status 1: sie missed compare_pcl's default accuracy check (1 deg, 5 mm) or failed;
  # its rows (if any) are still reported. Anything else is an error.
  if [ "$status" -ne 0 ] && [ "$status" -ne 1 ]; then
    echo "bench/pcl.sh: compare_pcl exited with $status" >&2
    exit 1
  fi
  if [ "$status" -eq 1 ]; then
    echo ">> note: compare_pcl exited with 1 (sie outside 1 deg / 5 mm, or failed)" >&2
  fi
  if [ "$(head -n 1 "$out")" != "$header" ]; then
    echo "bench/pcl.sh: unexpected CSV header from compare_pcl: $(head -n 1 "$out")" >&2
    exit 1
  fi
  tail -n +2 "$out"
  echo ">> N=$n: done in $((SECONDS - start)) s" >&2
}

for n in "${sizes[@]}"; do
  run "$n" --sie-threads 1
  run "$n" --skip-pcl --sie-threads 2
done
