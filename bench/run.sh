#!/usr/bin/env bash
# The ICP benchmark of docs/performance.md in one run: writes the synthetic room pairs, then
# times sie (bench_icp, per-stage times), PCL (bench/pcl.sh) and Open3D + small_gicp
# (bench/peers.sh, own venv) on the same files, one after the other, and prints the report.
#
#   bench/run.sh [OUT_DIR] [N,N,...]     (default: build/bench-run, 10000,100000,1000000)
#
# SIE_BENCH_SKIP=pcl,peers leaves libraries out (PCL takes ~10 min at 1M points). Not part of
# the default tests. Needs cargo; PCL needs cmake, g++, libpcl-dev; the peers need PyPI.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/bench-run}
sizes=${2:-10000,100000,1000000}
skip=${SIE_BENCH_SKIP:-}
mkdir -p "$out"
scenes=$out/scenes

echo "== scenes ($sizes points) into $scenes" >&2
cargo run --release --quiet --example bench_icp -- scenes "$scenes" "$sizes"
echo "== sie" >&2
cargo run --release --quiet --example bench_icp -- run "$scenes" "$sizes" >"$out/sie.csv"
if [[ ",$skip," != *,pcl,* ]]; then
  echo "== PCL (through examples-cpp/compare_pcl)" >&2
  bench/pcl.sh "$scenes" "$sizes" >"$out/pcl.csv"
fi
if [[ ",$skip," != *,peers,* ]]; then
  echo "== Open3D and small_gicp (PyPI)" >&2
  bench/peers.sh "$scenes" "$sizes" >"$out/peers.csv"
fi
python3 bench/report.py "$out"/*.csv | tee "$out/report.md"
