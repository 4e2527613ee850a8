//! The pose's covariance and information through the C ABI (`sie_context_get_pose_uncertainty`):
//! the very matrices of the Rust API after every kind of registration, row-major, in the
//! caller's units, symmetric and inverse to each other where the data constrain the pose, and
//! with the directions a plane leaves free far looser than the ones it fixes.
mod common;
use common::c_context::Context;
use std::ptr::{null, null_mut};

use nalgebra::{Matrix4, Matrix6};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use sie::ffi::*;
use sie::synthetic::{paper_simulation, random_motion, room_scene};
use sie::{
    Hooks, Metric, Point, PoseUncertainty, RegistrationConfig, register_clouds, register_correspondences,
};

const SENTINEL: f64 = -12345.0;

impl Context {
    /// Sets the metric (the context's only setting these tests change).
    fn metric(&self, metric: Metric) -> &Self {
        let value = match metric {
            Metric::PointToPoint => sie_metric::PointToPoint,
            Metric::PointToPlane => sie_metric::PointToPlane,
        };
        // SAFETY: live context.
        assert_eq!(
            unsafe { sie_context_set_metric(self.0, value as u32) },
            sie_status::Ok
        );
        self
    }

    /// ICP on packed double clouds from the identity.
    fn register_clouds(&self, source: &[Point], target: &[Point]) -> Matrix4<f64> {
        let mut out = [SENTINEL; 16];
        let status = self.register(source, target, &mut out);
        assert_eq!(status, sie_status::Ok, "{}", self.last_error());
        Matrix4::from_row_slice(&out)
    }

    /// ICP onto a target prepared with `normals` (None: estimated), from the identity.
    fn register_to_prepared(
        &self,
        source: &[Point],
        target: &[Point],
        normals: Option<&[Point]>,
    ) -> Matrix4<f64> {
        let mut prepared = null_mut();
        let mut out = [SENTINEL; 16];
        // SAFETY: packed arrays of the given counts; `out` holds 16 doubles; the target is
        // freed once, after its last use.
        unsafe {
            let status = sie_context_prepare_target_d(
                self.0,
                target.as_ptr().cast(),
                target.len(),
                0,
                normals.map_or(null(), |n| n.as_ptr().cast()),
                0,
                &mut prepared,
            );
            assert_eq!(status, sie_status::Ok, "{}", self.last_error());
            let status = sie_context_register_to_d(
                self.0,
                source.as_ptr().cast(),
                source.len(),
                0,
                prepared,
                null(),
                out.as_mut_ptr(),
            );
            sie_target_free(prepared);
            assert_eq!(status, sie_status::Ok, "{}", self.last_error());
        }
        Matrix4::from_row_slice(&out)
    }

    fn register_pairs_ok(&self, source: &[Point], target: &[Point]) -> Matrix4<f64> {
        let mut out = [SENTINEL; 16];
        let status = self.register_pairs(source, target, &mut out);
        assert_eq!(status, sie_status::Ok, "{}", self.last_error());
        Matrix4::from_row_slice(&out)
    }

    /// Both matrices of the stored result, read row-major as C reads them.
    fn uncertainty(&self) -> PoseUncertainty {
        let mut covariance = [SENTINEL; 36];
        let mut information = [SENTINEL; 36];
        // SAFETY: two disjoint buffers of 36 doubles.
        let status = unsafe {
            sie_context_get_pose_uncertainty(self.0, covariance.as_mut_ptr(), information.as_mut_ptr())
        };
        assert_eq!(status, sie_status::Ok, "{}", self.last_error());
        PoseUncertainty {
            covariance: Matrix6::from_row_slice(&covariance),
            information: Matrix6::from_row_slice(&information),
        }
    }
}

fn config(metric: Metric) -> RegistrationConfig {
    RegistrationConfig {
        metric,
        ..RegistrationConfig::default()
    }
}

