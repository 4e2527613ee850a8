#!/usr/bin/env bash
# Usage: bench/peers.sh DIR [N,N,...|all] [peers.py options, e.g. --max-dist 0.2]
# Registers DIR/room_N_{source,target}.pcd with Open3D point-to-plane ICP and
# small_gicp PLANE_ICP at 1 and 2 threads; CSV on stdout, progress on stderr.
# The venv lives outside the repo: ${SIE_BENCH_VENV:-$HOME/.cache/sie-bench-venv}.
set -euo pipefail
[ $# -ge 1 ] || { echo "usage: $0 DIR [N,N,...|all] [peers.py options]" >&2; exit 2; }
here=$(cd "$(dirname "$0")" && pwd)
venv=${SIE_BENCH_VENV:-$HOME/.cache/sie-bench-venv}
[ -x "$venv/bin/python" ] || python3 -m venv "$venv" >&2
"$venv/bin/pip" install -q --disable-pip-version-check -r "$here/requirements.txt" >&2

dir=$1; shift
sizes=()
if [ $# -ge 1 ]; then
  [ "$1" = all ] || sizes=(--sizes "$1")
  shift
fi
header=()
for lib in open3d small_gicp; do
  for threads in 1 2; do
    # A fresh process per thread count: thread limits are process-wide.
    echo "== $lib, $threads thread(s)" >&2
    "$venv/bin/python" "$here/peers.py" "$dir" --library "$lib" --threads "$threads" \
      "${sizes[@]}" "${header[@]}" "$@"
    header=(--no-header)
  done
done
