//! One residual histogram H_j and its fitted inlier model G_j (§4.1, §4.5), plus the per-bin
//! inlier probability table of eq. (InlierRatioReg).

use super::options::{NoiseShape, SieOptions};
use super::shape::{GeneralisedGaussian, minimise_1d, shape_cost, sigma_cost};

/// At most this many range refits per fit (fixed point of "range where G > ε").
const MAX_RANGE_REFITS: usize = 5;
/// Range refits stop when the old and new intervals overlap by ≥ exp(-0.025) of their mean width.
const RANGE_TOLERANCE: f64 = 0.025;
/// Shape-exponent search interval for `NoiseShape::Estimated`.
const SHAPE_RANGE: (f64, f64) = (0.25, 4.0);
/// An inlier peak must fall to at most MAX_SHOULDER·α at μ ± SHOULDER·σ (a clean Gaussian: 0.32).
const SHOULDER: f64 = 1.5;
const MAX_SHOULDER: f64 = 0.6;
/// Below this many samples no histogram is fitted (every sample is taken as an inlier).
const MIN_FIT_SAMPLES: usize = 10;
/// Alternating σ / p rounds when p is estimated.
const SHAPE_ROUNDS: usize = 6;

/// What one histogram holds: |r| of every column (folded at 0, so μ = 0 and the left edge
/// mirrors; `HistogramMode::Pooled`) or one column's signed residuals (`PerColumn`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Residuals {
    Magnitudes,
    Signed,
}

/// The width G is evaluated with: σ as fitted, or σ + β as predictions use it (§4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelWidth {
    /// σ: the model fitted to the histogram.
    Sigma,
    /// σ + β: the regularised model the probabilities are predicted with.
    SigmaPlusBeta,
}

/// A fitted histogram: the data the paper's Fig. 1 (right) draws, and the model that
/// turns it into probabilities.
#[derive(Clone, Debug, PartialEq)]
pub struct HistogramModel {
    /// The fitted inlier density G: α (counts per bin at the peak), μ, σ and the shape
    /// exponent p. Units: normalised residual.
    pub inlier: GeneralisedGaussian,
    /// Regulariser β_j added to σ_j when predicting (§4.3).
    pub beta: f64,
    /// Penalty k_j of eq. (fitParams) used for the last fit.
    pub penalty: f64,
    /// Histogram interval [lo, hi); for pooled |r| histograms lo = 0.
    pub lo: f64,
    /// Upper end of the histogram interval (exclusive).
    pub hi: f64,
    /// Raw counts per bin.
    pub counts: Vec<f64>,
    /// Counts after Gaussian smoothing (H̃, what the model is fitted to).
    pub smoothed: Vec<f64>,
    /// P(I|r) at each bin centre.
    pub probability: Vec<f64>,
    /// P(I|H_j): mean probability of the samples inside the range (§4.5, drives adaptive k).
    pub mean_inlier_probability: f64,
    /// Samples that fell inside [lo, hi).
    pub samples_in_range: usize,
    /// Samples given to the fit (inside the range or not).
    pub samples_total: usize,
    /// False when no inlier peak could be fitted (no spread, or σ ran to its upper bound).
    pub peak_found: bool,
}

impl HistogramModel {
    pub(crate) fn initial(inlier: GeneralisedGaussian, penalty: f64) -> Self {
        HistogramModel {
            inlier,
            beta: 0.0,
            penalty,
            lo: 0.0,
            hi: 0.0,
            counts: Vec::new(),
            smoothed: Vec::new(),
            probability: Vec::new(),
            mean_inlier_probability: 0.0,
            samples_in_range: 0,
            samples_total: 0,
            peak_found: false,
        }
    }

    /// Number of bins.
    pub fn bins(&self) -> usize {
        self.counts.len()
    }

    /// Width of one bin (normalised residual units).
    pub fn bin_width(&self) -> f64 {
        (self.hi - self.lo) / self.counts.len().max(1) as f64
    }

