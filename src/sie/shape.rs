//! The inlier noise model G of §4.1 and the appendix (generalised Gaussian), and the
//! asymmetric penalty fit of eq. (fitParams).
//!
//! Parametrisation: G(x) = α·exp(-(|x-μ|/σ)^p / p).
//! * p = 2 gives α·exp(-0.5((x-μ)/σ)²), the paper's Gaussian (§4.1), σ = standard deviation.
//! * p = 1 gives α·exp(-|x-μ|/σ), the appendix's Laplacian, σ = Laplace scale b.
//!
//! The appendix writes exp(-(|x-μ|/σ')^p); the two agree for p = 1 and differ only by the
//! constant σ' = σ·p^(1/p) otherwise. This form keeps σ the familiar scale for both special
//! cases, and its IRLS weight is exactly the appendix's eq. (regprob3GGD):
//! ρ(r) = (|r|/σ)^p/p  ⇒  ρ'(r)/r = σ^-p·|r|^(p-2).

/// Un-normalised generalised Gaussian α·exp(-(|x-μ|/σ)^p / p).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeneralisedGaussian {
    /// Height at the peak μ (counts per bin).
    pub alpha: f64,
    /// Centre (0 for pooled |r| histograms).
    pub mu: f64,
    /// Width σ (> 0), in the residuals' units.
    pub sigma: f64,
    /// The noise shape p (2 Gaussian, 1 Laplacian; in [0.1, 10]).
    pub p: f64,
}

impl GeneralisedGaussian {
    /// G(x) with the scale widened by the regulariser β (eq. InlierRatioReg: σ + β).
    #[inline]
    pub fn value(&self, x: f64, beta: f64) -> f64 {
        let scale = self.sigma + beta;
        if scale <= 0.0 {
            return if x == self.mu { self.alpha } else { 0.0 };
        }
        let u = (x - self.mu).abs() / scale;
        self.alpha * (-power(u, self.p) / self.p).exp()
    }

    /// Half-width around μ inside which G/α ≥ ε (§4.5: "limit H_j to the interval where G_j > ε").
    /// With scale s = σ+β: (|x-μ|/s)^p/p = ln(1/ε) ⇒ |x-μ| = s·(p·ln(1/ε))^(1/p)
    /// (5.26·s for p = 2 and ε = 1e-6).
    pub fn half_width(sigma_plus_beta: f64, p: f64, epsilon: f64) -> f64 {
        sigma_plus_beta * (p * (1.0 / epsilon).ln()).powf(1.0 / p)
    }
}

/// The asymmetric penalty of eq. (fitParams): F(x) = -k·x for x ≤ 0, x for x > 0,
/// summed over bins with x = H(i) - G(i).
///
/// Returns the cost and its derivative with respect to the parameter whose partial
/// derivative of G is given by `dg`. Model values above the histogram (x < 0) cost k per unit.
#[inline]
fn penalty_terms(h: f64, g: f64, dg: f64, k: f64) -> (f64, f64) {
    let x = h - g;
    if x > 0.0 { (x, -dg) } else { (-k * x, k * dg) }
}

/// Beyond this exponent u^p/p, G/α = exp(-u^p/p) < 1e-17: G is below the rounding of any
/// non-zero count, so it is taken as 0 (and exp's slow underflow path is not entered).
const NEGLIGIBLE_EXPONENT: f64 = 40.0;

/// u^p, with the Gaussian case (p = 2, the default) as one multiplication instead of `powf`.
#[inline]
fn power(u: f64, p: f64) -> f64 {
    if p == 2.0 { u * u } else { u.powf(p) }
}

/// Total penalty Σ F(H̃(c) - G(c)) and dC/dσ, evaluated at the bin centres `centres`.
/// This runs ~80 times per fit (the σ search), so it is the SIE fit's inner loop.
pub fn sigma_cost(model: &GeneralisedGaussian, centres: &[f64], hist: &[f64], k: f64) -> (f64, f64) {
    let mut cost = 0.0;
    let mut deriv = 0.0;
    let s = model.sigma;
    for (&c, &h) in centres.iter().zip(hist) {
        let u = (c - model.mu).abs() / s;
        let up = power(u, model.p);
        let exponent = up / model.p;
        let g = if exponent > NEGLIGIBLE_EXPONENT {
            0.0
        } else {
            model.alpha * (-exponent).exp()
        };
        // dG/dσ = G·u^p/σ
        let dg = g * up / s;
        let (f, df) = penalty_terms(h, g, dg, k);
        cost += f;
        deriv += df;
    }
    (cost, deriv)
}

