"""Tests of the ctypes binding against the real libsie (found as the package documents; CI sets
SIE_LIBRARY to the staged install)."""

from __future__ import annotations

import ctypes
import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

import sie
from sie import _native

# ---- synthetic data --------------------------------------------------------------------------


def rigid(angle, axis, translation):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    x, y, z = axis
    c, s, C = np.cos(angle), np.sin(angle), 1 - np.cos(angle)
    T = np.eye(4)
    T[:3, :3] = [
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ]
    T[:3, 3] = translation
    return T


def transform(T, points):
    return points @ T[:3, :3].T + T[:3, 3]


def pose_error(estimate, truth):
    cosine = np.clip((np.trace(estimate[:3, :3] @ truth[:3, :3].T) - 1) / 2, -1, 1)
    return np.degrees(np.arccos(cosine)), np.linalg.norm(estimate[:3, 3] - truth[:3, 3])


def room_corner(count, noise, rng):
    """Floor, two walls, a sphere and a box top, with exact normals."""
    pick = rng.uniform(size=count)
    u, v = rng.uniform(0, 2, size=(2, count))
    points = np.zeros((count, 3))
    normals = np.zeros((count, 3))
    floor, wall_x, wall_y = pick < 0.3, (pick >= 0.3) & (pick < 0.5), (pick >= 0.5) & (pick < 0.7)
    sphere, box = (pick >= 0.7) & (pick < 0.9), pick >= 0.9
    points[floor] = np.c_[u[floor], v[floor], np.zeros(floor.sum())]
    normals[floor] = [0, 0, 1]
    points[wall_x] = np.c_[np.zeros(wall_x.sum()), u[wall_x], 0.75 * v[wall_x]]
    normals[wall_x] = [1, 0, 0]
    points[wall_y] = np.c_[u[wall_y], np.zeros(wall_y.sum()), 0.75 * v[wall_y]]
    normals[wall_y] = [0, 1, 0]
    zs = rng.uniform(0, 1, size=sphere.sum())
    phi = rng.uniform(0, 2 * np.pi, size=sphere.sum())
    n = np.c_[np.sqrt(1 - zs**2) * np.cos(phi), np.sqrt(1 - zs**2) * np.sin(phi), zs]
    points[sphere] = [1.2, 1.0, 0.3] + 0.3 * n
    normals[sphere] = n
    points[box] = np.c_[0.4 + 0.15 * u[box], 1.4 + 0.2 * v[box], np.full(box.sum(), 0.45)]
    normals[box] = [0, 0, 1]
    return points + rng.normal(0, noise, size=points.shape), normals


TRUTH = rigid(0.09, [0.3, -0.2, 1.0], [0.08, -0.05, 0.04])


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(3)
    source, _ = room_corner(3000, 0.002, rng)
    target, target_normals = room_corner(3000, 0.002, rng)
    source = transform(np.linalg.inv(TRUTH), source)
    return source.astype(np.float32), target.astype(np.float32), target_normals.astype(np.float32)


def paper_simulation(inliers, outliers, noise, t0, rng):
    """The paper's correspondence simulation: inlier A uniform in [0,1]^3, B = A + N(0, noise^2),
    A moved by T0; outliers with B uniform in A + [-1,1]^3. Inliers first."""
    a = rng.uniform(size=(inliers, 3))
    b = a + rng.normal(0, noise, size=a.shape)
    a_out = rng.uniform(size=(outliers, 3))
    b_out = a_out + rng.uniform(-1, 1, size=a_out.shape)
    return np.vstack([transform(t0, a), a_out]), np.vstack([b, b_out])


def kabsch(source, target):
    """Least-squares rigid transform (the T_MLE on the inliers alone)."""
    ms, mt = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - ms).T @ (target - mt))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1, 1, d]) @ u.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, mt - R @ ms
    return T


def rms(T, source, target):
    return np.sqrt(np.mean(np.sum((transform(T, source) - target) ** 2, axis=1)))


# ---- the binding itself ------------------------------------------------------------------------


REPOSITORY = Path(__file__).resolve().parents[3]


def test_library_version_matches_the_binding():
    assert sie.library_version() == sie.__version__
    # One version everywhere: the wheel's is the Rust package's (setup.py reads Cargo.toml).
    cargo = REPOSITORY / "Cargo.toml"
    if cargo.is_file():
        line = next(l for l in cargo.read_text().splitlines() if l.startswith("version = "))
        assert sie.__version__ == line.split('"')[1]


