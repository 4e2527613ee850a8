//! `sie_estimate_inliers` through the C ABI on the case: 10 000 one-dimensional
//! residuals, inliers N(0, 0.02), 30 % outliers uniform in [-1, 1].
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use sie::ffi::{
    sie_context_free, sie_context_new, sie_context_set_histogram_mode, sie_estimate_inliers,
    sie_histogram_mode, sie_model, sie_status,
};

const SIGMA: f64 = 0.02;

fn residuals(seed: u64) -> (Vec<f64>, Vec<bool>) {
    let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(seed);
    let noise = Normal::new(0.0, SIGMA).unwrap();
    (0..10_000)
        .map(|_| {
            if rng.random::<f64>() < 0.3 {
                (rng.random_range(-1.0..1.0), false)
            } else {
                (noise.sample(&mut rng), true)
            }
        })
        .unzip()
}

fn mean_where(values: &[f64], mask: &[bool], want: bool) -> f64 {
    let chosen: Vec<f64> = values
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m == want)
        .map(|(v, _)| *v)
        .collect();
    chosen.iter().sum::<f64>() / chosen.len() as f64
}

#[test]
fn estimate_inliers_recovers_sigma_and_separates_inliers() {
    for mode in [sie_histogram_mode::Pooled, sie_histogram_mode::PerColumn] {
        for seed in 0..5 {
            let (r, inlier) = residuals(seed);
            let mut probabilities = vec![-1.0; r.len()];
            let mut model = sie_model::default();
            let mut count = 0usize;
            // SAFETY: every pointer is valid for the lengths passed; the context is freed once.
            let status = unsafe {
                let ctx = sie_context_new();
                assert_eq!(sie_context_set_histogram_mode(ctx, mode as u32), sie_status::Ok);
                let status = sie_estimate_inliers(
                    ctx,
                    r.as_ptr(),
                    r.len(),
                    1,
                    std::ptr::null(),
                    0.0,
                    probabilities.as_mut_ptr(),
                    &mut model,
                    1,
                    &mut count,
                );
                sie_context_free(ctx);
                status
            };
            assert_eq!(status, sie_status::Ok);
            assert_eq!(count, 1);
            let (p_in, p_out) = (
                mean_where(&probabilities, &inlier, true),
                mean_where(&probabilities, &inlier, false),
            );
            println!(
                "{mode:?} seed {seed}: sigma {:.5} (true {SIGMA}), P inliers {p_in:.3}, P outliers {p_out:.3}",
                model.sigma
            );
            assert!((model.sigma - SIGMA).abs() < 0.1 * SIGMA, "sigma {}", model.sigma);
            assert!(p_in > 0.8, "inliers {p_in}");
            assert!(p_out < 0.2, "outliers {p_out}");
            assert!(model.peak_found);
            assert!(probabilities.iter().all(|p| (0.0..=1.0).contains(p)));
        }
    }
}
