#!/usr/bin/env bash
# The sequence (odometry) benchmark of docs/performance.md in one run: writes the synthetic room
# trajectories, a depth camera on the same loop (noise growing as depth²), the simulated LiDAR
# street (FRAMES sweeps of 64 beams, ~120 000 points each; its whole drive takes 300), still and
# skewed by the motion, and the real frame sequences, runs sie (examples/bench_sequences.rs),
# small_gicp and KISS-ICP (bench/sequences.py, own venv) at 1 and 2 threads on the same frames,
# one after the other, and prints the report (frames/s over the fastest peer's, RPE and ATE).
#
#   bench/sequences.sh [OUT_DIR] [FRAMES] [N,N,...]   (default: build/bench-sequences, 100, 10000,50000)
#
# SIE_BENCH_SKIP=sie,small_gicp,kiss_icp leaves libraries out (sie: reuses OUT_DIR/sie.csv).
# The venv lives outside the repo: ${SIE_BENCH_VENV:-$HOME/.cache/sie-bench-venv}. Not part of
# the default tests (CI runs `bench_sequences quick`). Timings on a shared machine are noisy:
# compare the rows of one run.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/bench-sequences}
frames=${2:-100}
sizes=${3:-10000,50000}
skip=${SIE_BENCH_SKIP:-}
mkdir -p "$out"
sequences=$out/sequences
echo "== sequences ($frames frames of $sizes points, depth camera, LiDAR streets, Kinect, LiDAR pair) into $sequences" >&2
cargo run --release --quiet --example bench_sequences -- write "$sequences" "$frames" "$sizes"
if [[ ",$skip," != *,sie,* ]]; then
  echo "== sie" >&2
  cargo run --release --quiet --example bench_sequences -- run "$sequences" 1,2 >"$out/sie.csv"
fi
venv=${SIE_BENCH_VENV:-$HOME/.cache/sie-bench-venv}
[ -x "$venv/bin/python" ] || python3 -m venv "$venv" >&2
"$venv/bin/pip" install -q --disable-pip-version-check -r bench/requirements.txt >&2
header=()
: >"$out/peers.csv"
for lib in small_gicp kiss_icp; do
  [[ ",$skip," == *,$lib,* ]] && continue
  for threads in 1 2; do
    # A fresh process per thread count: thread limits are process-wide.
    echo "== $lib, $threads thread(s)" >&2
    "$venv/bin/python" bench/sequences.py "$sequences" --library "$lib" --threads "$threads" \
      "${header[@]}" >>"$out/peers.csv"
    header=(--no-header)
  done
done
python3 bench/sequences_report.py "$out/sie.csv" "$out/peers.csv" | tee "$out/report.md"