    /// Centre of bin `bin` (0-based).
    pub fn bin_centre(&self, bin: usize) -> f64 {
        self.lo + (bin as f64 + 0.5) * self.bin_width()
    }

    /// G at x, with σ (the fitted model) or σ+β (the prediction model).
    pub fn model(&self, x: f64, width: ModelWidth) -> f64 {
        let beta = match width {
            ModelWidth::Sigma => 0.0,
            ModelWidth::SigmaPlusBeta => self.beta,
        };
        self.inlier.value(x, beta)
    }

    /// P(I|x), linearly interpolated between bin centres; 0 outside the histogram range,
    /// where G < ε·α by construction.
    #[inline]
    pub fn probability(&self, x: f64) -> f64 {
        let bins = self.probability.len();
        if bins == 0 {
            return 0.0;
        }
        if self.hi == self.lo {
            // No spread: only the value at the peak is an inlier.
            return if x == self.lo { self.probability[0] } else { 0.0 };
        }
        if !(x >= self.lo && x < self.hi) {
            return 0.0;
        }
        let t = (x - self.lo) / (self.hi - self.lo) * bins as f64 - 0.5;
        if t <= 0.0 {
            return self.probability[0];
        }
        let i = t as usize;
        if i + 1 >= bins {
            return self.probability[bins - 1];
        }
        let f = t - i as f64;
        self.probability[i] * (1.0 - f) + self.probability[i + 1] * f
    }

    /// P(I|x) as [`HistogramModel::probability`] inside the range; beyond it G_{σ+β}(x)
    /// over the histogram's floor (the smallest H̃ the table divides by), capped as the table
    /// is: the samples there are too few to count, and G's own tail says how unlikely an
    /// inlier is (0 once G underflows, tens of σ out).
    pub(crate) fn probability_beyond_range(&self, x: f64, options: &SieOptions) -> f64 {
        if self.probability.is_empty() || self.hi == self.lo || (x >= self.lo && x < self.hi) {
            return self.probability(x);
        }
        let g = self.model(x, ModelWidth::SigmaPlusBeta);
        if g == 0.0 {
            return 0.0;
        }
        (g / density_floor(&self.smoothed)).min(options.max_probability)
    }

    /// H̃ at x, linearly interpolated between bin centres (0 outside the range; |r| histograms
    /// are mirrored at 0).
    fn smoothed_at(&self, x: f64) -> f64 {
        let bins = self.smoothed.len();
        if bins == 0 || !(x >= self.lo && x < self.hi) {
            return 0.0;
        }
        let t = ((x - self.lo) / (self.hi - self.lo) * bins as f64 - 0.5).max(0.0);
        let i = (t as usize).min(bins - 1);
        let next = (i + 1).min(bins - 1);
        let f = t - i as f64;
        self.smoothed[i] * (1.0 - f) + self.smoothed[next] * f
    }

    fn interval(&self, residuals: Residuals, options: &SieOptions) -> (f64, f64) {
        let w = GeneralisedGaussian::half_width(
            self.inlier.sigma + self.beta,
            self.inlier.p,
            options.range_epsilon,
        );
        if residuals == Residuals::Magnitudes {
            (0.0, w)
        } else {
            (self.inlier.mu - w, self.inlier.mu + w)
        }
    }