/// What a caller may rely on for a pose the data constrain: finite, symmetric, positive
/// definite, and the information its inverse.
fn assert_well_formed(u: &PoseUncertainty, what: &str) {
    let (c, i) = (&u.covariance, &u.information);
    assert!(c.iter().chain(i.iter()).all(|v| v.is_finite()), "{what}: {c} {i}");
    let asymmetry = |m: &Matrix6<f64>| (m - m.transpose()).abs().max() / m.abs().max();
    assert!(
        asymmetry(c) < 1e-12,
        "{what}: covariance asymmetry {:e}",
        asymmetry(c)
    );
    assert!(
        asymmetry(i) < 1e-12,
        "{what}: information asymmetry {:e}",
        asymmetry(i)
    );
    assert!(
        c.cholesky().is_some(),
        "{what}: covariance not positive definite: {c}"
    );
    assert!(
        i.cholesky().is_some(),
        "{what}: information not positive definite: {i}"
    );
    let product = c * i;
    assert!(
        (product - Matrix6::identity()).abs().max() < 1e-9,
        "{what}: covariance · information = {product}"
    );
}

/// The C ABI hands out the Rust API's matrices bit for bit, after ICP in both metrics, onto a
/// prepared target, and after a correspondence registration.
#[test]
fn c_abi_returns_the_rust_apis_matrices() {
    let scene = room_scene(2000, 0.01, 3);
    let ctx = Context::new();
    for metric in [Metric::PointToPlane, Metric::PointToPoint] {
        let rust = register_clouds(
            &scene.source,
            &scene.target,
            None,
            None,
            &config(metric),
            Hooks::default(),
        )
        .unwrap();
        let what = format!("room, {metric:?}");
        let transform = ctx.metric(metric).register_clouds(&scene.source, &scene.target);
        assert_eq!(transform, rust.transform, "{what}");
        assert_eq!(ctx.uncertainty(), rust.uncertainty, "{what}");
        assert_well_formed(&rust.uncertainty, &what);
        // Onto a prepared target: the same result again.
        ctx.register_to_prepared(&scene.source, &scene.target, None);
        assert_eq!(ctx.uncertainty(), rust.uncertainty, "{what}, prepared target");
    }

    let mut rng = Xoshiro256PlusPlus::seed_from_u64(29);
    let truth = random_motion(&mut rng, 0.5, 0.3);
    let pairs = paper_simulation(1000, 500, 0.01, &truth, 4);
    let rust = register_correspondences(
        &pairs.source,
        &pairs.target,
        None,
        &RegistrationConfig::default(),
        Hooks::default(),
    )
    .unwrap();
    ctx.register_pairs_ok(&pairs.source, &pairs.target);
    assert_eq!(ctx.uncertainty(), rust.uncertainty, "correspondences");
    assert_well_formed(&rust.uncertainty, "correspondences");
}

/// Correspondences far from the source frame's origin: the matrices are the inliers'
/// least-squares covariance σ²·(Σ JᵀJ)⁻¹ with J = [−[T·p]×  I], the left perturbation
/// T = Exp(δ)·T̂ with δ = (rotation vector, translation) in the target frame, as documented (to
/// 0.09 of the largest entry here, at most 0.13 over seeds 7–16: the sandwich estimate's own
/// scatter). Read as the right perturbation in the source frame it is 14–18× off, with the
/// translation first 0.96–1.10× off.
#[test]
fn covariance_is_the_documented_left_perturbation_in_the_target_frame() {
    let rotation = nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(nalgebra::Vector3::new(1.0, 2.0, 3.0)),
        0.8,
    );
    let t0 = nalgebra::Isometry3::from_parts(nalgebra::Translation3::new(2.0, -1.0, 3.0), rotation.into())
        .to_homogeneous();
    let pairs = paper_simulation(500, 200, 0.01, &t0, 7);
    let ctx = Context::new();
    let transform = ctx.register_pairs_ok(&pairs.source, &pairs.target);
    let u = ctx.uncertainty();
    assert_well_formed(&u, "pairs");
    let mut normal = Matrix6::zeros();
    for p in &pairs.source[..500] {
        let moved = transform.transform_point(&nalgebra::Point3::from(*p)).coords;
        let mut jacobian = nalgebra::Matrix3x6::zeros();
        jacobian
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-moved.cross_matrix()));
        jacobian
            .fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&nalgebra::Matrix3::identity());
        normal += jacobian.transpose() * jacobian;
    }
    let expected = normal.try_inverse().unwrap() * (0.01 * 0.01);
    let difference = (u.covariance - expected).abs().max() / expected.abs().max();
    println!("covariance off the least-squares one by {difference:.3} of its largest entry");
    assert!(difference < 0.4, "{} {expected}", u.covariance);
}