def test_the_library_is_called_with_the_gil_released():
    # ctypes.CDLL releases the GIL around every call (PyDLL would hold it): registrations in
    # several threads (e.g. a Dask worker's) run in parallel.
    assert isinstance(sie._lib, ctypes.CDLL) and not isinstance(sie._lib, ctypes.PyDLL)


def test_package_is_typed():
    package = Path(sie.__file__).parent
    assert (package / "py.typed").is_file()
    if os.environ.get("SIE_EXPECT_BUNDLED") == "1":
        # Installed with pip: the library inside the package is the one loaded.
        assert Path(sie._lib._name).resolve() == (package / _native.SONAME).resolve()


def test_enums_print_as_names():
    assert str(sie.StopReason.CONVERGED) == "StopReason.CONVERGED"
    assert f"{sie.Status.TOO_FEW_POINTS}" == "Status.TOO_FEW_POINTS"
    assert f"{sie.Metric.POINT_TO_PLANE:>30}".endswith("Metric.POINT_TO_PLANE")
    assert sie.StopReason.CONVERGED == 1  # still the C value


def test_numpy_style_validation(clouds):
    source, target, _ = clouds
    ctx = sie.Context()
    # Points as columns: refused with the fix, not read as 3 points.
    with pytest.raises(ValueError, match=r"3 x N.*source\.T"):
        ctx.align(source.T, target)
    with pytest.raises(ValueError, match=r"target\[:, :3\]"):
        ctx.align(source, np.c_[target, target])
    with pytest.raises(ValueError, match="N x 3"):
        ctx.align(source[:, 0], target)
    for bad, kind in [(source.astype(np.complex128), "complex"), (source.astype(str), "string"),
                      (source.astype(object), "object"), (source > 0, "boolean")]:
        with pytest.raises(TypeError, match=kind):
            ctx.align(bad, target)
    with pytest.raises(TypeError, match="complex"):
        ctx.align(source, target, init=np.eye(4, dtype=complex))
    with pytest.raises(TypeError, match="string"):
        ctx.estimate_inliers(["0.1"] * 20)
    # Integers are numbers: converted.
    as_int = np.rint(source * 1000).astype(np.int32)
    result = ctx.align(as_int, np.rint(target * 1000).astype(np.int64))
    assert result.summary.source_count == len(source)
    # Too few residuals for a histogram: said, not answered with P at its cap.
    with pytest.raises(sie.SieError) as error:
        ctx.estimate_inliers([0.1, -0.2])
    assert error.value.status is sie.Status.TOO_FEW_POINTS
    assert "2 given, at least 10" in error.value.message


def test_progress_carries_the_transform_and_the_summary_inlier_fraction(clouds):
    source, target, _ = clouds
    # From the initial guess alone the last update's transform is the result: a viewer moving
    # the cloud with each one ends there (one run: it corrected the guess locally).
    seen = []
    ctx = sie.Context(trace=True, starts=sie.Starts.INITIAL_GUESS)
    ctx.set_progress_callback(seen.append)
    result = ctx.align(source, target)
    assert len(seen) == result.summary.iterations and result.summary.starts_run == 1
    assert result.summary.agreeing_starts == 1
    assert all(e.transform.shape == (4, 4) and np.array_equal(e.transform[3], [0, 0, 0, 1]) for e in seen)
    np.testing.assert_array_equal(seen[-1].transform, result.transform)
    assert not np.allclose(seen[0].transform, np.eye(4))  # the first update already moved
    # One meaning of "inlier fraction": progress and summary agree at convergence.
    assert abs(seen[-1].inlier_fraction - result.summary.inlier_fraction) < 0.01
    np.testing.assert_array_equal(ctx.trace()[-1].transform, result.transform)
    # The automatic starts report every start's updates, numbered on; the result is the last
    # update of the start that won, one of them (here the paper's start alone: GOOD on its own
    # and a local correction of the guess, the search ends there).
    seen.clear()
    ctx.set_starts(sie.Starts.AUTOMATIC)
    result = ctx.align(source, target)
    assert result.summary.starts_run == 1 and result.summary.agreeing_starts == 1
    assert [e.iteration for e in seen] == list(range(1, result.summary.iterations + 1))
    assert any(np.array_equal(e.transform, result.transform) for e in seen)
    assert [e.iteration for e in ctx.trace()] == [e.iteration for e in seen]


