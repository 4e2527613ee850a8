//! The estimator's state across fits: one fitted model per histogram (§4.1), the adaptive
//! penalty k (§4.5), and the inlier probability of every row (eqs. InlierRatio and
//! InlierRatioReg, combined over columns with γ, §4.2).

use super::histogram::{HistogramModel, Residuals, root_mean_square};
use super::options::{GammaRule, HistogramMode, NoiseShape, SieOptions};
use super::shape::GeneralisedGaussian;
use crate::median::median;

/// SIE state carried between iterations (§4.5: range, bins and k are carried over).
#[derive(Clone, Debug)]
pub struct SieEstimator {
    options: SieOptions,
    models: Vec<HistogramModel>,
    /// Pooled mode: which residual columns had spread at the last fit (see `active_columns`).
    active: Vec<bool>,
}

impl SieEstimator {
    /// An estimator with these settings and no fitted histogram yet.
    pub fn new(options: SieOptions) -> Self {
        SieEstimator {
            options,
            models: Vec::new(),
            active: Vec::new(),
        }
    }

    /// Raises the lower bound on σ to `resolution` (normalised units): below the rounding
    /// of the coordinates, residuals carry no noise to fit (exact data), and a σ at the
    /// rounding level would make the next rounding error an outlier.
    pub fn set_resolution(&mut self, resolution: f64) {
        if resolution.is_finite() && resolution > self.options.min_sigma {
            self.options.min_sigma = resolution;
        }
    }

    /// The settings in use (with the σ floor raised by `set_resolution`).
    pub fn options(&self) -> &SieOptions {
        &self.options
    }

    /// The fitted histograms and models: one (pooled) or one per column.
    pub fn models(&self) -> &[HistogramModel] {
        &self.models
    }

    /// Forgets all fitted state (the next fit starts from the all-inlier ML guess, §4.5).
    pub fn reset(&mut self) {
        self.models.clear();
    }

    fn histogram_count(&self, cols: usize) -> usize {
        match self.options.histogram {
            HistogramMode::Pooled => 1,
            HistogramMode::PerColumn => cols,
        }
    }

    /// Makes sure there is one model per histogram, initialised to the ML estimate that treats
    /// every residual as an inlier (§4.5), with regulariser β. `beta = None` keeps an existing β.
    fn ensure_models(&mut self, residuals: &[f64], cols: usize) {
        let count = self.histogram_count(cols);
        if self.models.len() == count {
            return;
        }
        let p = match self.options.noise_shape {
            NoiseShape::Fixed(p) => p,
            NoiseShape::Estimated => 2.0,
        };
        let k = self.options.initial_penalty;
        self.models = (0..count)
            .map(|j| {
                let (mu, sigma) = match self.options.histogram {
                    HistogramMode::Pooled => (0.0, root_mean_square(residuals.iter().copied())),
                    HistogramMode::PerColumn => {
                        let mut column: Vec<f64> = residuals.iter().skip(j).step_by(cols).copied().collect();
                        let mu = median(&mut column).unwrap_or(0.0);
                        (mu, root_mean_square(column.iter().map(|r| r - mu)))
                    }
                };
                HistogramModel::initial(
                    GeneralisedGaussian {
                        alpha: 0.0,
                        mu,
                        sigma,
                        p,
                    },
                    k,
                )
            })
            .collect();
    }

    /// RMS of each histogram's samples about zero: the paper's suggested start value of β_j
    /// ("the standard deviation of the initial set of residuals", §4.3).
    pub fn residual_rms(&self, residuals: &[f64], cols: usize) -> Vec<f64> {
        match self.options.histogram {
            HistogramMode::Pooled => vec![root_mean_square(residuals.iter().copied())],
            HistogramMode::PerColumn => (0..cols)
                .map(|j| root_mean_square(residuals.iter().skip(j).step_by(cols).copied()))
                .collect(),
        }
    }

    /// Sets β_j for every histogram (one value is broadcast). Fits must have created the models,
    /// or `prepare` must be called first.
    pub fn set_beta(&mut self, beta: &[f64]) {
        for (j, m) in self.models.iter_mut().enumerate() {
            m.beta = beta[j.min(beta.len() - 1)].max(0.0);
        }
    }

