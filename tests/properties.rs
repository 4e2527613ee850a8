//! Property tests of the core: probabilities stay in [0, 1] for any residual matrix, every
//! returned transform is a proper rotation, and results follow a rigid change of both frames.
use nalgebra::{Matrix3, Matrix4, Rotation3, Translation3};
use proptest::prelude::*;
use rand::SeedableRng;
use sie::geometry::{rotation_part, transform_point, weighted_rigid_fit};
use sie::synthetic::{paper_simulation, random_motion, room_scene};
use sie::{
    CostFunction, HistogramMode, Hooks, Metric, NoiseShape, Point, RegistrationConfig, SieOptions, Verdict,
    estimate_inliers, register_clouds, register_correspondences,
};

fn is_proper_rotation(t: &Matrix4<f64>) -> bool {
    let r = rotation_part(t);
    let orthonormal = (r.transpose() * r - Matrix3::identity()).abs().max() < 1e-9;
    let bottom = t.row(3).iter().zip([0.0, 0.0, 0.0, 1.0]).all(|(a, b)| *a == b);
    orthonormal && (r.determinant() - 1.0).abs() < 1e-9 && bottom && t.iter().all(|v| v.is_finite())
}

fn rigid(rx: f64, ry: f64, rz: f64, tx: f64, ty: f64, tz: f64) -> Matrix4<f64> {
    Translation3::new(tx, ty, tz).to_homogeneous() * Rotation3::from_euler_angles(rx, ry, rz).to_homogeneous()
}

fn options(pooled: bool, shape: u8) -> SieOptions {
    SieOptions {
        histogram: if pooled {
            HistogramMode::Pooled
        } else {
            HistogramMode::PerColumn
        },
        noise_shape: match shape {
            0 => NoiseShape::Fixed(2.0),
            1 => NoiseShape::Fixed(1.0),
            _ => NoiseShape::Estimated,
        },
        ..SieOptions::default()
    }
}

/// `cases` cases from a fixed seed: the same inputs on every run, so CI cannot fail at random
/// (proptest's default seed is new each run; a failure found that way is kept in
/// properties.proptest-regressions and replayed first).
fn fixed_cases(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5e1e_2026),
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(fixed_cases(64))]

    /// Any finite residual matrix (any scale, ties, one or many columns) gives probabilities
    /// in [0, 1] and a finite model.
    #[test]
    fn probabilities_are_in_unit_interval(
        values in prop::collection::vec(prop_oneof![
            -1e3..1e3f64,
            -1e-6..1e-6f64,
            Just(0.0),
            Just(0.5),
        ], 1..600),
        cols in 1usize..4,
        pooled in any::<bool>(),
        shape in 0u8..3,
        beta in prop_oneof![Just(0.0), 0.0..10.0f64],
    ) {
        let rows = values.len() / cols;
        prop_assume!(rows >= 1);
        let residuals = &values[..rows * cols];
        let outcome = estimate_inliers(residuals, cols, None, beta, &options(pooled, shape));
        // Too few rows to fit a histogram is an error, not probabilities at their cap.
        if rows < sie::MIN_ESTIMATE_ROWS {
            prop_assert!(matches!(outcome, Err(sie::Error::TooFewPoints(_))));
            return Ok(());
        }
        let estimate = outcome.unwrap();
        prop_assert_eq!(estimate.probabilities.len(), rows);
        prop_assert!(estimate.probabilities.iter().all(|p| (0.0..=1.0).contains(p)));
        prop_assert!((0.0..=1.0).contains(&estimate.prior));
        for m in &estimate.models {
            prop_assert!(m.inlier.sigma.is_finite() && m.inlier.alpha.is_finite() && m.inlier.p.is_finite());
            prop_assert!(m.probability.iter().all(|p| (0.0..=1.0).contains(p)));
        }
    }
}

