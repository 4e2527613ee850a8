//! The estimator's settings: which residuals share a histogram, the noise shape p, the
//! histogram's resolution and range (§4.5), the penalty k of eq. (fitParams) and the γ rule
//! of §4.2. Defaults follow the paper and, where it is silent, the authors' experiments.

/// Which residuals share a histogram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HistogramMode {
    /// One histogram of |r| over all columns: all dimensions share σ (§4.5 "joint histogram …
    /// absolute values"); the authors' experiments use this. μ = 0.
    Pooled,
    /// One signed histogram per column, each with its own μ_j, σ_j (§4.1).
    PerColumn,
}

/// The exponent p of the generalised Gaussian inlier model (appendix).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NoiseShape {
    /// Fixed p: 2 is Gaussian (the paper's main text), 1 is Laplacian.
    Fixed(f64),
    /// p estimated from the histogram together with σ (appendix, "SIE estimated norm").
    Estimated,
}

/// How P(I) in γ = (P(I)/P(O))^(m-1) is obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GammaRule {
    /// Eq. (pi): P(I) ≈ Σ G over the data, computed as the mean per-dimension posterior
    /// (equal to ΣG/ΣH where the cap does not bite).
    Paper,
    /// γ = 1 (the authors' PPR3 code path).
    One,
}

/// Settings of the estimator. Defaults follow the paper and, where it is silent, the authors'
/// experiment configuration (see docs in README "SIE parameters").
#[derive(Clone, Debug, PartialEq)]
pub struct SieOptions {
    /// Which residuals share a histogram (pooled |r| or one per column).
    pub histogram: HistogramMode,
    /// The inlier density's noise shape p: fixed, or estimated with σ.
    pub noise_shape: NoiseShape,
    /// Samples per bin: bins = round(n_in_range / data_per_bin) (§4.5, 40 in the experiments).
    pub data_per_bin: f64,
    /// Fewest histogram bins, however few samples are in range.
    pub min_bins: usize,
    /// Most histogram bins, however many samples are in range.
    pub max_bins: usize,
    /// Smoothing kernel standard deviation as a fraction of the bin count (0.02 → 2 % of the
    /// histogram width, §4.5 "standard deviation proportional to the width").
    pub smoothing: f64,
    /// ε of §4.5: the histogram covers |x-μ| where G/α ≥ ε.
    pub range_epsilon: f64,
    /// Cap on P(I|r_ij) (§4.2: "we pick 0.99").
    pub max_probability: f64,
    /// k of eq. (fitParams) before adaptation (§4.5: k = 10 until convergence).
    pub initial_penalty: f64,
    /// Adapted k = P(I|H)^-exponent, clamped to [1, initial_penalty] (§4.5 uses 3; the authors'
    /// final code uses 1).
    pub penalty_exponent: f64,
    /// How P(I) in γ is obtained (§4.2).
    pub gamma: GammaRule,
    /// Lower bound on σ in normalised units (0 = none).
    pub min_sigma: f64,
}

impl Default for SieOptions {
    fn default() -> Self {
        SieOptions {
            histogram: HistogramMode::Pooled,
            noise_shape: NoiseShape::Fixed(2.0),
            data_per_bin: 40.0,
            min_bins: 50,
            max_bins: 1000,
            smoothing: 0.02,
            range_epsilon: 1e-6,
            max_probability: 0.99,
            initial_penalty: 10.0,
            penalty_exponent: 3.0,
            gamma: GammaRule::Paper,
            min_sigma: 0.0,
        }
    }
}

impl SieOptions {
    /// Checks every field; the message names the first bad one.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |v: f64, name: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{name} must be finite and > 0, got {v}"))
            }
        };
        positive(self.data_per_bin, "data_per_bin")?;
        if self.min_bins < 3 || self.max_bins < self.min_bins || self.max_bins > 1_000_000 {
            return Err(format!(
                "bins must satisfy 3 <= min_bins <= max_bins <= 1e6, got {}..{}",
                self.min_bins, self.max_bins
            ));
        }
        if !(self.smoothing.is_finite() && self.smoothing >= 0.0 && self.smoothing < 1.0) {
            return Err(format!("smoothing must be in [0, 1), got {}", self.smoothing));
        }
        if !(self.range_epsilon > 0.0 && self.range_epsilon < 1.0) {
            return Err(format!(
                "range_epsilon must be in (0, 1), got {}",
                self.range_epsilon
            ));
        }
        if !(self.max_probability > 0.0 && self.max_probability < 1.0) {
            return Err(format!(
                "max_probability must be in (0, 1), got {}",
                self.max_probability
            ));
        }
        if !(self.initial_penalty.is_finite() && self.initial_penalty >= 1.0) {
            return Err(format!(
                "penalty k must be finite and >= 1, got {}",
                self.initial_penalty
            ));
        }
        if !(self.penalty_exponent.is_finite() && self.penalty_exponent >= 0.0) {
            return Err(format!(
                "penalty exponent must be finite and >= 0, got {}",
                self.penalty_exponent
            ));
        }
        if let NoiseShape::Fixed(p) = self.noise_shape {
            if !(p.is_finite() && (0.1..=10.0).contains(&p)) {
                return Err(format!("noise shape p must be in [0.1, 10], got {p}"));
            }
        }
        if !(self.min_sigma.is_finite() && self.min_sigma >= 0.0) {
            return Err(format!(
                "min_sigma must be finite and >= 0, got {}",
                self.min_sigma
            ));
        }
        Ok(())
    }
}