    /// Fits the model to the samples (|r| for `Residuals::Magnitudes`), refitting the range
    /// until it is a fixed point (§4.5). `samples` yields the same values on every call.
    pub(crate) fn fit<I: Iterator<Item = f64>>(
        &mut self,
        options: &SieOptions,
        residuals: Residuals,
        samples: impl Fn() -> I,
    ) {
        self.samples_total = samples().count();
        let (low, high) = samples().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
            (l.min(x), h.max(x))
        });
        if low == high {
            // Every sample the same (exact data, or one value repeated): each is as likely an
            // inlier as the cap allows, whatever μ = 0 of a pooled |r| histogram assumes.
            self.inlier.mu = low;
            self.fit_without_spread(options);
            return;
        }
        if self.inlier.sigma + self.beta <= 0.0 || (self.inlier.sigma + self.beta).is_nan() {
            // The last data had no spread; this data may (e.g. round-off after a perfect fit).
            // Restart from the all-inlier ML estimate (§4.5) instead of a zero-width model.
            let mu = self.inlier.mu;
            self.inlier.sigma = root_mean_square(samples().map(|x| x - mu));
        }
        for refit in 0..=MAX_RANGE_REFITS {
            let (lo, hi) = self.interval(residuals, options);
            if !((hi - lo).is_finite() && hi > lo) {
                self.fit_without_spread(options);
                return;
            }
            if self.samples_total < MIN_FIT_SAMPLES {
                self.fit_too_few(options, lo, hi);
                return;
            }
            self.build_histogram(options, residuals, lo, hi, &samples);
            self.fit_shape(options, residuals);
            let (new_lo, new_hi) = self.interval(residuals, options);
            let overlap = (hi.min(new_hi) - lo.max(new_lo)).max(0.0);
            let mean_width = 0.5 * ((hi - lo) + (new_hi - new_lo));
            if refit == MAX_RANGE_REFITS
                || overlap / mean_width >= (-RANGE_TOLERANCE).exp()
                || self.widening_itself(options, hi - lo, new_hi - new_lo)
            {
                break;
            }
        }
        self.update_probabilities(options);
    }

    /// A wider range asked for by a histogram that already holds every sample and is at the bin
    /// floor: nothing lies beyond the range, so the wider σ comes from the smoothing kernel,
    /// which is capped at a sixth of the range and so grows with it. Refitting would widen σ
    /// again by the same factor (about 1.7 a refit for p = 2 on a dozen samples, so σ ends
    /// orders of magnitude past the largest residual), so the range stays. Histograms with
    /// samples beyond the range, or more samples than the floor's bins need, never get here.
    fn widening_itself(&self, options: &SieOptions, width: f64, new_width: f64) -> bool {
        new_width > width
            && self.samples_in_range == self.samples_total
            && self.counts.len() <= options.min_bins
    }

    /// All samples equal (σ+β = 0): every sample sits exactly at the peak, so each is as likely
    /// an inlier as the cap allows (e.g. a cloud registered onto itself). No peak is "found".
    fn fit_without_spread(&mut self, options: &SieOptions) {
        self.inlier.sigma = 0.0;
        self.lo = self.inlier.mu;
        self.hi = self.inlier.mu;
        self.set_flat(options, self.samples_total);
    }

    /// Too few samples for a histogram: keep the all-inlier ML start (σ = RMS, §4.5) and give
    /// every sample in the range the capped probability. No peak is "found".
    fn fit_too_few(&mut self, options: &SieOptions, lo: f64, hi: f64) {
        self.lo = lo;
        self.hi = hi;
        self.set_flat(options, self.samples_total);
    }

    /// A one-bin histogram holding `count` samples, all at the capped probability.
    fn set_flat(&mut self, options: &SieOptions, count: usize) {
        self.counts.clear();
        self.counts.push(count as f64);
        self.smoothed.clone_from(&self.counts);
        self.probability.clear();
        self.probability.push(options.max_probability);
        self.samples_in_range = count;
        self.mean_inlier_probability = options.max_probability;
        self.inlier.alpha = count as f64;
        self.peak_found = false;
    }

    fn build_histogram<I: Iterator<Item = f64>>(
        &mut self,
        options: &SieOptions,
        residuals: Residuals,
        lo: f64,
        hi: f64,
        samples: &impl Fn() -> I,
    ) {
        let inside = samples().filter(|&x| x >= lo && x < hi).count();
        // §4.5: bins linear in the samples in range keeps the per-bin sample variance constant.
        let wanted = (inside as f64 / options.data_per_bin).round() as usize;
        let bins = wanted.clamp(options.min_bins, options.max_bins);
        self.lo = lo;
        self.hi = hi;
        self.samples_in_range = inside;
        self.counts.clear();
        self.counts.resize(bins, 0.0);
        let scale = bins as f64 / (hi - lo);
        for x in samples() {
            if x >= lo && x < hi {
                let b = (((x - lo) * scale) as usize).min(bins - 1);
                self.counts[b] += 1.0;
            }
        }
        // Kernel std ∝ width (§4.5); when the bin cap binds, each bin holds more samples than
        // data_per_bin, the histogram is less noisy, and the kernel narrows in proportion.
        let capped = (bins as f64 / wanted.max(1) as f64).min(1.0);
        // When the bin floor binds, bins hold fewer than data_per_bin samples; widen the kernel
        // until it averages about data_per_bin samples, so the peak height α stays as precise
        // as the paper's sample-variance argument intends. At the mirrored edge of a |r|
        // histogram (where its peak is) the kernel sees one side only: ask for twice as many.
        let per_bin = inside.max(1) as f64 / bins as f64;
        let one_sided = if residuals == Residuals::Magnitudes {
            2.0
        } else {
            1.0
        };
        let sparse = one_sided * options.data_per_bin / ((2.0 * std::f64::consts::PI).sqrt() * per_bin);
        // That widening stops at half the model's width σ+β: a kernel as wide as the peak widens
        // the fitted σ by itself (σ² + kernel²), and the range is a multiple of σ+β, so each
        // range refit would widen σ again (70 residuals within 0.02 and two at ±3 gave σ = 3
        // and both outliers P = 0.99). A kernel wider than a sixth of the histogram would
        // flatten any peak: cap it too.
        let half_model = 0.5 * (self.inlier.sigma + self.beta) * scale;
        let std_bins = (options.smoothing * bins as f64 * capped)
            .max(sparse.min(half_model))
            .min(bins as f64 / 6.0);
        smooth(&self.counts, &mut self.smoothed, std_bins, residuals);
    }

    /// μ and α from the peak, then σ (and p) by eq. (fitParams).
    fn fit_shape(&mut self, options: &SieOptions, residuals: Residuals) {
        let bins = self.smoothed.len();
        let width = self.bin_width();
        let centres: Vec<f64> = (0..bins).map(|b| self.bin_centre(b)).collect();
        if residuals == Residuals::Magnitudes {
            // |r| histograms are mirrored at 0, so the peak of the residual density is at 0.
            self.inlier.mu = 0.0;
            self.inlier.alpha = self.smoothed[0];
        } else {
            let (mu, alpha) = refined_peak(&self.smoothed);
            self.inlier.mu = self.lo + (mu + 0.5) * width;
            self.inlier.alpha = alpha;
        }
        let total: f64 = self.smoothed.iter().sum();
        if !(self.inlier.alpha.is_finite() && self.inlier.alpha > 0.0) || total <= 0.0 {
            self.peak_found = false;
            return;
        }
        let moment = (centres
            .iter()
            .zip(&self.smoothed)
            .map(|(c, h)| (c - self.inlier.mu).powi(2) * h)
            .sum::<f64>()
            / total)
            .sqrt();
        let sigma_lo = (0.05 * width).max(options.min_sigma).max(f64::MIN_POSITIVE);
        let sigma_hi = (2.0 * moment).max(4.0 * sigma_lo);
        let k = self.penalty;
        let fit_sigma = |inlier: GeneralisedGaussian| {
            minimise_1d(sigma_lo, sigma_hi, |s| {
                sigma_cost(
                    &GeneralisedGaussian { sigma: s, ..inlier },
                    &centres,
                    &self.smoothed,
                    k,
                )
            })
        };
        match options.noise_shape {
            NoiseShape::Fixed(p) => {
                self.inlier.p = p;
                self.inlier.sigma = fit_sigma(self.inlier);
            }
            NoiseShape::Estimated => {
                for _ in 0..SHAPE_ROUNDS {
                    self.inlier.sigma = fit_sigma(self.inlier);
                    let before = self.inlier.p;
                    let inlier = self.inlier;
                    self.inlier.p = minimise_1d(SHAPE_RANGE.0, SHAPE_RANGE.1, |p| {
                        shape_cost(&GeneralisedGaussian { p, ..inlier }, &centres, &self.smoothed, k)
                    });
                    if (self.inlier.p - before).abs() < 1e-3 {
                        break;
                    }
                }
                self.inlier.sigma = fit_sigma(self.inlier);
            }
        }
        self.inlier.sigma = self.inlier.sigma.max(options.min_sigma);
        // An inlier peak falls off like G: at μ ± 1.5σ a Gaussian is down to 0.32α (plus the
        // outlier background), while a flat histogram (only outliers) is still near α there.
        // σ at its upper bracket means the fit found no bounded peak at all.
        let right = self.smoothed_at(self.inlier.mu + SHOULDER * self.inlier.sigma);
        let shoulder = if residuals == Residuals::Magnitudes {
            right
        } else {
            0.5 * (right + self.smoothed_at(self.inlier.mu - SHOULDER * self.inlier.sigma))
        };
        self.peak_found = self.inlier.sigma < 0.99 * sigma_hi
            && shoulder <= MAX_SHOULDER * self.inlier.alpha
            && self.samples_in_range >= MIN_FIT_SAMPLES;
    }

    /// Eq. (InlierRatioReg): P(I|r) = min(cap, G_{σ+β}(r)/H̃(r)); H̃ is floored at one count and
    /// at 1 % of its peak so empty tail bins do not produce spurious certainty.
    fn update_probabilities(&mut self, options: &SieOptions) {
        let bins = self.smoothed.len();
        let floor = density_floor(&self.smoothed);
        let mut table = std::mem::take(&mut self.probability);
        table.clear();
        table.extend((0..bins).map(|b| {
            let g = self.model(self.bin_centre(b), ModelWidth::SigmaPlusBeta);
            (g / self.smoothed[b].max(floor)).min(options.max_probability)
        }));
        self.probability = table;
        let weighted: f64 = self
            .counts
            .iter()
            .zip(&self.probability)
            .map(|(c, p)| c * p)
            .sum();
        let count: f64 = self.counts.iter().sum();
        self.mean_inlier_probability = if count > 0.0 { weighted / count } else { 0.0 };
    }
}