    /// Sets every histogram's model to σ, k and (when the shape is estimated) p: a warm start
    /// from an earlier fit. `prepare` must have created the models.
    pub fn set_model(&mut self, sigma: f64, penalty: f64, shape: f64) {
        let estimated = self.options.noise_shape == NoiseShape::Estimated;
        for m in &mut self.models {
            m.inlier.sigma = sigma;
            m.penalty = penalty;
            if estimated {
                m.inlier.p = shape;
            }
        }
    }

    /// β_j ← factor·β_j (§4.3: halve after each convergence).
    pub fn shrink_beta(&mut self, factor: f64) {
        for m in &mut self.models {
            m.beta *= factor;
        }
    }

    /// True when β_j < ratio·σ_j for every histogram (§4.3: "until β ≪ σ").
    pub fn beta_negligible(&self, ratio: f64) -> bool {
        // Below the smallest σ the data can show, narrowing β further changes nothing (noise-free
        // residuals fit σ = 0: "β ≪ σ" would never hold).
        let floor = self.options.min_sigma;
        self.models
            .iter()
            .all(|m| m.beta <= ratio * m.inlier.sigma.max(floor))
    }

    /// Creates the models for this residual layout without fitting (so β can be set first).
    pub fn prepare(&mut self, residuals: &[f64], cols: usize) {
        assert!(cols > 0 && residuals.len() % cols == 0, "residual matrix shape");
        self.ensure_models(residuals, cols);
    }

    /// Fits every histogram's model to the residuals (row-major n × cols, normalised).
    pub fn fit(&mut self, residuals: &[f64], cols: usize) {
        self.prepare(residuals, cols);
        let options = &self.options;
        match options.histogram {
            HistogramMode::Pooled => {
                self.active = active_columns(residuals, cols);
                let active = &self.active;
                self.models[0].fit(options, Residuals::Magnitudes, || {
                    residuals
                        .iter()
                        .enumerate()
                        .filter(|(idx, _)| active[idx % cols])
                        .map(|(_, r)| r.abs())
                });
            }
            HistogramMode::PerColumn => {
                for (j, model) in self.models.iter_mut().enumerate() {
                    model.fit(options, Residuals::Signed, || {
                        residuals.iter().skip(j).step_by(cols).copied()
                    });
                }
            }
        }
    }

    /// Sets k_j = P(I|H_j)^-exponent, clamped to [1, k₀] (§4.5, after convergence).
    pub fn adapt_penalty(&mut self) {
        let options = &self.options;
        for m in &mut self.models {
            let p = m.mean_inlier_probability.max(1e-12);
            m.penalty = p
                .powf(-options.penalty_exponent)
                .clamp(1.0, options.initial_penalty);
        }
    }

    /// P(I|r_ij) of one component.
    #[inline]
    fn component_probability(&self, value: f64, col: usize) -> f64 {
        match self.options.histogram {
            HistogramMode::Pooled => self.models[0].probability(value.abs()),
            HistogramMode::PerColumn => self.models[col].probability(value),
        }
    }

    /// P(I|r_ij) of one component as a row's combination (§4.2) takes it. One histogram per
    /// column is fitted to that column's samples alone, often a few hundred: its σ can come
    /// out well below the column's spread, and an inlier's component just outside its range
    /// would veto the row (P = 0) however well the other columns fit. There a component
    /// beyond the range keeps the model's odds, G/H̃ (`probability_beyond_range`).
    #[inline]
    fn row_component_probability(&self, value: f64, col: usize) -> f64 {
        match self.options.histogram {
            HistogramMode::Pooled => self.models[0].probability(value.abs()),
            HistogramMode::PerColumn => self.models[col].probability_beyond_range(value, &self.options),
        }
    }

    /// Per-row inlier probability P(I|R_i) into `out` (length n). Returns P(I), the mean
    /// per-component posterior used in γ.
    pub fn probabilities(&self, residuals: &[f64], cols: usize, out: &mut [f64]) -> f64 {
        let rows = residuals.len() / cols;
        assert_eq!(out.len(), rows, "output length");
        if rows == 0 {
            return 0.0;
        }
        if cols == 1 {
            let mut sum = 0.0;
            for (o, &r) in out.iter_mut().zip(residuals) {
                *o = self.component_probability(r, 0);
                sum += *o;
            }
            return sum / rows as f64;
        }
        let (total, count) = residuals
            .iter()
            .enumerate()
            .filter(|(idx, _)| self.takes_part(idx % cols))
            .fold((0.0, 0usize), |(sum, n), (idx, &r)| {
                (sum + self.component_probability(r, idx % cols), n + 1)
            });
        let prior = (total / count.max(1) as f64).clamp(1e-9, 1.0 - 1e-9);
        for (o, row) in out.iter_mut().zip(residuals.chunks_exact(cols)) {
            *o = self.row_probability(row, prior);
        }
        prior
    }