def test_module_level_align(clouds):
    source, target, normals = clouds
    result = sie.align(source, target, max_iterations=150, threads=1)
    rotation, translation = pose_error(result.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    with_normals = sie.align(source, target, target_normals=normals)
    assert pose_error(with_normals.transform, TRUTH)[0] < 0.2
    with pytest.raises(TypeError, match="unknown setting"):
        sie.align(source, target, no_such_setting=1)


def test_float32_n_by_3_and_n_by_4_are_passed_in_place():
    packed = np.zeros((10, 3), dtype=np.float32)
    view = sie._points(packed, "a", np.float32)
    assert view.address == packed.ctypes.data and view.stride == 12
    padded = np.zeros((10, 4), dtype=np.float32)
    view = sie._points(padded, "a", np.float32)
    assert view.address == padded.ctypes.data and view.stride == 16
    columns = padded[:, :3]  # a view with stride 16
    view = sie._points(columns, "a", np.float32)
    assert view.address == padded.ctypes.data and view.stride == 16
    doubles = np.zeros((10, 3))
    assert sie._points(doubles, "a", np.float64).address == doubles.ctypes.data


def test_other_layouts_are_converted():
    fortran = np.asfortranarray(np.zeros((10, 3), dtype=np.float32))
    view = sie._points(fortran, "a", np.float32)
    assert view.address != fortran.ctypes.data and view.stride == 12
    as_list = sie._points([[1, 2, 3], [4, 5, 6]], "a", np.float64)
    assert as_list.count == 2 and as_list.array.dtype == np.float64
    with pytest.raises(ValueError, match="N x 3"):
        sie._points(np.zeros((5, 2)), "source", np.float64)


def test_cloud_registration_float32(clouds):
    source, target, _ = clouds
    with sie.Context() as ctx:
        result = ctx.align(source, target)
    rotation, translation = pose_error(result.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    s = result.summary
    assert s.converged and s.stop_reason is sie.StopReason.CONVERGED
    assert s.source_count == len(source) and 0 < s.iterations <= 200
    assert 0.0015 < s.sigma[0] < 0.006  # two scans with 2 mm noise: about 2.8 mm point-to-plane
    assert result.inlier_probabilities.shape == (len(source),)
    assert np.all((result.inlier_probabilities >= 0) & (result.inlier_probabilities <= 1))
    assert result.correspondences.dtype == np.int64 and result.correspondences.shape == (len(source),)
    assert result.correspondences.max() < len(target)
    # A clean, well-constrained scene: the evidence supports the pose.
    assert s.verdict is sie.Verdict.GOOD and str(s.verdict) == "Verdict.GOOD"
    assert s.significance > 100 and 1e-3 <= s.conditioning <= 1 and 0 < s.sigma_to_spacing <= 1
    assert s.starts_run == 1 and s.agreeing_starts == 1 and s.hypotheses == 0
    assert s.start in (sie.StartKind.INITIAL_GUESS, sie.StartKind.NARROW_BETA, sie.StartKind.SCALE_FREE_LEAD)
    assert s.margin >= 2 if s.runner_up_significance > 0 else s.margin == 0


def check_pose_uncertainty(result):
    """6 x 6 float64, symmetric, positive definite, covariance @ information = I (a
    well-constrained scene)."""
    covariance, information = result.covariance, result.information
    for matrix in (covariance, information):
        assert matrix.shape == (6, 6) and matrix.dtype == np.float64
        assert np.all(np.isfinite(matrix))
        assert np.abs(matrix - matrix.T).max() <= 1e-12 * np.abs(matrix).max()
        assert np.all(np.linalg.eigvalsh(matrix) > 0)
    np.testing.assert_allclose(covariance @ information, np.eye(6), rtol=0, atol=1e-9)


def test_pose_covariance_and_information(clouds):
    source, target, _ = clouds
    with sie.Context() as ctx:
        with pytest.raises(sie.SieError) as error:
            ctx.pose_uncertainty()
        assert error.value.status is sie.Status.NO_RESULT
        result = ctx.align(source, target)
        check_pose_uncertainty(result)
        covariance, information = ctx.pose_uncertainty()
        np.testing.assert_array_equal(covariance, result.covariance)
        np.testing.assert_array_equal(information, result.information)
        # The same clouds in millimetres: rotation (rad^2) unchanged, translation x 1e6.
        in_mm = ctx.align(source.astype(np.float64) * 1000.0, target.astype(np.float64) * 1000.0)
    in_m = sie.align(source.astype(np.float64), target.astype(np.float64))
    scale = np.array([1.0, 1.0, 1.0, 1000.0, 1000.0, 1000.0])
    for block in (slice(0, 3), slice(3, 6)):
        expected = (in_m.covariance * np.outer(scale, scale))[block, block]
        np.testing.assert_allclose(in_mm.covariance[block, block], expected, rtol=0,
                                   atol=1e-6 * np.abs(expected).max())


def skew(p):
    return np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]])