/// Total penalty and dC/dp for the noise shape p (appendix: "SIE can be used to find an estimate of p").
pub fn shape_cost(model: &GeneralisedGaussian, centres: &[f64], hist: &[f64], k: f64) -> (f64, f64) {
    let mut cost = 0.0;
    let mut deriv = 0.0;
    let p = model.p;
    for (&c, &h) in centres.iter().zip(hist) {
        let u = (c - model.mu).abs() / model.sigma;
        let (g, dg) = if u > 0.0 {
            let up = u.powf(p);
            let g = model.alpha * (-up / p).exp();
            // d/dp [u^p/p] = u^p·(p·ln u - 1)/p²
            (g, -g * up * (p * u.ln() - 1.0) / (p * p))
        } else {
            (model.alpha, 0.0)
        };
        let (f, df) = penalty_terms(h, g, dg, k);
        cost += f;
        deriv += df;
    }
    (cost, deriv)
}

/// Minimises a 1-D cost on [lo, hi] (lo > 0): a coarse logarithmic grid finds the basin of the
/// global minimum (the penalty can have a second, shallow basin on an outlier shoulder), then
/// bisection on the sign of the analytic derivative refines it (§4.1: "effectively minimized
/// using bisection").
pub fn minimise_1d(lo: f64, hi: f64, f: impl Fn(f64) -> (f64, f64)) -> f64 {
    const GRID: usize = 40;
    const BISECTIONS: usize = 40;
    debug_assert!(lo > 0.0 && hi > lo);
    let ratio = (hi / lo).powf(1.0 / (GRID - 1) as f64);
    let mut best = 0;
    let mut best_cost = f64::INFINITY;
    let mut x = lo;
    let mut grid = [0.0; GRID];
    for (i, slot) in grid.iter_mut().enumerate() {
        *slot = x;
        let (c, _) = f(x);
        if c < best_cost {
            best_cost = c;
            best = i;
        }
        x *= ratio;
    }
    // Bracket around the best grid point; at an end of the grid the bisection simply walks
    // to that end, since the derivative keeps one sign there.
    let mut a = grid[best.saturating_sub(1)];
    let mut b = grid[(best + 1).min(GRID - 1)];
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (a + b);
        if f(mid).1 > 0.0 {
            b = mid;
        } else {
            a = mid;
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_width_matches_reference_constant_for_gaussian() {
        let w = GeneralisedGaussian::half_width(1.0, 2.0, 1e-6);
        assert!((w - 5.2565).abs() < 1e-3, "{w}");
        let g = GeneralisedGaussian {
            alpha: 1.0,
            mu: 0.0,
            sigma: 1.0,
            p: 2.0,
        };
        assert!((g.value(w, 0.0) - 1e-6).abs() < 1e-9);
    }

    #[test]
    fn gaussian_shape_is_the_papers_form() {
        let g = GeneralisedGaussian {
            alpha: 3.0,
            mu: 1.0,
            sigma: 0.5,
            p: 2.0,
        };
        let x = 1.7_f64;
        let expected = 3.0 * (-0.5 * ((x - 1.0) / 0.5).powi(2)).exp();
        assert!((g.value(x, 0.0) - expected).abs() < 1e-12);
        // β widens the scale: σ+β.
        let expected_wide = 3.0 * (-0.5 * ((x - 1.0) / 0.75).powi(2)).exp();
        assert!((g.value(x, 0.25) - expected_wide).abs() < 1e-12);
    }

    #[test]
    fn sigma_fit_recovers_a_clean_gaussian() {
        let centres: Vec<f64> = (0..200).map(|i| (i as f64 + 0.5) * 0.02).collect();
        let truth = GeneralisedGaussian {
            alpha: 100.0,
            mu: 0.0,
            sigma: 0.7,
            p: 2.0,
        };
        let hist: Vec<f64> = centres.iter().map(|&c| truth.value(c, 0.0)).collect();
        let sigma = minimise_1d(0.01, 4.0, |s| {
            sigma_cost(&GeneralisedGaussian { sigma: s, ..truth }, &centres, &hist, 10.0)
        });
        assert!((sigma - 0.7).abs() < 1e-6, "{sigma}");
    }

    #[test]
    fn shape_fit_recovers_a_laplacian() {
        let centres: Vec<f64> = (0..400).map(|i| (i as f64 + 0.5) * 0.02).collect();
        let truth = GeneralisedGaussian {
            alpha: 50.0,
            mu: 0.0,
            sigma: 0.6,
            p: 1.0,
        };
        let hist: Vec<f64> = centres.iter().map(|&c| truth.value(c, 0.0)).collect();
        let p = minimise_1d(0.3, 4.0, |p| {
            shape_cost(&GeneralisedGaussian { p, ..truth }, &centres, &hist, 10.0)
        });
        assert!((p - 1.0).abs() < 1e-5, "{p}");
    }

    #[test]
    fn penalty_prefers_model_under_histogram() {
        // With k = 10, exceeding the histogram by 1 costs 10, staying under by 1 costs 1.
        assert_eq!(penalty_terms(2.0, 1.0, 0.0, 10.0).0, 1.0);
        assert_eq!(penalty_terms(1.0, 2.0, 0.0, 10.0).0, 10.0);
    }
}