    /// Columns without spread (pooled mode) carry no evidence and take no part.
    fn takes_part(&self, col: usize) -> bool {
        self.options.histogram == HistogramMode::PerColumn || self.active.get(col).copied().unwrap_or(true)
    }

    /// P(I|R) of one row as [`SieEstimator::probabilities`] gives it, with the prior P(I)
    /// that call returned (unused for one column).
    pub fn row_probability(&self, row: &[f64], prior: f64) -> f64 {
        if row.len() == 1 {
            return self.component_probability(row[0], 0);
        }
        let columns = (0..row.len()).filter(|&j| self.takes_part(j)).count().max(1);
        // §4.2: γ = (P(I)/P(O))^(m-1), kept as a logarithm: with hundreds of columns the
        // products below leave f64's range (200 columns of N(0, 1) gave P = 0 for every row).
        let log_gamma = match self.options.gamma {
            GammaRule::Paper => (columns as f64 - 1.0) * (prior.ln() - (1.0 - prior).ln()),
            GammaRule::One => 0.0,
        };
        let (mut log_inlier, mut log_outlier) = (0.0, 0.0);
        for (j, &r) in row.iter().enumerate().filter(|(j, _)| self.takes_part(*j)) {
            let p = self.row_component_probability(r, j);
            log_inlier += p.ln();
            log_outlier += (-p).ln_1p();
        }
        // P(I|R_i) = Πp / (Πp + γ·Π(1-p)) = 1 / (1 + exp(ln γ + ΣlnΠ(1-p) − ΣlnΠp))
        let log_ratio = log_gamma + log_outlier - log_inlier;
        if log_inlier == f64::NEG_INFINITY {
            0.0
        } else {
            1.0 / (1.0 + log_ratio.exp())
        }
    }

    /// Scale σ_j + β_j of each histogram (normalised units).
    pub fn effective_scales(&self) -> Vec<f64> {
        self.models.iter().map(|m| m.inlier.sigma + m.beta).collect()
    }

    /// The noise shape p, the mean over histograms (2 unless estimated).
    pub fn noise_shape(&self) -> f64 {
        if self.models.is_empty() {
            return match self.options.noise_shape {
                NoiseShape::Fixed(p) => p,
                NoiseShape::Estimated => 2.0,
            };
        }
        self.models.iter().map(|m| m.inlier.p).sum::<f64>() / self.models.len() as f64
    }
}

/// A column whose RMS is below this fraction of the largest column's has no spread of its own
/// (rounding only: planar data, a 2-D scanner, noise on one axis): pooled with the others it
/// would put a spike at zero that makes every real residual an outlier.
const SILENT_COLUMN: f64 = 1e-6;