def test_pose_covariance_follows_the_documented_convention():
    """Correspondences far from the source frame's origin: the covariance is the inliers'
    least-squares one, sigma^2 (sum J^T J)^-1 with J = [-[T p]x, I] for the left perturbation
    T = Exp(d) T_hat, d = (rotation vector, translation) in the target frame (to 0.07 of its
    largest entry here, at most 0.22 over seeds 7-16: the sandwich estimate's own scatter).
    Read as the right perturbation in the source frame it is 15-20x off, with the translation
    first 0.99-1.16x off."""
    t0 = rigid(0.8, [1, 2, 3], [2.0, -1.0, 3.0])
    source, target = paper_simulation(500, 200, 0.01, t0, np.random.default_rng(7))
    result = sie.Context().align_correspondences(source, target)
    check_pose_uncertainty(result)
    moved = transform(result.transform, source[:500])
    jacobians = [np.hstack([-skew(p), np.eye(3)]) for p in moved]
    expected = 0.01**2 * np.linalg.inv(sum(J.T @ J for J in jacobians))
    difference = np.abs(result.covariance - expected).max() / np.abs(expected).max()
    assert difference < 0.4, (difference, result.covariance, expected)


def test_padded_float32_and_float64_agree(clouds):
    source, target, _ = clouds
    ctx = sie.Context()
    packed = ctx.align(source, target).transform
    padded_source = np.zeros((len(source), 4), dtype=np.float32)
    padded_source[:, :3] = source
    padded_target = np.zeros((len(target), 4), dtype=np.float32)
    padded_target[:, :3] = target
    # Same float data through stride 16: the same deterministic result.
    np.testing.assert_array_equal(ctx.align(padded_source, padded_target).transform, packed)
    as_double = ctx.align(source.astype(np.float64), target.astype(np.float64)).transform
    np.testing.assert_allclose(as_double, packed, atol=1e-6)


