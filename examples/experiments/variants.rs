//! A second, minimal IRLS + SIE driver for correspondences, built only on the library's public
//! estimator (`SieEstimator`) and weighted Kabsch, to try a change to the annealing without
//! touching the core: with `hold_broad_jumps`, a fit whose σ jumps above the previous fit's
//! σ + β while β is annealed is rejected and the previous model kept for that iteration.
//!
//! Why: on the 10 000-outlier rotation cells the failing runs show σ flipping between a
//! narrow peak (~0.06) and the flat outlier plateau (~0.45) on alternate iterations while β is
//! already small; each broad fit gives every outlier weight and pulls T back toward the
//! outliers' own optimum (the identity). σ + β of the previous level bounds the inliers' scale,
//! so a jump above it is the plateau, not the inliers.
use nalgebra::Matrix4;
use sie::geometry::{transform_point, weighted_rigid_fit};
use sie::synthetic::Correspondences;
use sie::{Point, SieEstimator, SieOptions};

/// Mirrors the library driver's constants (src/sie/schedule.rs and `RegistrationConfig::default`).
const LEVEL_TOLERANCE: f64 = 0.01;
const MAX_LEVEL_ITERATIONS: u32 = 5;
const BETA_SHRINK: f64 = 0.5;
const BETA_STOP_RATIO: f64 = 0.01;
const MAX_ITERATIONS: u32 = 300;
const TOLERANCE: f64 = 1e-6;

/// Registers the pairs of `data` from the identity; returns T_target_source.
pub fn register(data: &Correspondences, hold_broad_jumps: bool) -> Matrix4<f64> {
    let pairs: Vec<(Point, Point)> = data
        .source
        .iter()
        .copied()
        .zip(data.target.iter().copied())
        .collect();
    let n = pairs.len();
    let mut t = Matrix4::identity();
    let mut estimator = SieEstimator::new(SieOptions::default());
    let mut residuals = vec![0.0; 3 * n];
    let mut weights = vec![0.0; n];
    let mut annealing = true;
    let mut level_iterations = 0;
    for iteration in 0..MAX_ITERATIONS {
        for (row, (a, b)) in residuals.chunks_exact_mut(3).zip(&pairs) {
            let p = transform_point(&t, a);
            for k in 0..3 {
                row[k] = p[k] - b[k];
            }
        }
        if iteration == 0 {
            estimator.prepare(&residuals, 3);
            let beta = estimator.residual_rms(&residuals, 3);
            estimator.set_beta(&beta);
        }
        let previous = estimator.clone();
        if !annealing {
            estimator.adapt_penalty();
        }
        estimator.fit(&residuals, 3);
        if hold_broad_jumps && annealing && iteration > 0 {
            let (old, new) = (&previous.models()[0], &estimator.models()[0]);
            if new.inlier.sigma > old.inlier.sigma + old.beta {
                estimator = previous;
            }
        }
        estimator.probabilities(&residuals, 3, &mut weights);
        let Some(solve) = weighted_rigid_fit(&pairs, &weights) else {
            break;
        };
        let next = solve.transform;
        let displacement = (pairs
            .iter()
            .map(|(a, _)| {
                let (p, q) = (transform_point(&t, a), transform_point(&next, a));
                (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>()
            })
            .sum::<f64>()
            / n as f64)
            .sqrt();
        let change = (next - t).abs().max();
        t = next;
        let width = estimator.effective_scales()[0];
        let settled = change < TOLERANCE || displacement <= LEVEL_TOLERANCE * width;
        if annealing {
            level_iterations += 1;
            if settled || level_iterations >= MAX_LEVEL_ITERATIONS {
                level_iterations = 0;
                if estimator.beta_negligible(BETA_STOP_RATIO) {
                    annealing = false;
                } else {
                    estimator.shrink_beta(BETA_SHRINK);
                }
            }
        } else if change < TOLERANCE {
            break;
        }
    }
    t
}
