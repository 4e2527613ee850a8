//! The pose's covariance is calibrated: over many instances the mean normalised estimation
//! error squared, δᵀ·Cov⁻¹·δ with T̂ = Exp(δ)·T (rotation vector first), is close to 6, the
//! number of pose parameters; directions the data leave free get a variance far above the
//! constrained ones.
use nalgebra::{Matrix4, Matrix6, Rotation3, Vector6};
use rand::SeedableRng;
use rand::rngs::Xoshiro256PlusPlus;
use sie::geometry::{rotation_part, translation_part};
use sie::synthetic::{paper_simulation, random_motion};
use sie::{Hooks, RegistrationConfig, RegistrationResult, register_correspondences};

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