/// The smallest H̃ the probability table divides by: one count, or 1 % of the peak (a
/// smoothed histogram's far bins are noise).
fn density_floor(smoothed: &[f64]) -> f64 {
    let peak = smoothed.iter().cloned().fold(0.0, f64::max);
    (0.01 * peak).max(1.0)
}

/// Sub-bin peak: argmax refined by the parabola through its neighbours. Returns (position in
/// bins, height).
fn refined_peak(h: &[f64]) -> (f64, f64) {
    let (b, &y) = h
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
        .expect("histogram has bins");
    if b == 0 || b + 1 == h.len() {
        return (b as f64, y);
    }
    let (l, r) = (h[b - 1], h[b + 1]);
    let curvature = l - 2.0 * y + r;
    if curvature >= 0.0 {
        return (b as f64, y);
    }
    let d = (0.5 * (l - r) / curvature).clamp(-0.5, 0.5);
    (b as f64 + d, y - 0.25 * (l - r) * d)
}

/// Gaussian smoothing with std `std_bins` (in bins), truncated where the kernel weight drops
/// below 1e-3. The left edge of a |r| histogram is mirrored (|r| is folded at 0); other edges
/// renormalise by the kernel mass that falls inside the histogram.
fn smooth(input: &[f64], output: &mut Vec<f64>, std_bins: f64, residuals: Residuals) {
    let n = input.len();
    output.clear();
    if std_bins < 1e-3 {
        output.extend_from_slice(input);
        return;
    }
    let radius = ((2.0 * 1000f64.ln()).sqrt() * std_bins).ceil() as usize;
    let kernel: Vec<f64> = (0..=radius)
        .map(|i| (-0.5 * (i as f64 / std_bins).powi(2)).exp())
        .collect();
    output.resize(n, 0.0);
    let r = radius as isize;
    for (i, out) in output.iter_mut().enumerate() {
        let mut sum = 0.0;
        let mut mass = 0.0;
        for d in -r..=r {
            let j = i as isize + d;
            // bin -1 mirrors bin 0, -2 mirrors 1, …
            let source = if j < 0 && residuals == Residuals::Magnitudes {
                -j - 1
            } else {
                j
            };
            if (0..n as isize).contains(&source) {
                let w = kernel[d.unsigned_abs()];
                sum += w * input[source as usize];
                mass += w;
            }
        }
        *out = if mass > 0.0 { sum / mass } else { 0.0 };
    }
}

