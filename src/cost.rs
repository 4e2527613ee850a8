//! Cost functions for the IRLS step (eq. regprob2: T_{k+1} = argmin Σ w(r_i^k)·‖r_i‖²).
//!
//! SIE's weight (eq. regprob3 / regprob3GGD) lives in the registration driver because it needs
//! the fitted model; the baselines of §5 and the usual robust kernels are here. Every weight is
//! a function of the norm u = ‖r̃_i‖ of the noise-normalised residual row (§4.4).

/// Which weight the IRLS step uses. Scales and thresholds are in normalised residual units
/// (input units when the noise model is constant).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CostFunction {
    /// Statistical Inlier Estimation (the paper's method; no parameter to tune).
    Sie,
    /// Least squares: w = 1.
    L2,
    /// w = 1 if u < threshold, else 0 (§5 "Truncated L2-norm").
    TruncatedL2 {
        /// The cut-off (residual units, > 0).
        threshold: f64,
    },
    /// w = max(u, δ)^(p-2): L1 (p = 1) and L0.1 (p = 0.1) in §5, as IRLS.
    Lp {
        /// The exponent p, in (0, 2].
        p: f64,
    },
    /// Student-t with ν degrees of freedom and the scale re-estimated every iteration
    /// (Kerl et al. 2013, ν = 5): w = (ν+m)/(ν + u²/s²).
    StudentT {
        /// Degrees of freedom ν (> 0).
        dof: f64,
    },
    /// w = 1 if u ≤ c, else c/u.
    Huber {
        /// The threshold c (residual units, > 0).
        scale: f64,
    },
    /// w = 1/(1 + (u/c)²).
    Cauchy {
        /// The scale c (residual units, > 0).
        scale: f64,
    },
    /// w = 1/(1 + (u/c)²)².
    GemanMcClure {
        /// The scale c (residual units, > 0).
        scale: f64,
    },
    /// w = (1 - (u/c)²)² if u < c, else 0.
    Tukey {
        /// The cut-off c (residual units, > 0).
        scale: f64,
    },
}

/// δ of the Lp weight, so a zero residual does not give an infinite weight.
pub const LP_DELTA: f64 = 1e-6;
/// Student-t scale iteration: relative change of s² that ends it, and the iteration cap.
const STUDENT_T_TOLERANCE: f64 = 1e-6;
const STUDENT_T_MAX_ITERATIONS: usize = 100;

impl CostFunction {
    /// The parameter the C API's `sie_context_set_cost_function` carries (0 for SIE and L2).
    pub fn parameter(&self) -> f64 {
        match *self {
            CostFunction::Sie | CostFunction::L2 => 0.0,
            CostFunction::TruncatedL2 { threshold } => threshold,
            CostFunction::Lp { p } => p,
            CostFunction::StudentT { dof } => dof,
            CostFunction::Huber { scale }
            | CostFunction::Cauchy { scale }
            | CostFunction::GemanMcClure { scale }
            | CostFunction::Tukey { scale } => scale,
        }
    }

    /// Checks the parameter: p in (0, 2] for `Lp`, finite and > 0 for the others with one;
    /// the error says which value is wrong.
    pub fn validate(&self) -> Result<(), String> {
        let value = self.parameter();
        let ok = match self {
            CostFunction::Sie | CostFunction::L2 => true,
            CostFunction::Lp { p } => p.is_finite() && *p > 0.0 && *p <= 2.0,
            _ => value.is_finite() && value > 0.0,
        };
        if ok {
            Ok(())
        } else {
            Err(format!(
                "{self:?}: parameter out of range (Lp needs 0 < p <= 2, others > 0)"
            ))
        }
    }
}

/// Weights of a baseline cost for residual rows (row-major n × cols, normalised). Returns the
/// scale it estimated (Student-t) or used (the others; 0 for scale-free ones).
pub fn baseline_weights(cost: CostFunction, residuals: &[f64], cols: usize, weights: &mut [f64]) -> f64 {
    debug_assert_eq!(residuals.len(), weights.len() * cols);
    let scale2 = match cost {
        CostFunction::StudentT { dof } => student_t_scale2(dof, residuals, cols),
        _ => 0.0,
    };
    for (w, row) in weights.iter_mut().zip(residuals.chunks_exact(cols)) {
        *w = baseline_weight(cost, row, scale2);
    }
    match cost {
        CostFunction::Sie | CostFunction::L2 | CostFunction::Lp { .. } => 0.0,
        CostFunction::StudentT { .. } => scale2.sqrt(),
        _ => cost.parameter(),
    }
}

