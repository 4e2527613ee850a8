#!/usr/bin/env python3
"""The peers of sie's global stage (examples/bench_global.rs) on the same cases: Open3D FPFH +
RANSAC (its tutorial's recipe) and KISS-Matcher, each followed by the same Open3D point-to-plane
refinement. Each pair as given and with the source turned 30, 90 and 180 degrees about the same
fixed axes through its centroid; success is 2 degrees and 2 % of the target's diagonal. Both peers
need a voxel size: they get the one sie's rule picks (about 2500 keypoints per cloud, never finer
than the point spacing), the same scale sie's descriptors use. A program, not a test.

    python3 -m venv VENV && VENV/bin/pip install -r bench/requirements.txt
    VENV/bin/python bench/global_peers.py [data dir]
"""
import sys
import time
from pathlib import Path

import numpy as np
import open3d as o3d
import kiss_matcher

TURNS = [(0.0, (0.0, 0.0, 1.0)), (30.0, (0.3, -0.5, 0.8)), (90.0, (-0.7, 0.2, 0.6)), (180.0, (0.1, 0.9, -0.4))]
TARGET_KEYPOINTS = 2500


def read(path):
    if path.suffix == ".xyz":
        return np.loadtxt(path)[:, :3]
    return np.asarray(o3d.io.read_point_cloud(str(path)).points)


def bunny_pose(folder, scan):
    for line in (folder / "bun.conf").read_text().splitlines():
        if line.startswith("bmesh") and f"{scan}.ply" in line:
            tx, ty, tz, qx, qy, qz, qw = map(float, line.split()[2:9])
            rotation = o3d.geometry.get_rotation_matrix_from_quaternion([qw, qx, qy, qz])
            pose = np.eye(4)
            pose[:3, :3] = rotation.T
            pose[:3, 3] = [tx, ty, tz]
            return pose
    raise KeyError(scan)


# Kinect intrinsics and depth scale of the slambook frames (data README); every 4th pixel in both
# directions, as examples/common/slambook.rs reads them for bench_global.
FX, FY, CX, CY, DEPTH_SCALE, DEPTH_STRIDE = 518.0, 519.0, 325.5, 253.5, 1000.0, 4


def kinect_frames(folder):
    """The frames' points (camera frame, metres) and T_world_camera poses."""
    poses = []
    for line in (folder / "pose.txt").read_text().splitlines():
        if line.strip():
            tx, ty, tz, qx, qy, qz, qw = map(float, line.split())
            pose = np.eye(4)
            pose[:3, :3] = o3d.geometry.get_rotation_matrix_from_quaternion([qw, qx, qy, qz])
            pose[:3, 3] = [tx, ty, tz]
            poses.append(pose)
    frames = []
    for i in range(1, len(poses) + 1):
        data = (folder / "depth" / f"{i}.pgm").read_bytes()
        tokens, pos = [], 0
        while len(tokens) < 4:
            while data[pos:pos + 1].isspace():
                pos += 1
            start = pos
            while not data[pos:pos + 1].isspace():
                pos += 1
            tokens.append(data[start:pos])
        width, height = int(tokens[1]), int(tokens[2])
        depth = np.frombuffer(data[pos + 1:pos + 1 + 2 * width * height], dtype=">u2").reshape(height, width)
        v, u = np.mgrid[0:height:DEPTH_STRIDE, 0:width:DEPTH_STRIDE]
        d = depth[::DEPTH_STRIDE, ::DEPTH_STRIDE]
        keep = d != 0
        z = d[keep] / DEPTH_SCALE
        frames.append(np.stack([(u[keep] - CX) * z / FX, (v[keep] - CY) * z / FY, z], axis=1))
    return frames, poses


def rotation(axis, degrees):
    axis = np.asarray(axis) / np.linalg.norm(axis)
    return o3d.geometry.get_rotation_matrix_from_axis_angle(axis * np.radians(degrees))


def spacing(points):
    tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    step = max(1, len(points) // 2000)
    gaps = []
    for p in points[::step]:
        _, _, d2 = tree.search_knn_vector_3d(p, 2)
        gaps.append(np.sqrt(d2[1]))
    return float(np.median(gaps))


def voxel_for(points):
    """sie's rule (src/features/scale.rs): about TARGET_KEYPOINTS occupied voxels, at least the spacing."""
    floor = spacing(points)
    diagonal = np.linalg.norm(points.max(0) - points.min(0))
    voxel = max(diagonal / np.sqrt(TARGET_KEYPOINTS), floor)
    count = lambda v: len(np.unique(np.floor(points / v).astype(np.int64), axis=0))
    for _ in range(6):
        ratio = count(voxel) / TARGET_KEYPOINTS
        if 0.8 <= ratio <= 1.25:
            break
        voxel = max(voxel * np.clip(np.sqrt(ratio), 0.5, 2.0), floor)
    return voxel


def cloud(points):
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))


