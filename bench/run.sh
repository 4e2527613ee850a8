#!/usr/bin/env bash
# The ICP benchmark of docs/performance.md in one run: writes the synthetic room pairs, then
# times sie (bench_icp, per-stage times), PCL (bench/pcl.sh) and Open3D + small_gicp
# (bench/peers.sh, own venv) on the same files, one after the other, and prints the report.
#
#   bench/run.sh [OUT_DIR] [N,N,...]     (default: build/bench-run, 10000,100000,1000000)
#
# SIE_BENCH_SKIP=pcl,peers leaves libraries out (PCL takes ~10 min at 1M points);
# SIE_BENCH_SKIP=sie reuses OUT_DIR/sie.csv. SIE_BENCH_MAX_DIST sets the peers' and PCL's
# correspondence cut-off (default 0.5 m; sie has none). Not part of the default tests. Needs
# cargo; PCL needs cmake, g++, libpcl-dev; the peers need PyPI.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/bench-run}
sizes=${2:-10000,100000,1000000}
skip=${SIE_BENCH_SKIP:-}
mkdir -p "$out"
scenes=$out/scenes

echo "== scenes ($sizes points) into $scenes" >&2
cargo run --release --quiet --example bench_icp -- scenes "$scenes" "$sizes"
max_dist=${SIE_BENCH_MAX_DIST:-0.5}
suffix=$([ "$max_dist" = 0.5 ] || echo "-maxdist-$max_dist")
if [[ ",$skip," != *,sie,* ]]; then
  echo "== sie" >&2
  cargo run --release --quiet --example bench_icp -- run "$scenes" "$sizes" >"$out/sie.csv"
fi
if [[ ",$skip," != *,pcl,* ]]; then
  echo "== PCL (through examples-cpp/compare_pcl), max distance $max_dist" >&2
  SIE_BENCH_MAX_DIST=$max_dist bench/pcl.sh "$scenes" "$sizes" >"$out/pcl$suffix.csv"
fi
if [[ ",$skip," != *,peers,* ]]; then
  echo "== Open3D and small_gicp (PyPI), max distance $max_dist" >&2
  bench/peers.sh "$scenes" "$sizes" --max-dist "$max_dist" >"$out/peers$suffix.csv"
fi
python3 bench/report.py "$out"/*.csv | tee "$out/report.md"
