#!/usr/bin/env python3
"""Register room_N pairs with one peer library (Open3D or small_gicp) and print CSV rows.

Usage: peers.py --library open3d|small_gicp --threads T [--sizes N,N] [--repeats 3]
                [--max-dist 0.5] [--no-header] DIR

Run once per (library, thread count) in a fresh process: thread limits are
process-wide and some can only be set before the library is loaded.
bench/peers.sh does that for both libraries and 1 and 2 threads.
"""
import argparse
import contextlib
import io
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HEADER = ("library,method,points,threads,seconds,iterations,"
          "rotation_error_deg,translation_error_m,converged,note")
K = 10            # target normals from the k nearest neighbours (same as ours)
MAX_DIST = 0.5    # default cut-off: both peers need one, ours has none
MAX_ITER = 100


def read_pcd(path):
    """Binary PCD v0.7 with exactly FIELDS x y z as little-endian float32 -> (N, 3) float32."""
    data = Path(path).read_bytes()
    header, pos = {}, 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            sys.exit(f"{path}: no 'DATA binary' line in the header")
        line = data[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key] = value.split()
        if key == "DATA":
            break
    expect = {"FIELDS": ["x", "y", "z"], "SIZE": ["4"] * 3, "TYPE": ["F"] * 3,
              "COUNT": ["1"] * 3, "DATA": ["binary"]}
    for key, want in expect.items():
        got = header.get(key, ["1"] * 3 if key == "COUNT" else None)  # COUNT is optional
        if got != want:
            got = "missing" if got is None else "'" + " ".join(got) + "'"
            sys.exit(f"{path}: unsupported PCD, {key} is {got}, need '{' '.join(want)}'")
    n = int(header["POINTS"][0]) if "POINTS" in header else \
        int(header["WIDTH"][0]) * int(header["HEIGHT"][0])
    if len(data) - pos < n * 12:
        sys.exit(f"{path}: header says {n} points but only {len(data) - pos} data bytes")
    return np.frombuffer(data, dtype="<f4", count=n * 3, offset=pos).reshape(n, 3)


def errors(T_gt, T_est):
    E = np.linalg.inv(T_gt) @ T_est
    cos = np.clip((np.trace(E[:3, :3]) - 1) / 2, -1.0, 1.0)
    return math.degrees(math.acos(cos)), float(np.linalg.norm(E[:3, 3]))


def open3d_runner(threads, max_dist):
    os.environ["OMP_NUM_THREADS"] = str(threads)  # older, OpenMP builds read it at load time
    import open3d as o3d
    print(f"open3d {o3d.__version__}, OMP_NUM_THREADS={threads}", file=sys.stderr)
    # 0.20 uses TBB and ignores OMP_NUM_THREADS; this is its own process-wide limit.
    if hasattr(o3d.utility, "set_max_threads"):
        o3d.utility.set_max_threads(threads)
        print(f"open3d max threads {o3d.utility.get_max_threads()}", file=sys.stderr)
    reg = o3d.pipelines.registration

    def run(src, tgt):
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src.astype(np.float64)))
        target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tgt.astype(np.float64)))
        target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(K))
        # The result has no iteration count; the debug log prints one line per
        # iteration through Python's print, so count those (a few hundred lines, negligible cost).
        log = io.StringIO()
        with contextlib.redirect_stdout(log), \
                o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Debug):
            result = reg.registration_icp(
                source, target, max_dist, np.eye(4), reg.TransformationEstimationPointToPlane(),
                reg.ICPConvergenceCriteria(max_iteration=MAX_ITER))
        iters = log.getvalue().count("ICP Iteration #") or None
        # Open3D stops early only when fitness and RMSE stop changing.
        converged = None if iters is None else iters < MAX_ITER
        return np.asarray(result.transformation), iters, converged

    return "point-to-plane", "iterations from debug log", run


def small_gicp_runner(threads, max_dist):
    os.environ["OMP_NUM_THREADS"] = str(threads)  # num_threads below is what counts
    import small_gicp
    print(f"small_gicp (num_threads={threads})", file=sys.stderr)

    def run(src, tgt):
        target = small_gicp.PointCloud(tgt.astype(np.float64))
        source = small_gicp.PointCloud(src.astype(np.float64))
        tree = small_gicp.KdTree(target, num_threads=threads)
        small_gicp.estimate_normals(target, tree, num_neighbors=K, num_threads=threads)
        result = small_gicp.align(target, source, tree, np.eye(4), registration_type="PLANE_ICP",
                                  max_correspondence_distance=max_dist, num_threads=threads,
                                  max_iterations=MAX_ITER)
        return np.asarray(result.T_target_source), result.iterations, result.converged

    return "PLANE_ICP", "", run


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--library", required=True, choices=["open3d", "small_gicp"])
    ap.add_argument("--threads", type=int, required=True)
    ap.add_argument("--sizes", help="comma separated N; default all room_*_source.pcd in DIR")
    ap.add_argument("--repeats", type=int,
                    help="timed runs per size (median reported); default 3 up to 100000 points, "
                         "1 above, as bench/pcl.sh and bench_icp do")
    ap.add_argument("--max-dist", type=float, default=MAX_DIST,
                    help="max correspondence distance in metres")
    ap.add_argument("--no-header", action="store_true")
    args = ap.parse_args()

    if args.sizes:
        sizes = sorted(int(s) for s in args.sizes.split(","))
    else:
        sizes = sorted(int(p.name.split("_")[1]) for p in args.dir.glob("room_*_source.pcd"))
    if not sizes:
        sys.exit(f"{args.dir}: no room_N_source.pcd files")

    runner = open3d_runner if args.library == "open3d" else small_gicp_runner
    method, extra, run = runner(args.threads, args.max_dist)

    if not args.no_header:
        print(HEADER, flush=True)
    for n in sizes:
        src = read_pcd(args.dir / f"room_{n}_source.pcd")
        tgt = read_pcd(args.dir / f"room_{n}_target.pcd")
        T_gt = np.loadtxt(args.dir / f"room_{n}_gt.txt").reshape(4, 4)
        repeats = args.repeats or (3 if n <= 100_000 else 1)
        note = f"k={K} maxdist={args.max_dist:g} maxiter={MAX_ITER} repeats={repeats}"
        note += f" {extra}" if extra else ""
        times = []
        for r in range(repeats):
            t0 = time.perf_counter()
            T, iters, converged = run(src, tgt)
            times.append(time.perf_counter() - t0)
            print(f"{args.library} N={n} threads={args.threads} run {r + 1}: {times[-1]:.3f} s",
                  file=sys.stderr)
        rot, trans = errors(T_gt, T)
        fmt = lambda v: "" if v is None else str(v).lower()
        print(f"{args.library},{method},{len(src)},{args.threads},{statistics.median(times):.4f},"
              f"{fmt(iters)},{rot:.5f},{trans:.6f},{fmt(converged)},{note}", flush=True)


if __name__ == "__main__":
    main()
