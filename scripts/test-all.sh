#!/usr/bin/env bash
# Runs every test of the repository on a fresh Debian machine (this is what CI runs).
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages: a C and C++ compiler for the C ABI tests.
need=()
command -v cc >/dev/null || need+=(gcc)
command -v g++ >/dev/null || need+=(g++)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  fi
fi

# Real scans for the data-driven tests (CI has ../shared/data beside the checkout).
export SIE_DATA_DIR="${SIE_DATA_DIR:-$(cd .. && pwd)/shared/data}"

echo "== rustfmt"
cargo fmt --all -- --check
echo "== clippy"
cargo clippy --release --all-targets --locked -- -D warnings
echo "== tests (unit, integration, C ABI, header)"
cargo test --release --locked
