#!/usr/bin/env python3
"""sie, Open3D and small_gicp on one scan pair from Python, against its ground truth.

    pip install ./bindings/python "open3d-cpu>=0.17" "small_gicp>=1.0"
    python bindings/python/examples/compare_open3d_small_gicp.py                 # LiDAR pair
    python bindings/python/examples/compare_open3d_small_gicp.py --pair bunny

The clouds are read once with Open3D and handed to each library as it takes them: sie gets the
open3d.geometry.PointCloud objects themselves (sie.align reads their points, and the target's
normals when it has them), Open3D runs point-to-plane ICP, small_gicp PLANE_ICP; both need a
maximum correspondence distance (--max-distance, the value printed), sie has none. Every method
starts from the identity; normals come from 10 neighbours for all three. Exit status 1 when sie
misses the pair's tolerance, never because of another library. A library that is not installed
is reported and skipped.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

import sie

NEIGHBOURS = 10
MAX_ITERATIONS = 100

# bun0 -> bun4 from the Stanford bun.conf poses (pcl-test-bunny/README.md, preferred there).
BUNNY_TRUTH = np.array([
    [0.826351, 0.004137, -0.563141, 0.036838],
    [-0.0106, 0.99991, -0.00821, -0.000257],
    [0.563056, 0.012754, 0.82632, 0.038321],
    [0.0, 0.0, 0.0, 1.0],
])

# pair: (source, target, ground truth, max correspondence distance for the peers, tolerance in
# degrees and metres for sie).
PAIRS = {
    "lidar": ("small_gicp-data/source.ply", "small_gicp-data/target.ply", "small_gicp-data/T_target_source.txt",
              1.0, (0.5, 0.05)),
    "bunny": ("pcl-test-bunny/bun0.pcd", "pcl-test-bunny/bun4.pcd", BUNNY_TRUTH, 0.05, (1.0, 0.005)),
}


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Rotation (degrees) and translation of estimate relative to truth."""
    relative = np.linalg.inv(truth) @ estimate
    cosine = np.clip((np.trace(relative[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cosine))), float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))


def run_sie(o3d, source, target, _max_distance):
    result = sie.align(source, target, max_iterations=MAX_ITERATIONS * 2)
    s = result.summary
    return result.transform, s.iterations, f"{s.stop_reason.name.lower()}", f"sigma {s.sigma[0]:.4g}"


def run_open3d(o3d, source, target, max_distance):
    registration = o3d.pipelines.registration
    result = registration.registration_icp(
        source, target, max_distance, np.eye(4), registration.TransformationEstimationPointToPlane(),
        registration.ICPConvergenceCriteria(max_iteration=MAX_ITERATIONS))
    return np.asarray(result.transformation), None, "-", f"fitness {result.fitness:.3f}"


def run_small_gicp(o3d, source, target, max_distance):
    import small_gicp

    target_cloud = small_gicp.PointCloud(np.asarray(target.points))
    source_cloud = small_gicp.PointCloud(np.asarray(source.points))
    tree = small_gicp.KdTree(target_cloud)
    small_gicp.estimate_normals(target_cloud, tree, num_neighbors=NEIGHBOURS)
    result = small_gicp.align(target_cloud, source_cloud, tree, np.eye(4), registration_type="PLANE_ICP",
                              max_correspondence_distance=max_distance, max_iterations=MAX_ITERATIONS)
    return np.asarray(result.T_target_source), result.iterations, "yes" if result.converged else "no", ""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pair", choices=sorted(PAIRS), default="lidar")
    parser.add_argument("--data", type=Path,
                        default=Path(os.environ.get("SIE_DATA_DIR", Path(__file__).resolve().parents[4] / "shared" / "data")))
    parser.add_argument("--max-distance", type=float, help="Open3D's and small_gicp's gate (default: per pair)")
    args = parser.parse_args()

    try:
        import open3d as o3d
    except ImportError:
        print("open3d is not installed (pip install open3d-cpu): it reads the clouds here", file=sys.stderr)
        return 2
    source_file, target_file, truth, max_distance, (tolerance_deg, tolerance_m) = PAIRS[args.pair]
    if args.max_distance is not None:
        max_distance = args.max_distance
    truth = np.loadtxt(args.data / truth) if isinstance(truth, str) else truth
    source = o3d.io.read_point_cloud(str(args.data / source_file))
    target = o3d.io.read_point_cloud(str(args.data / target_file))
    if len(source.points) == 0 or len(target.points) == 0:
        print(f"cannot read {args.data / source_file} / {target_file}", file=sys.stderr)
        return 2
    # One set of target normals (k = 10) for every method; sie uses the Open3D target's normals.
    target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NEIGHBOURS))

    print(f"pair: {source_file} -> {target_file} ({len(source.points)} / {len(target.points)} points), "
          f"from the identity")
    print(f"versions: sie {sie.__version__}, open3d {o3d.__version__}")
    print(f"Open3D and small_gicp: max correspondence distance {max_distance:g}, at most {MAX_ITERATIONS} "
          f"iterations; sie: defaults, no distance gate")
    print(f"{'method':<34}{'rot [deg]':>10}{'trans':>10}{'iters':>7}{'converged':>11}{'time [s]':>10}  note")
    sie_ok = False
    for name, run in [("sie (SIE, point-to-plane)", run_sie), ("Open3D ICP (point-to-plane)", run_open3d),
                      ("small_gicp PLANE_ICP", run_small_gicp)]:
        started = time.perf_counter()
        try:
            transform, iterations, converged, note = run(o3d, source, target, max_distance)
        except ImportError as error:
            print(f"{name:<34}skipped: {error}")
            continue
        seconds = time.perf_counter() - started
        rotation, translation = pose_error(transform, truth)
        print(f"{name:<34}{rotation:>10.3f}{translation:>10.4f}{iterations if iterations is not None else '-':>7}"
              f"{converged:>11}{seconds:>10.3f}  {note}")
        if run is run_sie:
            sie_ok = rotation <= tolerance_deg and translation <= tolerance_m
    print(f"check: sie within {tolerance_deg} deg and {tolerance_m} of the ground truth -> "
          f"{'PASS' if sie_ok else 'FAIL'}")
    return 0 if sie_ok else 1


if __name__ == "__main__":
    sys.exit(main())