/// Residuals larger than this (normalised units) are outliers whatever the model: their squares
/// would leave f64's range. They are left out of every statistic (one garbage pair at 1e160
/// among good ones made the RMS start infinite and every probability 0).
pub(crate) const ARITHMETIC_LIMIT: f64 = 1e100;

/// sqrt(mean(x²)) over the values within ±ARITHMETIC_LIMIT; 0 for none.
pub(crate) fn root_mean_square(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values
        .filter(|v| v.abs() <= ARITHMETIC_LIMIT)
        .fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_preserves_a_flat_histogram() {
        let input = vec![5.0; 100];
        let mut out = Vec::new();
        smooth(&input, &mut out, 3.0, Residuals::Magnitudes);
        assert!(out.iter().all(|v| (v - 5.0).abs() < 1e-12));
        smooth(&input, &mut out, 3.0, Residuals::Signed);
        assert!(out.iter().all(|v| (v - 5.0).abs() < 1e-12));
    }

    #[test]
    fn smoothing_spreads_a_spike_symmetrically() {
        let mut input = vec![0.0; 101];
        input[50] = 1.0;
        let mut out = Vec::new();
        smooth(&input, &mut out, 2.0, Residuals::Signed);
        assert!((out[48] - out[52]).abs() < 1e-15);
        assert!(out[50] > out[49] && out[49] > out[48]);
    }

    #[test]
    fn peak_refinement_finds_vertex() {
        // Parabola with vertex at 3.3.
        let h: Vec<f64> = (0..8).map(|i| 10.0 - (i as f64 - 3.3).powi(2)).collect();
        let (pos, height) = refined_peak(&h);
        assert!((pos - 3.3).abs() < 1e-9, "{pos}");
        assert!((height - 10.0).abs() < 1e-9);
    }

    #[test]
    fn probability_is_zero_outside_range_and_interpolates_inside() {
        let mut m = HistogramModel::initial(
            GeneralisedGaussian {
                alpha: 1.0,
                mu: 0.0,
                sigma: 1.0,
                p: 2.0,
            },
            10.0,
        );
        m.lo = 0.0;
        m.hi = 4.0;
        m.counts = vec![1.0; 4];
        m.probability = vec![0.9, 0.5, 0.3, 0.1];
        assert_eq!(m.probability(4.0), 0.0);
        assert_eq!(m.probability(-0.1), 0.0);
        assert_eq!(m.probability(0.2), 0.9);
        assert!((m.probability(1.0) - 0.7).abs() < 1e-12);
        assert_eq!(m.probability(3.9), 0.1);
    }
}
