//! The pose's covariance is calibrated: over many instances the mean normalised estimation
//! error squared, δᵀ·Cov⁻¹·δ with T̂ = Exp(δ)·T (rotation vector first), is close to 6, the
//! number of pose parameters; directions the data leave free get a variance far above the
//! constrained ones.
use nalgebra::{Matrix4, Matrix6, Rotation3, Vector6};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use sie::geometry::{rotation_part, transform_point, translation_part};
use sie::synthetic::{paper_simulation, random_motion, room_scene};
use sie::{
    Hooks, Metric, Point, RegistrationConfig, RegistrationResult, register_clouds, register_correspondences,
};

/// δ with T̂ = Exp(δ)·T to first order: the rotation vector of R̂·Rᵀ, then the translation of
/// T̂·T⁻¹.
fn error(estimate: &Matrix4<f64>, truth: &Matrix4<f64>) -> Vector6<f64> {
    let difference = estimate * truth.try_inverse().expect("rigid");
    let rotation = Rotation3::from_matrix_unchecked(rotation_part(&difference)).scaled_axis();
    let translation = translation_part(&difference);
    Vector6::new(
        rotation.x,
        rotation.y,
        rotation.z,
        translation.x,
        translation.y,
        translation.z,
    )
}

fn nees(result: &RegistrationResult, truth: &Matrix4<f64>) -> f64 {
    let delta = error(&result.transform, truth);
    let information: Matrix6<f64> = result
        .uncertainty
        .covariance
        .try_inverse()
        .expect("covariance invertible");
    (delta.transpose() * information * delta)[(0, 0)]
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

/// The paper's simulation (1000 inliers with σ = 0.01 per axis, 100 or 1000 outliers), a
/// random motion of up to 30° and 0.3 each: 200 instances.
#[test]
fn correspondence_covariance_is_calibrated() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(29);
    for outliers in [100, 1000] {
        let values: Vec<f64> = (0..200)
            .map(|seed| {
                let t0 = random_motion(&mut rng, 0.5, 0.3);
                let data = paper_simulation(1000, outliers, 0.01, &t0, seed);
                let result = register_correspondences(
                    &data.source,
                    &data.target,
                    None,
                    &RegistrationConfig::default(),
                    Hooks::default(),
                )
                .unwrap();
                nees(&result, &t0.try_inverse().unwrap())
            })
            .collect();
        let m = mean(&values);
        println!("{outliers} outliers: mean NEES {m:.3} (6 expected)");
        assert!(
            (0.8 * 6.0..=1.25 * 6.0).contains(&m),
            "{outliers} outliers: mean NEES {m}"
        );
    }
}

/// ICP of the synthetic room (2 000 points a cloud, σ = 0.01 per axis, source and target
/// sampled apart), each metric from the truth moved by 1° and 3 cm: 200 instances (on one
/// thread: at this size more only wait for each other).
#[test]
fn icp_covariance_is_calibrated_on_the_room() {
    for metric in [Metric::PointToPlane, Metric::PointToPoint] {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(2929);
        let config = RegistrationConfig {
            metric,
            threads: 1,
            ..RegistrationConfig::default()
        };
        let values: Vec<f64> = (0..200)
            .map(|seed| {
                let scene = room_scene(2_000, 0.01, 1_000 + seed);
                let truth = scene.t_target_source;
                let init = random_motion(&mut rng, 1f64.to_radians(), 0.03) * truth;
                let result = register_clouds(
                    &scene.source,
                    &scene.target,
                    None,
                    Some(&init),
                    &config,
                    Hooks::default(),
                )
                .unwrap();
                nees(&result, &truth)
            })
            .collect();
        let m = mean(&values);
        println!("{metric:?}: mean NEES {m:.3} (6 expected)");
        assert!((0.8 * 6.0..=1.25 * 6.0).contains(&m), "{metric:?}: mean NEES {m}");
    }
}

/// `count` points uniform by area on a corridor along x (floor z = 0 and walls y = ±1, 4 m
/// long and 2 m high) with N(0, σ²) noise per axis.
fn corridor(count: usize, sigma: f64, rng: &mut Xoshiro256PlusPlus) -> Vec<Point> {
    let noise = Normal::new(0.0, sigma).unwrap();
    (0..count)
        .map(|_| {
            let (x, a) = (rng.random_range(0.0..4.0), rng.random_range(-1.0..1.0f64));
            // Three faces of equal area: the floor, then either wall.
            let p = match rng.random_range(0..3) {
                0 => [x, a, 0.0],
                1 => [x, -1.0, a + 1.0],
                _ => [x, 1.0, a + 1.0],
            };
            p.map(|c| c + noise.sample(rng))
        })
        .collect()
}

/// A corridor fixes every direction but the translation along it: its variance is at least
/// 100 times the constrained translations', in both metrics.
#[test]
fn a_corridor_leaves_its_axis_free() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(31);
    let target = corridor(3_000, 0.005, &mut rng);
    let truth = random_motion(&mut rng, 2f64.to_radians(), 0.05);
    let inverse = truth.try_inverse().unwrap();
    let source: Vec<Point> = corridor(3_000, 0.005, &mut rng)
        .iter()
        .map(|p| transform_point(&inverse, p))
        .collect();
    for metric in [Metric::PointToPlane, Metric::PointToPoint] {
        let config = RegistrationConfig {
            metric,
            ..RegistrationConfig::default()
        };
        let result =
            register_clouds(&source, &target, None, Some(&truth), &config, Hooks::default()).unwrap();
        let variance = |k: usize| result.uncertainty.covariance[(k, k)];
        let constrained = variance(4).max(variance(5));
        println!(
            "{metric:?}: translation variances {:.2e} {:.2e} {:.2e}",
            variance(3),
            variance(4),
            variance(5)
        );
        assert!(constrained > 0.0, "{metric:?}");
        assert!(
            variance(3) >= 100.0 * constrained,
            "{metric:?}: {} vs {constrained}",
            variance(3)
        );
    }
}