/// The weight [`baseline_weights`] gives one row, with the squared Student-t scale it
/// estimated (`scale2`; unused by the other costs).
pub(crate) fn baseline_weight(cost: CostFunction, row: &[f64], scale2: f64) -> f64 {
    let u = row.iter().map(|r| r * r).sum::<f64>().sqrt();
    match cost {
        CostFunction::Sie => unreachable!("SIE weights come from the estimator"),
        CostFunction::L2 => 1.0,
        CostFunction::TruncatedL2 { threshold } => {
            if u < threshold {
                1.0
            } else {
                0.0
            }
        }
        CostFunction::Lp { p } => u.max(LP_DELTA).powf(p - 2.0),
        CostFunction::Huber { scale } => {
            if u <= scale {
                1.0
            } else {
                scale / u
            }
        }
        CostFunction::Cauchy { scale } => 1.0 / (1.0 + (u / scale).powi(2)),
        CostFunction::GemanMcClure { scale } => 1.0 / (1.0 + (u / scale).powi(2)).powi(2),
        CostFunction::Tukey { scale } => {
            if u < scale {
                (1.0 - (u / scale).powi(2)).powi(2)
            } else {
                0.0
            }
        }
        CostFunction::StudentT { dof } => {
            let m = row.len() as f64;
            if scale2 > 0.0 {
                (dof + m) / (dof + u * u / scale2)
            } else {
                1.0
            }
        }
    }
}

/// Scale of an isotropic multivariate t (Kerl et al. 2013, eq. for σ² generalised to m
/// dimensions): s² ← Σ_i w_i‖r_i‖² / (n·m), w_i = (ν+m)/(ν + ‖r_i‖²/s²), from s² = mean r².
pub fn student_t_scale2(dof: f64, residuals: &[f64], cols: usize) -> f64 {
    let rows = residuals.len() / cols;
    if rows == 0 {
        return 0.0;
    }
    let squared: Vec<f64> = residuals
        .chunks_exact(cols)
        .map(|row| row.iter().map(|r| r * r).sum())
        .collect();
    let m = cols as f64;
    let denominator = rows as f64 * m;
    let mut s2 = squared.iter().sum::<f64>() / denominator;
    for _ in 0..STUDENT_T_MAX_ITERATIONS {
        if !(s2.is_finite() && s2 > 0.0) {
            return 0.0;
        }
        let next = squared
            .iter()
            .map(|&q| q * (dof + m) / (dof + q / s2))
            .sum::<f64>()
            / denominator;
        let done = ((next - s2) / s2).abs() < STUDENT_T_TOLERANCE;
        s2 = next;
        if done {
            break;
        }
    }
    s2
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weight_of(cost: CostFunction, u: f64) -> f64 {
        let mut w = [0.0];
        baseline_weights(cost, &[u], 1, &mut w);
        w[0]
    }

    #[test]
    fn kernels_match_their_formulas() {
        assert_eq!(weight_of(CostFunction::L2, 7.0), 1.0);
        assert_eq!(weight_of(CostFunction::TruncatedL2 { threshold: 1.0 }, 0.99), 1.0);
        assert_eq!(weight_of(CostFunction::TruncatedL2 { threshold: 1.0 }, 1.0), 0.0);
        assert!((weight_of(CostFunction::Lp { p: 1.0 }, 0.5) - 2.0).abs() < 1e-12);
        assert_eq!(weight_of(CostFunction::Lp { p: 1.0 }, 0.0), 1.0 / LP_DELTA);
        assert_eq!(weight_of(CostFunction::Huber { scale: 1.0 }, 0.5), 1.0);
        assert!((weight_of(CostFunction::Huber { scale: 1.0 }, 4.0) - 0.25).abs() < 1e-12);
        assert!((weight_of(CostFunction::Cauchy { scale: 2.0 }, 2.0) - 0.5).abs() < 1e-12);
        assert!((weight_of(CostFunction::GemanMcClure { scale: 2.0 }, 2.0) - 0.25).abs() < 1e-12);
        assert!((weight_of(CostFunction::Tukey { scale: 2.0 }, 1.0) - 0.5625).abs() < 1e-12);
        assert_eq!(weight_of(CostFunction::Tukey { scale: 2.0 }, 2.0), 0.0);
    }

    #[test]
    fn row_norm_is_used_for_multidimensional_residuals() {
        let mut w = [0.0];
        baseline_weights(CostFunction::Huber { scale: 1.0 }, &[3.0, 4.0, 0.0], 3, &mut w);
        assert!((w[0] - 0.2).abs() < 1e-12);
    }

    #[test]
    fn student_t_scale_is_robust_to_outliers() {
        // 90 residuals at ±1 (s ≈ 1), 10 at ±100: the scale stays near the inliers'.
        let mut r: Vec<f64> = (0..90).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
        r.extend((0..10).map(|i| if i % 2 == 0 { 100.0 } else { -100.0 }));
        let s = student_t_scale2(5.0, &r, 1).sqrt();
        assert!(s > 0.8 && s < 2.5, "{s}");
        let plain = (r.iter().map(|v| v * v).sum::<f64>() / 100.0).sqrt();
        assert!(plain > 30.0);
    }

    #[test]
    fn validation_rejects_bad_parameters() {
        assert!(CostFunction::Lp { p: 0.0 }.validate().is_err());
        assert!(CostFunction::Lp { p: 3.0 }.validate().is_err());
        assert!(CostFunction::Huber { scale: f64::NAN }.validate().is_err());
        assert!(CostFunction::Tukey { scale: -1.0 }.validate().is_err());
        assert!(CostFunction::Sie.validate().is_ok());
        assert!(CostFunction::Lp { p: 0.1 }.validate().is_ok());
    }
}