/// Pooled mode: the columns with spread (every column when none has any).
fn active_columns(residuals: &[f64], cols: usize) -> Vec<bool> {
    let rms: Vec<f64> = (0..cols)
        .map(|j| root_mean_square(residuals.iter().skip(j).step_by(cols).copied()))
        .collect();
    let largest = rms.iter().copied().fold(0.0, f64::max);
    rms.iter()
        .map(|&r| largest == 0.0 || r > SILENT_COLUMN * largest)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    fn mixture(n: usize, sigma: f64, outlier_fraction: f64, seed: u64) -> (Vec<f64>, Vec<bool>) {
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(seed);
        let normal = Normal::new(0.0, sigma).unwrap();
        let mut r = Vec::with_capacity(n);
        let mut inlier = Vec::with_capacity(n);
        for _ in 0..n {
            if rng.random::<f64>() < outlier_fraction {
                r.push(rng.random_range(-1.0..1.0));
                inlier.push(false);
            } else {
                r.push(normal.sample(&mut rng));
                inlier.push(true);
            }
        }
        (r, inlier)
    }

    fn mean_where(p: &[f64], mask: &[bool], want: bool) -> f64 {
        let v: Vec<f64> = p
            .iter()
            .zip(mask)
            .filter(|(_, m)| **m == want)
            .map(|(p, _)| *p)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    }

    #[test]
    fn one_dimensional_mixture_pooled_and_per_column() {
        for mode in [HistogramMode::Pooled, HistogramMode::PerColumn] {
            let (r, inlier) = mixture(10_000, 0.02, 0.3, 7);
            let mut sie = SieEstimator::new(SieOptions {
                histogram: mode,
                ..SieOptions::default()
            });
            sie.fit(&r, 1);
            sie.adapt_penalty();
            sie.fit(&r, 1);
            let sigma = sie.models()[0].inlier.sigma;
            assert!((sigma - 0.02).abs() < 0.002, "{mode:?}: sigma {sigma}");
            let mut p = vec![0.0; r.len()];
            sie.probabilities(&r, 1, &mut p);
            assert!(p.iter().all(|v| (0.0..=1.0).contains(v)));
            let pin = mean_where(&p, &inlier, true);
            let pout = mean_where(&p, &inlier, false);
            assert!(pin > 0.8 && pout < 0.2, "{mode:?}: inliers {pin} outliers {pout}");
        }
    }

    #[test]
    fn laplacian_shape_is_estimated() {
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(3);
        // Laplace(0, b) by inverse CDF.
        let b = 0.05;
        let r: Vec<f64> = (0..40_000)
            .map(|_| {
                let u: f64 = rng.random::<f64>() - 0.5;
                -b * u.signum() * (1.0 - 2.0 * u.abs()).ln()
            })
            .collect();
        let mut sie = SieEstimator::new(SieOptions {
            noise_shape: NoiseShape::Estimated,
            ..SieOptions::default()
        });
        for _ in 0..3 {
            sie.fit(&r, 1);
        }
        let m = &sie.models()[0];
        assert!((m.inlier.p - 1.0).abs() < 0.2, "p {}", m.inlier.p);
        assert!((m.inlier.sigma - b).abs() < 0.2 * b, "sigma {}", m.inlier.sigma);
    }

    #[test]
    fn gamma_combines_dimensions() {
        // Three columns: rows 0..800 inliers (N(0, 0.01)), the rest uniform outliers.
        let (mut r, _) = mixture(3 * 800, 0.01, 0.0, 11);
        let (o, _) = mixture(3 * 800, 0.01, 1.0, 12);
        r.extend(o);
        let mut sie = SieEstimator::new(SieOptions::default());
        sie.fit(&r, 3);
        let mut p = vec![0.0; 1600];
        let prior = sie.probabilities(&r, 3, &mut p);
        assert!(prior > 0.3 && prior < 0.7, "prior {prior}");
        let pin = p[..800].iter().sum::<f64>() / 800.0;
        let pout = p[800..].iter().sum::<f64>() / 800.0;
        assert!(pin > 0.95, "{pin}");
        assert!(pout < 0.05, "{pout}");
        // One row at a time with the returned prior: the same probabilities, bit for bit.
        for (row, expected) in r.chunks_exact(3).zip(&p) {
            assert_eq!(sie.row_probability(row, prior).to_bits(), expected.to_bits());
        }
    }
    /// Hundreds of columns, one histogram each, fitted on 200 samples: some σ come out well
    /// below the spread (0.3 for N(0, 1)), and an inlier's component outside such a range used
    /// to give its whole row P = 0. Rows whose every component is far out stay outliers.
    #[test]
    fn many_columns_of_inliers_are_inliers_per_column() {
        let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(3);
        let normal = Normal::new(0.0, 1.0).unwrap();
        for cols in [3, 200, 500, 1000] {
            let (inliers, outliers) = (200, 20);
            let mut r: Vec<f64> = (0..inliers * cols).map(|_| normal.sample(&mut rng)).collect();
            r.extend(
                (0..outliers * cols)
                    .map(|_| rng.random_range(15.0..30.0) * if rng.random::<bool>() { 1.0 } else { -1.0 }),
            );
            let mut sie = SieEstimator::new(SieOptions {
                histogram: HistogramMode::PerColumn,
                ..SieOptions::default()
            });
            sie.fit(&r, cols);
            sie.adapt_penalty();
            sie.fit(&r, cols);
            let mut p = vec![0.0; inliers + outliers];
            sie.probabilities(&r, cols, &mut p);
            let lowest_inlier = p[..inliers].iter().cloned().fold(1.0, f64::min);
            let highest_outlier = p[inliers..].iter().cloned().fold(0.0, f64::max);
            assert!(
                lowest_inlier > 0.5,
                "{cols} columns: an inlier row at P = {lowest_inlier}"
            );
            assert!(
                highest_outlier < 0.01,
                "{cols} columns: an outlier row at P = {highest_outlier}"
            );
        }
    }
}