proptest! {
    #![proptest_config(fixed_cases(24))]

    /// Whatever the data and the cost, the transform is a proper rotation (det +1,
    /// orthonormal to 1e-9) with last row 0 0 0 1.
    #[test]
    fn transforms_are_proper_rotations(
        points in prop::collection::vec(prop::array::uniform3(-5.0..5.0f64), 3..80),
        targets in prop::collection::vec(prop::array::uniform3(-5.0..5.0f64), 3..80),
        cost in 0usize..4,
        max_iterations in 1u32..40,
    ) {
        let n = points.len().min(targets.len());
        let cost = [
            CostFunction::Sie,
            CostFunction::L2,
            CostFunction::Lp { p: 0.1 },
            CostFunction::StudentT { dof: 5.0 },
        ][cost];
        let config = RegistrationConfig { cost, max_iterations, ..RegistrationConfig::default() };
        let pairs = register_correspondences(&points[..n], &targets[..n], None, &config, Hooks::default()).unwrap();
        prop_assert!(is_proper_rotation(&pairs.transform), "{}", pairs.transform);
        for metric in [Metric::PointToPoint, Metric::PointToPlane] {
            let config = RegistrationConfig { metric, ..config.clone() };
            let clouds = register_clouds(&points, &targets, None, None, &config, Hooks::default()).unwrap();
            prop_assert!(is_proper_rotation(&clouds.transform), "{metric:?}: {}", clouds.transform);
            prop_assert!(clouds.probabilities.iter().all(|p| (0.0..=1.0).contains(p)));
        }
    }
}

fn moved(points: &[Point], g: &Matrix4<f64>) -> Vec<Point> {
    points.iter().map(|p| transform_point(g, p)).collect()
}

/// Point-to-plane ICP of the room scene of `seed` in its own frame and in frame `g`: the largest
/// difference of the two results (compared back in the scene's frame: G's lever arm, up to
/// 170 m, would turn a rotation difference far inside the precision into a translation
/// difference outside it), the pose's statistical precision σ/√n, and whether both stopped
/// for the same reason.
fn frame_change_difference(g: &Matrix4<f64>, seed: u64) -> (f64, f64, bool) {
    let scene = room_scene(1500, 0.01, seed);
    let config = RegistrationConfig {
        metric: Metric::PointToPlane,
        ..RegistrationConfig::default()
    };
    let here = register_clouds(
        &scene.source,
        &scene.target,
        None,
        None,
        &config,
        Hooks::default(),
    )
    .unwrap();
    let (source, target) = (moved(&scene.source, g), moved(&scene.target, g));
    // The initial guess follows the frame change too (identity becomes G·I·G⁻¹ = I).
    let there = register_clouds(&source, &target, None, None, &config, Hooks::default()).unwrap();
    let back = g.try_inverse().unwrap() * there.transform * g;
    let error = (back - here.transform).abs().max();
    let precision = here.sigma[0] / (scene.source.len() as f64).sqrt();
    (error, precision, here.stop_reason == there.stop_reason)
}

