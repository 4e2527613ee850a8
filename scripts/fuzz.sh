#!/usr/bin/env bash
# Bounded fuzzing of the C ABI and the cloud readers (cargo-fuzz + libFuzzer).
#
# Usage: scripts/fuzz.sh [RUNS]   (default 20000; executions, scaled per target below)
#        SIE_FUZZ_EXPLORE_SECONDS=600 scripts/fuzz.sh   (explore for a time per target instead;
#                                                         new inputs are added to fuzz/corpus/)
#
# The default is reproducible: a fixed number of executions, seeded from the commit being
# tested, starting from the corpora kept in fuzz/corpus/ (read, not modified). A given commit
# therefore always passes or always fails, whatever the machine's load (a time budget would
# explore fewer inputs on a busy machine), while every new commit explores new inputs.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
runs="${1:-20000}"
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked --quiet
# cargo-fuzz needs nightly compiler flags; the stable toolchain accepts them with this switch.
export RUSTC_BOOTSTRAP=1
commit=$(git rev-parse HEAD 2>/dev/null || echo 1)
seed=$((16#${commit:0:7} % 2147483647 + 1))
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
passed=0
# Each target with its executions per RUNS/8, from what one execution costs (this machine, RUNS =
# 20000: ~1.5 min each; wide residual matrices and ICP are the slow ones).
for entry in estimate_inliers:1 register_correspondences:4 register_clouds:1 cloud_readers:80 prepared_target:1 \
  starts_and_warm_starts:2 odometry_frames:1; do
  target=${entry%%:*}
  if [ -n "${SIE_FUZZ_EXPLORE_SECONDS:-}" ]; then
    echo "== fuzz $target for ${SIE_FUZZ_EXPLORE_SECONDS}s"
    corpora=("corpus/$target")
    budget=(-max_total_time="$SIE_FUZZ_EXPLORE_SECONDS")
  else
    target_runs=$((runs * ${entry##*:} / 8))
    echo "== fuzz $target: $target_runs runs, seed $seed"
    mkdir -p "$scratch/$target"
    # New inputs go to the scratch folder (first); the kept corpus is only read.
    corpora=("$scratch/$target" "corpus/$target")
    budget=(-runs="$target_runs" -seed="$seed")
  fi
  # cargo fuzz exits non-zero on a crash; PIPESTATUS keeps that through the filter (read
  # right after the pipeline: a following `|| true` would replace it with true's status).
  set +e
  cargo fuzz run "$target" "${corpora[@]}" -- "${budget[@]}" -rss_limit_mb=4096 -print_final_stats=1 2>&1 \
    | grep -E "^(Done|stat::number_of_executed_units|==[0-9]+==ERROR|SUMMARY)|panicked|Test unit written"
  status=${PIPESTATUS[0]}
  set -e
  if [ "$status" -ne 0 ]; then
    echo "fuzz target $target failed (exit $status); the crashing input is in fuzz/artifacts/$target/"
    echo "fuzz: $passed passed, 1 failed"
    exit 1
  fi
  passed=$((passed + 1))
done
echo "fuzz: $passed passed, 0 failed"
