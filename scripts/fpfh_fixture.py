#!/usr/bin/env python3
"""Writes tests/data/fpfh_open3d.txt: Open3D's FPFH of a few hundred points with given normals,
the reference tests/fpfh_open3d.rs checks sie's FPFH against.

Run once (it needs open3d 0.20.0, as in bench/requirements.txt):
    python3 -m venv /tmp/venv31 && /tmp/venv31/bin/pip install open3d==0.20.0
    /tmp/venv31/bin/python scripts/fpfh_fixture.py

The points: 400 random points (seed 31) on a bumpy surface z = 0.3 sin(2x) cos(3y) over the unit
square, its unit normals from the gradient (turned towards +z), and 40 points of a sphere
(radius 0.2, centre (0.5, 0.5, 0.6), outward normals) so that the histograms vary. The search is
Open3D's hybrid one, radius 0.25 and at most 100 neighbours (the point itself counted).
Each line: x y z nx ny nz and the 33 bins, full precision.
"""
import numpy as np
import open3d as o3d

RADIUS = 0.25
MAX_NN = 100

rng = np.random.default_rng(31)
xy = rng.random((400, 2))
z = 0.3 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1])
surface = np.column_stack([xy, z])
dzdx = 0.6 * np.cos(2 * xy[:, 0]) * np.cos(3 * xy[:, 1])
dzdy = -0.9 * np.sin(2 * xy[:, 0]) * np.sin(3 * xy[:, 1])
surface_normals = np.column_stack([-dzdx, -dzdy, np.ones(len(xy))])
surface_normals /= np.linalg.norm(surface_normals, axis=1, keepdims=True)

directions = rng.normal(size=(40, 3))
directions /= np.linalg.norm(directions, axis=1, keepdims=True)
sphere = np.array([0.5, 0.5, 0.6]) + 0.2 * directions

points = np.vstack([surface, sphere])
normals = np.vstack([surface_normals, directions])

cloud = o3d.geometry.PointCloud()
cloud.points = o3d.utility.Vector3dVector(points)
cloud.normals = o3d.utility.Vector3dVector(normals)
fpfh = o3d.pipelines.registration.compute_fpfh_feature(
    cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=RADIUS, max_nn=MAX_NN)
).data.T

with open("tests/data/fpfh_open3d.txt", "w") as out:
    out.write(f"# open3d {o3d.__version__} compute_fpfh_feature, hybrid radius {RADIUS} max_nn {MAX_NN}; "
              "made by scripts/fpfh_fixture.py\n")
    for p, n, f in zip(np.asarray(cloud.points), np.asarray(cloud.normals), fpfh):
        out.write(" ".join(repr(float(v)) for v in [*p, *n, *f]) + "\n")
