#!/usr/bin/env python3
"""Odometry with a peer library over the sequences bench_sequences wrote; CSV rows on stdout.

Usage: sequences.py DIR --library small_gicp|kiss_icp --threads T [--max-dist 0.5] [--no-header]

small_gicp: PLANE_ICP, frame to previous frame (each frame's KdTree and normals built once and
reused as the next frame's target) and frame to a voxel map of keyframes (the map, its KdTree and
normals rebuilt at each keyframe), with the rules of examples/bench_sequences.rs: the same
constant-velocity guess, map voxel (DIR/<sequence>/voxel.txt, first point per voxel) and
keyframe interval. KISS-ICP: its own pipeline (kiss_icp.KissICP: voxel hash map, adaptive
threshold, constant-velocity guess), voxel_size from voxel.txt, no deskewing.
Run once per (library, thread count) in a fresh process; bench/sequences.sh does that.
"""
import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

HEADER = ("library,method,sequence,points,frames,threads,mode,seconds,fps,rpe_t_rmse_mm,"
          "rpe_r_rmse_deg,rpe_t_max_mm,ate_t_rmse_mm,note")
K = 10                 # target normals from the k nearest neighbours (as sie's default)
KEYFRAME_INTERVAL = 5  # as examples/bench_sequences.rs
MAX_ITER = 100


def read_sequence(folder):
    poses = np.loadtxt(folder / "poses.txt", ndmin=2).reshape(-1, 4, 4)
    voxel = float((folder / "voxel.txt").read_text().split()[0])
    frames = [np.fromfile(folder / f"{i:04d}.f32", dtype="<f4").reshape(-1, 3).astype(np.float64)
              for i in range(len(poses))]
    return frames, poses, voxel


def absolute_trajectory_error(truth, estimate):
    """RMS distance (mm) of each estimated position from the true one; every trajectory starts at
    the true first pose, so no alignment is fitted (as examples/bench_sequences.rs)."""
    errors = [np.linalg.norm(e[:3, 3] - t[:3, 3]) * 1e3 for t, e in zip(truth, estimate)]
    return math.sqrt(np.mean(np.square(errors)))


def relative_pose_errors(truth, estimate):
    """RMS and max per-frame error of the motion i-1 -> i: translation mm, rotation degrees."""
    t, r = [], []
    for i in range(1, len(truth)):
        true_motion = np.linalg.inv(truth[i - 1]) @ truth[i]
        estimated = np.linalg.inv(estimate[i - 1]) @ estimate[i]
        error = np.linalg.inv(true_motion) @ estimated
        t.append(np.linalg.norm(error[:3, 3]) * 1e3)
        r.append(math.degrees(math.acos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1.0, 1.0))))
    t, r = np.array(t), np.array(r)
    return math.sqrt(np.mean(t ** 2)), math.sqrt(np.mean(r ** 2)), float(t.max())


class VoxelMap:
    """World points of keyframes, one per voxel: the first that fell into it (vectorised, so
    that Python does not slow the peer down)."""

    def __init__(self, voxel):
        self.voxel = voxel
        self.points = np.empty((0, 3))

    def insert(self, frame, pose):
        world = frame @ pose[:3, :3].T + pose[:3, 3]
        points = np.vstack([self.points, world])
        cells = np.floor(points / self.voxel).astype(np.int64) + (1 << 20)
        keys = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
        _, first = np.unique(keys, return_index=True)
        self.points = points[np.sort(first)]

    def array(self):
        return self.points