/// The variances' diagonal: rotation first (rad²), then translation (length²).
fn variances(u: &PoseUncertainty) -> [f64; 6] {
    std::array::from_fn(|k| u.covariance[(k, k)])
}

fn scientific(values: &[f64]) -> String {
    let values: Vec<String> = values.iter().map(|v| format!("{v:.4e}")).collect();
    values.join(" ")
}

/// A 2 m × 2 m patch of the plane z = 0, ±`roughness`/2 off it: two independent samplings, the
/// source shifted by (2, −1, 3) cm.
fn plane_patch(roughness: f64, seed: u64) -> (Vec<Point>, Vec<Point>) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut sample = |n: usize, shift: Point| -> Vec<Point> {
        (0..n)
            .map(|_| {
                [
                    rng.random::<f64>() * 2.0 + shift[0],
                    rng.random::<f64>() * 2.0 + shift[1],
                    (rng.random::<f64>() - 0.5) * roughness + shift[2],
                ]
            })
            .collect()
    };
    let target = sample(1500, [0.0; 3]);
    let source = sample(1500, [0.02, -0.01, 0.03]);
    (source, target)
}

/// Point-to-plane on one plane fixes the rotations about x and y and the translation along z;
/// the rotation about z and the translations along x and y are free. Through the C ABI: with
/// the plane's normals given, their variances are ≥ 10⁶× every constrained one (2.9·10¹¹ here)
/// and their information ≤ 10⁻⁶ of it; with normals estimated from the points still ≥ 100×
/// (6.9·10³ here, about (spacing / roughness)², as the normals' scatter holds the sliding).
#[test]
fn a_plane_leaves_its_free_directions_loose() {
    const FREE: [usize; 3] = [2, 3, 4];
    const FIXED: [usize; 3] = [0, 1, 5];
    let ratio = |u: &PoseUncertainty| {
        let v = variances(u);
        let loosest_fixed = FIXED.iter().map(|&k| v[k]).fold(0.0, f64::max);
        FREE.iter()
            .map(|&k| v[k] / loosest_fixed)
            .fold(f64::INFINITY, f64::min)
    };
    // Given normals: the free directions are exactly free.
    let (source, target) = plane_patch(0.002, 5);
    let normals = vec![[0.0, 0.0, 1.0]; target.len()];
    let ctx = Context::new();
    let transform = ctx.register_to_prepared(&source, &target, Some(&normals));
    assert!((transform[(2, 3)] + 0.03).abs() < 1e-3, "tz {transform}");
    let given = ctx.uncertainty();
    println!(
        "given normals: variances {}, ratio {:.3e}",
        scientific(&variances(&given)),
        ratio(&given)
    );
    assert!(ratio(&given) >= 1e6, "{}", given.covariance);
    let information = &given.information;
    for free in FREE {
        for fixed in FIXED {
            assert!(
                information[(free, free)].abs() < 1e-6 * information[(fixed, fixed)],
                "{free} {fixed}: {information}"
            );
        }
    }

    // Estimated normals (0.6 mm RMS roughness, 5 cm spacing).
    let estimated = {
        ctx.register_clouds(&source, &target);
        ctx.uncertainty()
    };
    println!(
        "estimated normals: variances {}, ratio {:.3e}",
        scientific(&variances(&estimated)),
        ratio(&estimated)
    );
    assert!(ratio(&estimated) >= 100.0, "{}", estimated.covariance);
}