def test_prepared_target_gives_the_same_results_and_is_shared_by_threads(clouds):
    import threading

    source, target, normals = clouds
    ctx = sie.Context(threads=1)
    direct = ctx.align(source, target)
    prepared = ctx.prepare_target(target)
    assert len(prepared) == len(target)
    for _ in range(2):  # the second call reuses the normals the first estimated
        again = ctx.align(source, prepared)
        np.testing.assert_array_equal(again.transform, direct.transform)
        np.testing.assert_array_equal(again.correspondences, direct.correspondences)
        np.testing.assert_array_equal(again.inlier_probabilities, direct.inlier_probabilities)
    # Several contexts on several threads at once, onto one target built by sie.Target.
    shared = sie.Target(target)
    shared.estimate_normals(2)
    results = [None] * 4

    def run(k):
        with sie.Context(threads=1) as own:
            results[k] = own.align(source, shared).transform

    threads = [threading.Thread(target=run, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for transform in results:
        np.testing.assert_array_equal(transform, direct.transform)
    # Given normals and float64 take the same paths as align().
    with_normals = ctx.align(source, target, target_normals=normals)
    np.testing.assert_array_equal(ctx.align(source, ctx.prepare_target(target, normals)).transform,
                                  with_normals.transform)
    as_double = ctx.align(source.astype(np.float64), target.astype(np.float64))
    np.testing.assert_array_equal(
        ctx.align(source.astype(np.float64), sie.Target(target.astype(np.float64))).transform, as_double.transform)
    # Errors: normals twice, a closed target, a normal count that differs, a bad setting.
    with pytest.raises(ValueError, match="carries its normals"):
        ctx.align(source, prepared, target_normals=normals)
    with pytest.raises(ValueError, match="normals has 10 rows"):
        sie.Target(target, normals[:10])
    with pytest.raises(sie.SieError) as error:
        sie.Target(target, normal_neighbours=2)
    assert error.value.status is sie.Status.INVALID_ARGUMENT
    with pytest.raises(sie.SieError) as error:
        sie.Context(normal_neighbours=20).align(source, prepared)
    assert error.value.status is sie.Status.INVALID_ARGUMENT and "normal_neighbours" in str(error.value)
    prepared.close()
    with pytest.raises(sie.SieError) as error:
        ctx.align(source, prepared)
    assert error.value.status is sie.Status.NULL_ARGUMENT


def test_initial_guess_and_caller_normals(clouds):
    source, target, normals = clouds
    ctx = sie.Context(max_iterations=100)
    guess = rigid(0.05, [0.3, -0.2, 1.0], [0.05, 0, 0])
    result = ctx.align(source, target, init=guess)
    rotation, translation = pose_error(result.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    assert result.summary.init_correction < 1e-12
    # A guess printed with 4 decimals (orthonormal to ~5e-5, like published ground truths) is
    # accepted, made exactly rigid, and the correction reported.
    rounded = ctx.align(source, target, init=np.round(guess, 4))
    assert 1e-6 < rounded.summary.init_correction < 1e-4
    with_normals = ctx.align(source, target, target_normals=normals)
    rotation, translation = pose_error(with_normals.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    with pytest.raises(ValueError, match="rows for"):
        ctx.align(source, target, target_normals=normals[:-1])
    with pytest.raises(ValueError, match="4 x 4"):
        ctx.align(source, target, init=np.eye(3))


@pytest.mark.parametrize(
    "t0",
    [rigid(0.0, [1, 0, 0], [0.5, 0, 0]), rigid(np.pi / 2, [1, 0, 0], [0, 0, 0])],
    ids=["translation 0.5", "rotation pi/2"],
)
def test_paper_simulation_reaches_the_inlier_least_squares_fit(t0):
    noise = 0.01
    for seed in range(5):
        source, target = paper_simulation(1000, 1000, noise, t0, np.random.default_rng(100 + seed))
        result = sie.Context().align_correspondences(source, target)
        inliers = slice(0, 1000)
        mle = kabsch(source[inliers], target[inliers])
        excess = rms(result.transform, source[inliers], target[inliers]) - rms(mle, source[inliers], target[inliers])
        # The paper calls an error above the noise a failure; SIE lands on the MLE itself.
        assert result.summary.converged, seed
        assert excess < 1e-4, (seed, excess)
        p = result.inlier_probabilities
        assert p[:1000].mean() > 0.9 and p[1000:].mean() < 0.2
        np.testing.assert_array_equal(result.correspondences, np.arange(2000))


def test_starts_setting_and_the_search_report(clouds):
    source, target, _ = clouds
    one = sie.align(source, target, starts=sie.Starts.INITIAL_GUESS).summary
    # It travelled from the identity by a local correction with every direction fixed: one run.
    assert (one.starts_run, one.start, one.agreeing_starts) == (1, sie.StartKind.INITIAL_GUESS, 1)
    assert one.margin == 0 and one.runner_up_significance == 0 and one.verdict is sie.Verdict.GOOD
    # max_iterations caps each start; iterations counts them all.
    capped = sie.align(source, target, starts=sie.Starts.INITIAL_GUESS, max_iterations=4).summary
    assert capped.iterations == 4 and capped.stop_reason is sie.StopReason.ITERATION_LIMIT
    several = sie.align(source, target, max_iterations=4).summary
    assert several.starts_run == 3 and 4 < several.iterations <= 16
    with pytest.raises(sie.SieError) as error:
        sie.Context().set_starts(5)
    assert error.value.status is sie.Status.INVALID_ARGUMENT and "starts = 5" in error.value.message


def test_unrelated_pairs_are_unsupported():
    rng = np.random.default_rng(11)
    source, target = rng.uniform(-1, 1, (800, 3)), rng.uniform(-1, 1, (800, 3))
    s = sie.Context().align_correspondences(source, target).summary
    assert s.verdict is sie.Verdict.UNSUPPORTED and s.significance == 0
    assert s.hypotheses > 0 and s.sigma_to_spacing == 0
    # The paper's simulation, by contrast: the hypothesis search finds the inliers' pose.
    source, target = paper_simulation(500, 500, 0.01, rigid(1.2, [1, 0, 0], [0.5, 0, 0]), rng)
    s = sie.Context().align_correspondences(source, target).summary
    assert s.verdict is sie.Verdict.GOOD and s.hypotheses > 0 and s.significance > 0


def test_summary_struct_has_the_header_layout():
    # sie.h: 13 fields of 0.1, then verdict/start (u32), five doubles and three u32 (0.2).
    assert ctypes.sizeof(_native.sie_summary) == 184
    assert _native.sie_summary.verdict.offset == 120 and _native.sie_summary.significance.offset == 128
    assert _native.sie_summary.agreeing_starts.offset == 176
    assert sie.Verdict.UNSUPPORTED == 3 and sie.StartKind.HYPOTHESIS == 3 and sie.Starts.INITIAL_GUESS == 1


def test_correspondences_in_float32_and_unequal_counts():
    source, target = paper_simulation(500, 200, 0.01, rigid(0.3, [0, 0, 1], [0.1, 0, 0]), np.random.default_rng(1))
    result = sie.Context().align_correspondences(source.astype(np.float32), target.astype(np.float32))
    truth = np.linalg.inv(rigid(0.3, [0, 0, 1], [0.1, 0, 0]))
    rotation, translation = pose_error(result.transform, truth)
    assert rotation < 0.5 and translation < 0.01
    with pytest.raises(ValueError, match="equal counts"):
        sie.Context().align_correspondences(source, target[:-1])


def test_estimate_inliers():
    rng = np.random.default_rng(7)
    residuals = np.concatenate([rng.normal(0, 0.02, 10_000), rng.uniform(-1, 1, 3_000)])
    estimate = sie.Context().estimate_inliers(residuals)
    assert len(estimate.models) == 1 and estimate.models[0].peak_found
    assert abs(estimate.models[0].sigma - 0.02) < 0.002
    assert estimate.probabilities[:10_000].mean() > 0.9
    far = np.abs(residuals[10_000:]) > 0.2
    assert estimate.probabilities[10_000:][far].mean() < 0.01
    per_column = sie.Context(histogram_mode=sie.HistogramMode.PER_COLUMN).estimate_inliers(
        residuals[:12_000].reshape(-1, 3)
    )
    assert len(per_column.models) == 3 and per_column.probabilities.shape == (4_000,)


def test_histogram_and_trace(clouds):
    source, target, _ = clouds
    ctx = sie.Context(trace=True)
    result = ctx.align(source, target)
    trace = ctx.trace()
    assert len(trace) == result.summary.iterations
    assert [t.iteration for t in trace] == list(range(1, len(trace) + 1))
    histogram = ctx.histogram(0)
    assert histogram.model.bins == len(histogram.counts) == len(histogram.probability) > 0
    assert histogram.counts.sum() > 0


# ---- errors ------------------------------------------------------------------------------------


def test_errors_carry_status_and_message(clouds):
    source, target, _ = clouds
    ctx = sie.Context()
    with pytest.raises(sie.SieError) as error:
        ctx.summary()
    assert error.value.status is sie.Status.NO_RESULT
    with pytest.raises(sie.SieError) as error:
        ctx.set_max_iterations(0)
    assert error.value.status is sie.Status.INVALID_ARGUMENT and error.value.message
    bad = source.copy()
    bad[42, 1] = np.nan
    with pytest.raises(sie.SieError) as error:
        ctx.align(bad, target)
    assert error.value.status is sie.Status.NON_FINITE_INPUT
    assert "42" in error.value.message and "42" in str(error.value)
    with pytest.raises(sie.SieError) as error:
        ctx.align(source[:0], target)
    assert error.value.status is sie.Status.TOO_FEW_POINTS
    with pytest.raises(TypeError, match="unknown setting"):
        sie.Context(no_such_setting=1)


# ---- the noise callback -------------------------------------------------------------------------


def test_noise_callback_is_called_per_cloud(clouds):
    source, target, _ = clouds
    calls = []

    def depth_noise(cloud, xyz):
        calls.append((cloud, xyz.shape, xyz.flags.writeable))
        return 1.0 + xyz[:, 2] ** 2  # quadratic in depth, relative

    ctx = sie.Context()
    ctx.set_noise_callback(depth_noise)
    rotation, translation = pose_error(ctx.align(source, target).transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    assert sorted(calls) == [
        (sie.Cloud.SOURCE, (len(source), 3), False),
        (sie.Cloud.TARGET, (len(target), 3), False),
    ]
    ctx.set_noise_callback(None)
    calls.clear()
    ctx.align(source, target)
    assert calls == []


class CustomFailure(Exception):
    pass


def test_callback_exceptions_come_back_out(clouds):
    source, target, _ = clouds
    ctx = sie.Context()
    failure = CustomFailure("from the callback")

    def failing(cloud, xyz):
        raise failure

    ctx.set_noise_callback(failing)
    with pytest.raises(CustomFailure) as raised:
        ctx.align(source, target)
    assert raised.value is failure

    ctx.set_noise_callback(lambda cloud, xyz: np.ones(3))  # wrong length
    with pytest.raises(ValueError, match="expected"):
        ctx.align(source, target)

    ctx.set_noise_callback(lambda cloud, xyz: -np.ones(len(xyz)))  # rejected by the library
    with pytest.raises(sie.SieError) as error:
        ctx.align(source, target)
    assert error.value.status is sie.Status.CALLBACK_FAILED

    # A call on the busy context from inside the callback is refused with BUSY.
    def reentrant(cloud, xyz):
        ctx.set_seed(1)
        return np.ones(len(xyz))

    ctx.set_noise_callback(reentrant)
    with pytest.raises(sie.SieError) as error:
        ctx.align(source, target)
    assert error.value.status is sie.Status.BUSY

    # Still usable afterwards.
    ctx.set_noise_callback(None)
    assert ctx.align(source, target).summary.converged


# ---- progress, cancellation, non-finite points ---------------------------------------------------


def test_progress_callback_and_cancellation(clouds):
    source, target, _ = clouds
    ctx = sie.Context()
    seen = []
    ctx.set_progress_callback(lambda entry: seen.append(entry.iteration))
    full = ctx.align(source, target).summary
    assert full.converged and seen == list(range(1, full.iterations + 1))

    # Returning False cancels; that is a result (the transform so far), not an error.
    ctx.set_progress_callback(lambda entry: entry.iteration < 3)
    partial = ctx.align(source, target)
    assert partial.summary.stop_reason is sie.StopReason.CANCELLED
    assert partial.summary.iterations == 3 and not partial.summary.converged
    assert not np.allclose(partial.transform, np.eye(4))

    failure = CustomFailure("stop")

    def failing(entry):
        raise failure

    ctx.set_progress_callback(failing)
    with pytest.raises(CustomFailure) as raised:
        ctx.align(source, target)
    assert raised.value is failure
    ctx.set_progress_callback(None)

    # cancel() with nothing running: the next registration stops after one iteration, once.
    ctx.cancel()
    assert ctx.align(source, target).summary.stop_reason is sie.StopReason.CANCELLED
    assert ctx.summary().iterations == 1
    assert ctx.align(source, target).summary.converged


def test_skip_non_finite(clouds):
    source, target, _ = clouds
    bad = source.copy()
    bad[17] = np.nan
    result = sie.Context(skip_non_finite=True).align(bad, target)
    rotation, translation = pose_error(result.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    assert result.inlier_probabilities[17] == 0 and result.correspondences[17] == -1


# ---- real scans (skipped when the data folder is absent) -----------------------------------------

DATA = Path(os.environ.get("SIE_DATA_DIR", Path(__file__).resolve().parents[4] / "shared" / "data"))


def read_ascii_pcd(path):
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("DATA")) + 1
    return np.array([[float(v) for v in line.split()[:3]] for line in lines[start:] if line.strip()])


def read_binary_ply(path):
    """x y z of a binary little-endian PLY with one vertex element of scalar float/double properties."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    assert "format binary_little_endian 1.0" in header, header
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    types = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1", "int": "<i4"}
    fields = [(line.split()[2], types[line.split()[1]]) for line in header if line.startswith("property")]
    vertices = np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end)
    return np.c_[vertices["x"], vertices["y"], vertices["z"]].astype(np.float32)


def test_bunny_from_identity():
    folder = DATA / "pcl-test-bunny"
    if not (folder / "bun0.pcd").exists():
        pytest.skip(f"{folder} not present")
    source, target = read_ascii_pcd(folder / "bun0.pcd"), read_ascii_pcd(folder / "bun4.pcd")
    truth = np.array([  # bun000 -> bun045 from bun.conf (the folder README's preferred ground truth)
        [0.826351, 0.004137, -0.563141, 0.036838],
        [-0.0106, 0.99991, -0.00821, -0.000257],
        [0.563056, 0.012754, 0.82632, 0.038321],
        [0, 0, 0, 1],
    ])
    rotation, translation = pose_error(sie.Context().align(source, target).transform, truth)
    assert rotation < 1.0 and translation < 0.005


def test_lidar_pair_from_identity():
    folder = DATA / "small_gicp-data"
    if not (folder / "source.ply").exists():
        pytest.skip(f"{folder} not present")
    source, target = read_binary_ply(folder / "source.ply"), read_binary_ply(folder / "target.ply")
    truth = np.loadtxt(folder / "T_target_source.txt")
    result = sie.Context().align(source, target)
    rotation, translation = pose_error(result.transform, truth)
    assert rotation < 0.5 and translation < 0.05
    assert result.summary.stop_reason is not sie.StopReason.DEGENERATE


# ---- finding the library ------------------------------------------------------------------------


def _import_in_subprocess(environment):
    import subprocess
    import sys

    return subprocess.run(
        [sys.executable, "-c", "import sie; print(sie._lib._name)"],
        env=environment, capture_output=True, text=True, check=False,
    )


def test_library_search_order():
    loaded = Path(sie._lib._name)
    base = {k: v for k, v in os.environ.items() if k not in ("SIE_LIBRARY", "LD_LIBRARY_PATH")}
    # An explicit SIE_LIBRARY that does not exist is an error, not a silent fallback.
    missing = _import_in_subprocess({**base, "SIE_LIBRARY": f"/nonexistent/{_native.SONAME}"})
    assert missing.returncode != 0 and "libsie not found" in missing.stderr
    assert f"/nonexistent/{_native.SONAME}" in missing.stderr
    if loaded.is_absolute():
        # Without SIE_LIBRARY, the soname is found through the dynamic loader's path.
        found = _import_in_subprocess({**base, "LD_LIBRARY_PATH": str(loaded.parent)})
        assert found.returncode == 0, found.stderr
        assert found.stdout.strip() in (_native.SONAME, str(loaded))


def test_type_hints_serve_a_strict_mypy_user(tmp_path):
    """py.typed: mypy --strict on user code finds sie's hints (no missing-stubs error) and
    catches a misuse."""
    from conftest import require

    mypy = require("mypy.api")
    good = tmp_path / "good.py"
    good.write_text(
        "import numpy as np\n"
        "import sie\n\n\n"
        "def register(source: np.ndarray, target: np.ndarray) -> np.ndarray:\n"
        "    result: sie.Registration = sie.align(source, target, max_iterations=50)\n"
        "    reason: sie.StopReason = result.summary.stop_reason\n"
        "    verdict: sie.Verdict = result.summary.verdict\n"
        "    if verdict is not sie.Verdict.GOOD:\n"
        "        print(result.summary.significance, result.summary.margin)\n"
        "    print(reason, result.summary.sigma[0] + 1.0)\n"
        "    covariance: np.ndarray = result.covariance @ result.information\n"
        "    print(covariance.shape)\n"
        "    pairs: np.ndarray = result.correspondence_set\n"
        "    share: float = result.fitness + result.inlier_rmse\n"
        "    count: int = result.num_inliers + result.num_iterations + result.iterations\n"
        "    done: bool = result.converged\n"
        "    print(pairs.shape, share, count, done, result.H.shape, result.T_target_source.shape)\n"
        "    return result.transform\n"
    )
    cache = ["--cache-dir", str(tmp_path / "mypy-cache")]  # numpy's stubs analysed once
    out, err, status = mypy.run(["--strict", *cache, str(good)])
    assert status == 0, out + err
    bad = tmp_path / "bad.py"
    bad.write_text("import sie\n\nsigma: str = sie.Context().summary().sigma\n"
                   "inliers: str = sie.align([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]).num_inliers\n")
    out, err, status = mypy.run(["--strict", *cache, str(bad)])
    assert status == 1 and out.count("Incompatible types") == 2, out + err


def test_warm_start_from_a_previous_summary(clouds):
    source, target, _ = clouds
    ctx = sie.Context().set_threads(1)
    cold = ctx.align(source, target)
    assert cold.summary.start is not sie.StartKind.WARM_START
    ctx.set_warm_start(cold.summary)
    warm = ctx.align(source, target, cold.transform)
    assert warm.summary.start is sie.StartKind.WARM_START and warm.summary.starts_run == 1
    assert warm.summary.iterations < cold.summary.iterations
    rotation, translation = pose_error(warm.transform, TRUTH)
    assert rotation < 0.2 and translation < 0.004
    ctx.set_warm_start(None)
    assert ctx.align(source, target, cold.transform).summary.start is not sie.StartKind.WARM_START
    # A summary that is not GOOD clears the warm start: its successor runs cold.
    assert cold.summary.verdict is sie.Verdict.GOOD
    ctx.set_warm_start(dataclasses.replace(cold.summary, verdict=sie.Verdict.DOUBTFUL))
    assert ctx.align(source, target, cold.transform).summary.start is not sie.StartKind.WARM_START
    # A baseline's summary has no SIE model to start from.
    baseline = sie.Context().set_cost_function(sie.CostFunction.L2).align(source, target).summary
    with pytest.raises(sie.SieError) as error:
        ctx.set_warm_start(baseline)
    assert error.value.status is sie.Status.INVALID_ARGUMENT and "no SIE noise model" in error.value.message