def small_gicp_odometry(frames, poses, voxel, mode, threads, max_dist):
    import small_gicp

    def prepare(points):
        cloud = small_gicp.PointCloud(points)
        tree = small_gicp.KdTree(cloud, num_threads=threads)
        small_gicp.estimate_normals(cloud, tree, num_neighbors=K, num_threads=threads)
        return cloud, tree

    def align(target, tree, source, guess):
        result = small_gicp.align(target, source, tree, guess, registration_type="PLANE_ICP",
                                  max_correspondence_distance=max_dist, num_threads=threads,
                                  max_iterations=MAX_ITER)
        return np.asarray(result.T_target_source), result.iterations

    estimates, velocity, iterations = [poses[0]], np.eye(4), 0
    voxel_map = VoxelMap(voxel)
    if mode == "frame-to-frame":
        target, tree = prepare(frames[0])
    else:
        voxel_map.insert(frames[0], poses[0])
        target, tree = prepare(voxel_map.array())
    for i in range(1, len(frames)):
        previous = estimates[-1]
        if mode == "frame-to-frame":
            source, source_tree = prepare(frames[i])
            T, n = align(target, tree, source, velocity)
            target, tree = source, source_tree
            pose = previous @ T
        else:
            pose, n = align(target, tree, small_gicp.PointCloud(frames[i]), previous @ velocity)
            if i % KEYFRAME_INTERVAL == 0:
                voxel_map.insert(frames[i], pose)
                target, tree = prepare(voxel_map.array())
        iterations += n
        velocity = np.linalg.inv(previous) @ pose
        estimates.append(pose)
    note = f"{iterations / max(len(frames) - 1, 1):.1f} iterations/frame; maxdist={max_dist:g}"
    if mode == "frame-to-map":
        note += f"; map {len(voxel_map.points)} points"
    return "PLANE_ICP", estimates, note


def kiss_icp_odometry(frames, poses, voxel, mode, threads, max_dist):
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    config = KISSConfig()
    config.data.deskew = False
    config.data.max_range = 1e4
    config.data.min_range = 0.0
    config.mapping.voxel_size = voxel
    config.registration.max_num_threads = threads
    odometry = KissICP(config)
    estimates = []
    for frame in frames:
        odometry.register_frame(frame, np.zeros(len(frame)))
        # KISS-ICP starts at the identity; express its poses from the true first pose.
        estimates.append(poses[0] @ odometry.last_pose)
    return "pipeline", estimates, f"voxel_size={voxel:g}; its own map and adaptive threshold"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--library", required=True, choices=["small_gicp", "kiss_icp"])
    ap.add_argument("--threads", type=int, required=True)
    ap.add_argument("--max-dist", type=float, default=0.5, help="small_gicp's correspondence cut-off (m)")
    ap.add_argument("--no-header", action="store_true")
    args = ap.parse_args()
    os.environ["OMP_NUM_THREADS"] = str(args.threads)

    folders = sorted(p.parent for p in args.dir.glob("*/poses.txt"))
    if not folders:
        sys.exit(f"{args.dir}: no sequences (run bench_sequences write first)")
    if not args.no_header:
        print(HEADER, flush=True)
    # Imported here, before any timing.
    if args.library == "small_gicp":
        import small_gicp  # noqa: F401
        odometry, modes = small_gicp_odometry, ["frame-to-frame", "frame-to-map"]
    else:
        import kiss_icp.kiss_icp  # noqa: F401
        odometry, modes = kiss_icp_odometry, ["kiss-icp map"]
    for folder in folders:
        frames, poses, voxel = read_sequence(folder)
        for mode in modes:
            started = time.perf_counter()
            method, estimates, note = odometry(frames, poses, voxel, mode, args.threads, args.max_dist)
            seconds = time.perf_counter() - started
            t_rmse, r_rmse, t_max = relative_pose_errors(poses, estimates)
            ate = absolute_trajectory_error(poses, estimates)
            points = sum(len(f) for f in frames) // len(frames)
            print(f"{args.library},{method},{folder.name},{points},{len(frames)},{args.threads},{mode},"
                  f"{seconds:.4f},{(len(frames) - 1) / seconds:.2f},{t_rmse:.3f},{r_rmse:.4f},{t_max:.3f},{ate:.3f},{note}",
                  flush=True)
            print(f"{args.library} {folder.name} {mode} threads={args.threads}: {seconds:.2f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