/// The same scene in millimetres instead of metres: rotation variances unchanged,
/// rotation–translation covariances × 1000, translation variances × 10⁶ (and the information
/// the inverse scaling), though the library normalises the clouds internally.
#[test]
fn matrices_are_in_the_callers_units() {
    let scene = room_scene(2000, 0.01, 3);
    let millimetres =
        |points: &[Point]| -> Vec<Point> { points.iter().map(|p| p.map(|c| c * 1000.0)).collect() };
    let ctx = Context::new();
    for metric in [Metric::PointToPlane, Metric::PointToPoint] {
        ctx.metric(metric).register_clouds(&scene.source, &scene.target);
        let metres = ctx.uncertainty();
        ctx.register_clouds(&millimetres(&scene.source), &millimetres(&scene.target));
        let scaled = ctx.uncertainty();
        let factor = |r: usize| if r < 3 { 1.0 } else { 1000.0 };
        let expected_covariance = Matrix6::from_fn(|r, c| metres.covariance[(r, c)] * factor(r) * factor(c));
        let expected_information =
            Matrix6::from_fn(|r, c| metres.information[(r, c)] / (factor(r) * factor(c)));
        // Compared entry by entry against the entry's block scale, which rounding in another
        // unit cannot exceed by more than a registration's own rounding.
        for r in 0..6 {
            for c in 0..6 {
                let block = |m: &Matrix6<f64>| {
                    let rows = if r < 3 { 0..3 } else { 3..6 };
                    let cols = if c < 3 { 0..3 } else { 3..6 };
                    rows.flat_map(|i| cols.clone().map(move |j| (i, j)))
                        .map(|(i, j)| m[(i, j)].abs())
                        .fold(0.0, f64::max)
                };
                let (got, want) = (scaled.covariance[(r, c)], expected_covariance[(r, c)]);
                assert!(
                    (got - want).abs() <= 1e-6 * block(&expected_covariance),
                    "{metric:?} covariance ({r}, {c}): {got:e} in mm, {want:e} expected"
                );
                let (got, want) = (scaled.information[(r, c)], expected_information[(r, c)]);
                assert!(
                    (got - want).abs() <= 1e-6 * block(&expected_information),
                    "{metric:?} information ({r}, {c}): {got:e} in mm, {want:e} expected"
                );
            }
        }
        println!(
            "{metric:?}: variances in m {}, in mm {}",
            scientific(&variances(&metres)),
            scientific(&variances(&scaled))
        );
    }
}

/// On a live context: nothing to read before a registration and after a failed one, and a
/// refused call leaves both buffers as they were.
#[test]
fn refusals_on_a_live_context_write_nothing() {
    let ctx = Context::new();
    let mut covariance = [SENTINEL; 36];
    let mut information = [SENTINEL; 36];
    // SAFETY (all calls): live context, buffers of 36 doubles or NULL.
    let read = |covariance: *mut f64, information: *mut f64| unsafe {
        sie_context_get_pose_uncertainty(ctx.0, covariance, information)
    };
    assert_eq!(
        read(covariance.as_mut_ptr(), information.as_mut_ptr()),
        sie_status::NoResult
    );
    let pairs = paper_simulation(200, 50, 0.01, &Matrix4::identity(), 1);
    ctx.register_pairs_ok(&pairs.source, &pairs.target);
    assert_eq!(read(null_mut(), null_mut()), sie_status::NullArgument);
    assert!(ctx.last_error().contains("out_covariance and out_information"));
    assert_eq!(
        read(covariance.as_mut_ptr(), covariance.as_mut_ptr()),
        sie_status::InvalidArgument
    );
    assert_eq!((covariance, information), ([SENTINEL; 36], [SENTINEL; 36]));
    assert_eq!(read(null_mut(), information.as_mut_ptr()), sie_status::Ok);
    assert_eq!(covariance, [SENTINEL; 36]);
    assert_ne!(information, [SENTINEL; 36]);

    // A failed registration drops the stored result.
    let mut out = [SENTINEL; 16];
    // SAFETY: a NULL source is reported; `out` holds 16 doubles.
    let status = unsafe {
        sie_context_register_correspondences_d(ctx.0, null(), 0, null(), 0, 10, null(), out.as_mut_ptr())
    };
    assert_eq!(status, sie_status::NullArgument);
    let before = information;
    assert_eq!(
        read(covariance.as_mut_ptr(), information.as_mut_ptr()),
        sie_status::NoResult
    );
    assert_eq!((covariance, information), ([SENTINEL; 36], before));
    // SAFETY: a NULL context is reported before anything is touched.
    let status = unsafe { sie_context_get_pose_uncertainty(null(), covariance.as_mut_ptr(), null_mut()) };
    assert_eq!(status, sie_status::NullArgument);
    assert_eq!(covariance, [SENTINEL; 36]);
}