def open3d_ransac(source, target, voxel):
    def prepare(points):
        down = cloud(points).voxel_down_sample(voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        fpfh = o3d.pipelines.registration.compute_fpfh_feature(
            down, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return down, fpfh
    s, fs = prepare(source)
    t, ft = prepare(target)
    result = o3d.pipelines.registration.registration_ransac_based_on_feature_matching(
        s, t, fs, ft, True, 1.5 * voxel,
        o3d.pipelines.registration.TransformationEstimationPointToPoint(False), 3,
        [o3d.pipelines.registration.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         o3d.pipelines.registration.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        o3d.pipelines.registration.RANSACConvergenceCriteria(100000, 0.999))
    return result.transformation


def kiss(source, target, voxel):
    # KISS-Matcher refuses small voxels ("Too small voxel size", the bunny's 3 mm): the clouds are
    # scaled to its default voxel of 0.3 and the translation scaled back.
    scale = 0.3 / voxel
    matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(0.3))
    solution = matcher.estimate((scale * source).astype(np.float32), (scale * target).astype(np.float32))
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(solution.rotation)
    pose[:3, 3] = np.asarray(solution.translation).ravel() / scale
    return pose


def refine(source, target, guess, voxel):
    """Open3D's point-to-plane ICP, its tutorial's threshold (0.4 voxel) and normals (2 voxels)."""
    t = cloud(target)
    t.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    return o3d.pipelines.registration.registration_icp(
        cloud(source), t, 0.4 * voxel, guess,
        o3d.pipelines.registration.TransformationEstimationPointToPlane()).transformation


def errors(estimate, truth, diagonal):
    difference = np.linalg.inv(truth) @ estimate
    angle = np.degrees(np.arccos(np.clip((np.trace(difference[:3, :3]) - 1) / 2, -1, 1)))
    return angle, np.linalg.norm(difference[:3, 3]) / diagonal


def main():
    data = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared/data"
    bunny = data / "stanford-bunny-scans"
    pairs = []
    for s, t in [("bun045", "bun000"), ("bun315", "bun000"), ("bun090", "bun045"), ("bun270", "bun315")]:
        pairs.append((f"bunny {s} -> {t}", read(bunny / f"{s}.ply"), read(bunny / f"{t}.ply"),
                      np.linalg.inv(bunny_pose(bunny, t)) @ bunny_pose(bunny, s)))
    lo = data / "predator-3dlomatch-redkitchen"
    pairs.append(("3DLoMatch redkitchen 34 -> 21", read(lo / "cloud_bin_34.xyz"), read(lo / "cloud_bin_21.xyz"),
                  np.loadtxt(lo / "gt_34_to_21.txt").reshape(4, 4)))
    lidar = data / "small_gicp-data"
    pairs.append(("LiDAR small_gicp", read(lidar / "source.ply"), read(lidar / "target.ply"),
                  np.loadtxt(lidar / "T_target_source.txt").reshape(4, 4)))
    frames, poses = kinect_frames(data / "slambook-joinmap-rgbd")
    for i in range(1, len(frames)):
        pairs.append((f"Kinect frame {i + 1} -> {i}", frames[i], frames[i - 1],
                      np.linalg.inv(poses[i - 1]) @ poses[i]))
    room = data / "pcl-data-room-scans"
    source, target = read(room / "room_scan2.pcd"), read(room / "room_scan1.pcd")
    guess = np.eye(4)
    guess[:3, :3] = rotation((0, 0, 1), np.degrees(0.6931))
    guess[:3, 3] = [1.79387, 0.720047, 0.0]
    # No exact truth: Open3D's point-to-plane ICP from the tutorial's guess (bench_global uses sie's).
    pairs.append(("PCL room scan2 -> scan1", source, target, refine(source, target, guess, 0.5)))

    print("| pair | turn | peer | rot err [deg] | trans err [% diag] | success | time [s] |")
    print("|---|---|---|---|---|---|---|")
    totals = {}
    for name, source, target, truth in pairs:
        diagonal = np.linalg.norm(target.max(0) - target.min(0))
        voxel = max(voxel_for(source), voxel_for(target))
        for degrees, axis in TURNS:
            turn = np.eye(4)
            c = source.mean(0)
            turn[:3, :3] = rotation(axis, degrees)
            turn[:3, 3] = c - turn[:3, :3] @ c
            turned = source @ turn[:3, :3].T + turn[:3, 3]
            expected = truth @ np.linalg.inv(turn)
            for peer, run in [("Open3D FPFH+RANSAC", open3d_ransac), ("KISS-Matcher", kiss)]:
                started = time.time()
                pose = refine(turned, target, run(turned, target, voxel), voxel)
                seconds = time.time() - started
                angle, shift = errors(pose, expected, diagonal)
                success = angle < 2 and shift < 0.02
                count = totals.setdefault(peer, [0, 0, 0.0])
                count[0] += success
                count[1] += 1
                count[2] += seconds
                print(f"| {name} | {degrees:g}° | {peer} | {angle:.2f} | {100 * shift:.2f} | "
                      f"{'yes' if success else 'no'} | {seconds:.2f} |", flush=True)
    print()
    for peer, (ok, n, seconds) in totals.items():
        print(f"{peer}: {ok} of {n} within 2° and 2 % of the diagonal, {seconds / n:.2f} s a run on average")


if __name__ == "__main__":
    main()
