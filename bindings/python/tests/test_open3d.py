"""sie.align on Open3D point clouds, and the example comparing sie, Open3D and small_gicp."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sie
from conftest import require
from test_sie import TRUTH, clouds, pose_error  # noqa: F401 (clouds is a fixture)

o3d = require("open3d")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "compare_open3d_small_gicp.py"
DATA = Path(os.environ.get("SIE_DATA_DIR", Path(__file__).resolve().parents[4] / "shared" / "data"))


def legacy(points, normals=None):
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    if normals is not None:
        cloud.normals = o3d.utility.Vector3dVector(np.asarray(normals, dtype=np.float64))
    return cloud


def test_legacy_point_clouds_register_like_arrays(clouds):
    source, target, normals = clouds
    as_arrays = sie.align(source.astype(np.float64), target.astype(np.float64))
    as_open3d = sie.align(legacy(source), legacy(target))
    # Open3D holds float64: the same input as the float64 arrays, the same deterministic result.
    np.testing.assert_array_equal(as_open3d.transform, as_arrays.transform)
    rotation, translation = pose_error(as_open3d.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004


def test_target_normals_are_used(clouds):
    source, target, normals = clouds
    with_normals = sie.align(legacy(source), legacy(target, normals))
    given = sie.align(source, target, target_normals=normals)
    np.testing.assert_allclose(with_normals.transform, given.transform, atol=1e-6)
    # Wrong normals (all along x) change the result: proof that they are read, not estimated.
    wrong = np.tile([1.0, 0.0, 0.0], (len(target), 1))
    misled = sie.align(legacy(source), legacy(target, wrong))
    assert not np.allclose(misled.transform, given.transform, atol=1e-4)
    # Explicit target_normals win over the cloud's own.
    explicit = sie.align(legacy(source), legacy(target, wrong), target_normals=normals)
    np.testing.assert_allclose(explicit.transform, given.transform, atol=1e-6)


def test_tensor_point_clouds(clouds):
    source, target, normals = clouds
    tensor_source = o3d.t.geometry.PointCloud(o3d.core.Tensor(source))
    tensor_target = o3d.t.geometry.PointCloud(o3d.core.Tensor(target))
    tensor_target.point.normals = o3d.core.Tensor(normals)
    result = sie.Context().align(tensor_source, tensor_target)
    given = sie.align(source, target, target_normals=normals)
    np.testing.assert_allclose(result.transform, given.transform, atol=1e-6)


def test_other_open3d_objects_are_refused():
    with pytest.raises(TypeError, match="not a point cloud"):
        sie.align(o3d.geometry.TriangleMesh(), legacy(np.zeros((10, 3))))


def test_example_compares_the_three_on_the_bunny():
    if not (DATA / "pcl-test-bunny" / "bun0.pcd").exists():
        pytest.skip(f"{DATA}/pcl-test-bunny not present")
    run = subprocess.run([sys.executable, str(EXAMPLE), "--pair", "bunny", "--data", str(DATA)],
                         capture_output=True, text=True, check=False)
    print(run.stdout, run.stderr)
    assert run.returncode == 0, run.stderr
    assert "sie (SIE, point-to-plane)" in run.stdout and "Open3D ICP" in run.stdout
    # small_gicp is optional for the example, not for CI's run of this test.
    if os.environ.get("SIE_REQUIRE_OPTIONAL") == "1":
        assert "small_gicp PLANE_ICP" in run.stdout and "skipped" not in run.stdout
    assert "-> PASS" in run.stdout