proptest! {
    #![proptest_config(fixed_cases(8))]

    /// Expressing both clouds in another frame G gives T' = G·T·G⁻¹ (point-to-plane ICP: the
    /// plane distance and PCA normals do not depend on the frame). Up to rounding, which
    /// usually leaves 1e-8 (40 random frames: at most 4e-8 in G's frame); but rounding can
    /// tip one of the fit's discrete choices (which bin a residual falls in, which match is
    /// cached), and then the fitted σ and the IRLS fixed point move a little (the replayed
    /// case: σ 1.4 % apart, the transforms 2.2e-5, 5 % of the pose's statistical precision
    /// σ/√n). Hence the bound: a quarter of that precision. G turns about the origin: the
    /// normals take the origin for the sensor (their orientation, and whether a line-like
    /// neighbourhood's smallest spread lies across the line of sight, `normals`), so a frame
    /// change that moves the sensor is the next test's.
    #[test]
    fn point_to_plane_icp_follows_a_turn_about_the_sensor(
        angles in prop::array::uniform3(-3.0..3.0f64),
        seed in 0u64..1000,
    ) {
        let g = rigid(angles[0], angles[1], angles[2], 0.0, 0.0, 0.0);
        let (error, precision, same_stop) = frame_change_difference(&g, seed);
        prop_assert!(error < 0.25 * precision, "frame change moved the result by {error} (precision {precision})");
        prop_assert!(same_stop);
    }

    /// A frame change that moves the sensor (the origin) by up to 170 m: the line-like
    /// neighbourhoods whose smallest spread lies across the line of sight are judged from
    /// another viewpoint, so a few normals differ (on this room's random samples, widened or
    /// not). The result stays within its statistical precision's order: 3 × σ/√n.
    #[test]
    fn point_to_plane_icp_follows_a_change_of_frame(
        angles in prop::array::uniform3(-3.0..3.0f64),
        shift in prop::array::uniform3(-100.0..100.0f64),
        seed in 0u64..1000,
    ) {
        let g = rigid(angles[0], angles[1], angles[2], shift[0], shift[1], shift[2]);
        let (error, precision, _) = frame_change_difference(&g, seed);
        prop_assert!(error < 3.0 * precision, "frame change moved the result by {error} (precision {precision})");
    }

    /// Correspondences with SIE: a translation of both frames changes nothing but the
    /// translation; a rotation changes the per-axis histograms' samples (the pooled histogram
    /// is of x, y, z components), so the result agrees only to well within the noise.
    #[test]
    fn correspondence_registration_follows_a_change_of_frame(
        angles in prop::array::uniform3(-3.0..3.0f64),
        shift in prop::array::uniform3(-100.0..100.0f64),
        seed in 0u64..1000,
    ) {
        let t0 = rigid(0.3, 0.0, 0.0, 0.2, 0.0, 0.0);
        let data = paper_simulation(1000, 1000, 0.01, &t0, seed);
        let config = RegistrationConfig::default();
        let here = register_correspondences(&data.source, &data.target, None, &config, Hooks::default()).unwrap();
        let truth_error = (here.transform - t0.try_inverse().unwrap()).abs().max();
        prop_assert!(truth_error < 0.01, "seed {seed}: error against the truth {truth_error}");
        let translate = rigid(0.0, 0.0, 0.0, shift[0], shift[1], shift[2]);
        let full = rigid(angles[0], angles[1], angles[2], shift[0], shift[1], shift[2]);
        for (g, tolerance) in [(translate, 1e-6), (full, 2e-3)] {
            let there = register_correspondences(
                &moved(&data.source, &g),
                &moved(&data.target, &g),
                None,
                &config,
                Hooks::default(),
            )
            .unwrap();
            let expected = g * here.transform * g.try_inverse().unwrap();
            let rotation = (rotation_part(&there.transform) - rotation_part(&expected)).abs().max();
            // Compare translations at the data (the origin is up to 170 units away).
            let at_data = there.transform * g.column(3) - expected * g.column(3);
            let error = rotation.max(at_data.abs().max());
            prop_assert!(error < tolerance, "error {error} (tolerance {tolerance})");
        }
    }
}

proptest! {
    #![proptest_config(fixed_cases(32))]

    /// The paper's protocol with 1000 outliers, beyond its one-axis grid: a rotation up to π
    /// about any axis combined with a translation up to 1 in any direction. SIE with no
    /// parameter recovers the inliers' least-squares fit (error above it < 1e-5, far below the
    /// failure bound of the noise, 0.01).
    #[test]
    fn correspondences_any_motion_with_as_many_outliers_as_inliers(
        angle in 0.0..std::f64::consts::PI,
        shift in 0.0..1.0f64,
        seed in 0u64..1_000_000,
    ) {
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(seed);
        let t0 = random_motion(&mut rng, angle, shift);
        let data = paper_simulation(1000, 1000, 0.01, &t0, seed);
        let result = register_correspondences(&data.source, &data.target, None, &RegistrationConfig::default(), Hooks::default()).unwrap();
        let inliers: Vec<(Point, Point)> = (0..1000).map(|i| (data.source[i], data.target[i])).collect();
        let rms = |t: &Matrix4<f64>| {
            (inliers.iter().map(|(a, b)| {
                let p = transform_point(t, a);
                (p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2)
            }).sum::<f64>() / 1000.0).sqrt()
        };
        let best = weighted_rigid_fit(&inliers, &[1.0; 1000]).unwrap().transform;
        let error = rms(&result.transform) - rms(&best);
        // Rarely the pooled histogram's fit settles at a second fixed point, σ ≈ 0.4 of the
        // true one (k = P(I|H)^-3 then holds it there): the pose stays within 3e-5 of the fit,
        // a thirtieth of its standard error, and the verdict says it is not good.
        prop_assert!(error < 1e-4, "angle {angle}, shift {shift}, seed {seed}: error {error}");
        prop_assert!(
            error < 1e-5 || result.quality.verdict != Verdict::Good,
            "angle {angle}, shift {shift}, seed {seed}: error {error} called good"
        );
        prop_assert!(is_proper_rotation(&result.transform));
    }
}
