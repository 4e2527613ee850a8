#!/usr/bin/env bash
# Bounded fuzzing of the C ABI and the cloud readers (cargo-fuzz + libFuzzer).
# Usage: scripts/fuzz.sh [seconds per target, default 60]. The corpora under fuzz/corpus/ are
# kept in the repository; new interesting inputs found here are added to them.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
seconds="${1:-60}"
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked --quiet
# cargo-fuzz needs nightly compiler flags; the stable toolchain accepts them with this switch.
export RUSTC_BOOTSTRAP=1
passed=0
for target in estimate_inliers register_correspondences cloud_readers; do
  echo "== fuzz $target for ${seconds}s"
  # cargo fuzz exits non-zero on a crash; PIPESTATUS keeps that through the filter (read
  # right after the pipeline: a following `|| true` would replace it with true's status).
  set +e
  cargo fuzz run "$target" -- -max_total_time="$seconds" -rss_limit_mb=4096 -print_final_stats=1 2>&1 \
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
