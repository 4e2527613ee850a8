//! SIE inside an IRLS registration (§3, §4.3, §4.5): the β annealing schedule, the moment k
//! adapts, the final round, and the IRLS weight of eq. (regprob3).
//!
//! The registration driver owns the loop (match, weigh, solve, stop); this type decides how
//! each iteration's correspondences are weighed and when the model may be called converged.

use super::estimator::SieEstimator;
use super::options::SieOptions;

/// A β level has converged when one update moves the correspondences by less than this
/// fraction of the current model width σ+β (normalised RMS displacement).
const LEVEL_TOLERANCE: f64 = 0.01;
/// At most this many updates per β level before β shrinks anyway: with many outliers a level
/// can wander at the scale of σ+β without settling (the authors' driver likewise makes at most
/// 3 model updates per level).
const MAX_LEVEL_UPDATES: u32 = 5;
/// δ of eq. (regprob3GGD) relative to σ+β: bounds the weight max(‖r‖, δ)^(p-2) for p < 2.
const SHAPE_DELTA: f64 = 1e-3;
/// In the final round, an update smaller than this fraction of the pose's standard error
/// (`precision`) is below what the data can resolve: the registration has converged. ICP's
/// updates can keep changing at that level (matches and histogram bins flip), which no fixed
/// tolerance of 1e-6 can wait out.
const PRECISION_FRACTION: f64 = 0.1;
/// Degrees of freedom of a rigid transform.
const RIGID_DOF: f64 = 6.0;

/// A previous registration's fitted noise model, to start the next similar one from: a
/// sequence's next frame, registered from a good guess (a constant-velocity prediction). σ in
/// the units `RegistrationResult::sigma` reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarmStart {
    /// Fitted σ (`RegistrationResult::sigma`, the RMS over histograms when there are several).
    pub sigma: f64,
    /// Adapted k (`RegistrationResult::penalty`).
    pub penalty: f64,
    /// Noise shape p (`RegistrationResult::noise_shape`; used when the shape is estimated).
    pub noise_shape: f64,
    /// Inlier fraction (`RegistrationResult::inlier_fraction`): a warm run that ends with far
    /// fewer inliers has left the previous frame's basin, and the full schedule runs instead.
    pub inlier_fraction: f64,
}

impl WarmStart {
    /// A noise model from its numbers (σ per histogram, each finite and > 0); the message
    /// names the first bad value.
    pub fn from_fit(
        sigma: &[f64],
        penalty: f64,
        noise_shape: f64,
        inlier_fraction: f64,
    ) -> Result<WarmStart, String> {
        if let Some(bad) = sigma.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(format!("warm start sigma must be finite and > 0, got {bad}"));
        }
        let warm = WarmStart {
            sigma: root_mean_square_of_positive(sigma),
            penalty,
            noise_shape,
            inlier_fraction,
        };
        warm.validate().map(|()| warm)
    }

    /// Checks the values; the message names the first bad one.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.sigma.is_finite() && self.sigma > 0.0) {
            return Err(format!(
                "warm start sigma must be finite and > 0, got {}",
                self.sigma
            ));
        }
        if !(self.penalty.is_finite() && self.penalty >= 1.0) {
            return Err(format!(
                "warm start penalty must be finite and >= 1, got {}",
                self.penalty
            ));
        }
        if !(self.noise_shape.is_finite() && self.noise_shape > 0.0) {
            return Err(format!(
                "warm start noise_shape must be finite and > 0, got {}",
                self.noise_shape
            ));
        }
        if !(0.0..=1.0).contains(&self.inlier_fraction) {
            return Err(format!(
                "warm start inlier_fraction must be in [0, 1], got {}",
                self.inlier_fraction
            ));
        }
        Ok(())
    }
}

/// sqrt(mean(s²)) of finite positive values, with no overflow or underflow on the way: σ of
/// 1e300 (finite, accepted) gave an infinite RMS and an error saying "got inf".
fn root_mean_square_of_positive(values: &[f64]) -> f64 {
    let plain = (values.iter().map(|s| s * s).sum::<f64>() / values.len().max(1) as f64).sqrt();
    if plain.is_finite() && plain > 0.0 {
        return plain;
    }
    let largest = values.iter().cloned().fold(0.0, f64::max);
    if largest == 0.0 {
        return 0.0;
    }
    largest * (values.iter().map(|s| (s / largest).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
}

/// A warm start's β₀, in σ of the previous fit: one level above the noise, wide enough for a
/// guess a few σ off (a constant-velocity prediction) without the levels that search the
/// initial residuals' whole spread.
pub const WARM_BETA_WIDTHS: f64 = 2.0;
/// A warm start's annealing ends once β falls below this fraction of σ: the model's k and
/// shape are already the data's (§4.5 adapts them after annealing only because a cold start
/// cannot know them), so the levels far below σ that a cold start needs change nothing.
const WARM_FINAL_RATIO: f64 = 0.5;
/// A warm start whose first level moved the rows by at most this many model widths σ+β in all
/// (β = 2σ there) found its guess where the previous noise model said it would be: the levels
/// between only refine a pose the final round refines anyway, so it begins at once. A guess
/// further off (the Kinect frames: 7–37σ) keeps every level.
const WARM_HELD_WIDTHS: f64 = 1.0;
/// Such a first level ends once an update moves the rows by at most this fraction of σ+β
/// (LEVEL_TOLERANCE is 0.01): it only seeds the final round, which refines to the caller's
/// tolerance anyway (docs/performance.md, item 15, has what it saves).
const WARM_HELD_TOLERANCE: f64 = 0.1;

/// How β starts and shrinks (§4.3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BetaSchedule {
    /// Where β starts.
    pub start: BetaStart,
    /// β ← shrink·β after each level converges (§4.3: 0.5).
    pub shrink: f64,
    /// Annealing ends when β_j < stop_ratio·σ_j for every histogram ("until β ≪ σ").
    pub stop_ratio: f64,
}

/// β₀ (§4.3 leaves it open: "prior knowledge about the uncertainty of T or … the standard
/// deviation of the initial set of residuals").
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BetaStart {
    /// The RMS of the first residuals of each histogram (the paper's suggestion).
    ResidualRms,
    /// This β₀ (normalised units) for every histogram.
    Fixed(f64),
    /// From this noise model with β₀ = WARM_BETA_WIDTHS·σ; annealing ends at β < σ/2 with β set
    /// to 0 for the final round.
    Warm(WarmStart),
}

impl BetaSchedule {
    /// The warm start's noise model, when β starts from one.
    fn warm(&self) -> Option<WarmStart> {
        match self.start {
            BetaStart::Warm(warm) => Some(warm),
            _ => None,
        }
    }
}

/// Where the schedule stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// β is being annealed with k = k₀.
    Annealing,
    /// β ≪ σ: k adapts to the data (§4.5) and the model is refitted every update.
    Final,
    /// The final round has settled at the model's scale: the model is held fixed so IRLS can
    /// converge on it instead of chasing histogram bin-count jitter.
    Frozen,
}

/// Which convergence tests the driver may apply after an update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Convergence {
    /// Still annealing: no stop on a small update (the level just ends).
    NotYet,
    /// Final round: stop when the update is below the tolerances.
    Tolerance,
    /// Model frozen: also stop when the iterates return to where they were two updates ago.
    ToleranceOrCycle,
    /// Final round: the update was below the pose's precision (stop).
    Resolved,
}

/// When the final round may stop on an update below the pose's precision.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrecisionStop {
    /// ICP: matches and histogram bins flip at the precision's scale, so the updates may never
    /// get below the tolerances.
    Allowed,
    /// Fixed pairs: IRLS converges geometrically; the tolerances alone decide (the simulation's
    /// excess error stays at the tolerance's level, not the precision's).
    Never,
}

/// SIE's state across the updates of one registration.
#[derive(Clone, Debug)]
pub struct Schedule {
    estimator: SieEstimator,
    beta: BetaSchedule,
    precision_stop: PrecisionStop,
    phase: Phase,
    level_updates: u32,
    /// Σ displacement of the current level's updates (normalised RMS).
    level_motion: f64,
    /// True until the first level ends.
    first_level: bool,
    started: bool,
    /// A final-round update on a subset of the points has settled: the next update fits the
    /// model on every point, and it freezes (σ from every point, without a second settling).
    subset_settled: bool,
    /// Σ P(I|R_i) of the last update: the effective number of inlier rows.
    inlier_mass: f64,
    /// P(I) of the last `probabilities` (see [`SieEstimator::row_probability`]).
    prior: f64,
}

impl Schedule {
    pub fn new(options: SieOptions, beta: BetaSchedule, precision_stop: PrecisionStop) -> Self {
        Schedule {
            estimator: SieEstimator::new(options),
            beta,
            precision_stop,
            phase: Phase::Annealing,
            level_updates: 0,
            level_motion: 0.0,
            first_level: true,
            started: false,
            subset_settled: false,
            inlier_mass: 0.0,
            prior: 0.5,
        }
    }

    /// The smallest σ the data can show (`SieEstimator::set_resolution`).
    pub fn set_resolution(&mut self, resolution: f64) {
        self.estimator.set_resolution(resolution);
    }

    /// The estimator with its last fitted models.
    pub fn estimator(&self) -> &SieEstimator {
        &self.estimator
    }

    /// True while β is being annealed.
    pub fn annealing(&self) -> bool {
        self.phase == Phase::Annealing
    }

    /// Whether the final round's updates may still match a subset of the points: the model is
    /// fitted (after the annealing) and no subset's update has settled yet.
    pub fn final_fit_on_subset(&self) -> bool {
        self.phase == Phase::Final && !self.subset_settled
    }

    /// Whether the final round's model is held fixed (the updates then iterate one map of the
    /// pose alone).
    pub fn model_frozen(&self) -> bool {
        self.phase == Phase::Frozen
    }

    /// Fits SIE to this update's residuals (rows × `cols`, divided by the row scales F_i of
    /// §4.4; `row_scale(i)` is F_i) and fills the IRLS weights of eq. (regprob3) / (regprob3GGD):
    /// w_i = σ^-p·max(‖r_i‖, δ)^(p-2)·P(I|r_i)·F_i^-2; σ^-p is common to all rows and dropped.
    pub fn weigh(
        &mut self,
        normalised: &[f64],
        cols: usize,
        row_scale: impl Fn(usize) -> f64,
        weights: &mut [f64],
    ) {
        let estimator = &mut self.estimator;
        if !self.started {
            self.started = true;
            estimator.prepare(normalised, cols);
            let beta = match self.beta.start {
                BetaStart::Warm(warm) => {
                    estimator.set_model(warm.sigma, warm.penalty, warm.noise_shape);
                    vec![WARM_BETA_WIDTHS * warm.sigma]
                }
                BetaStart::Fixed(b) => vec![b],
                BetaStart::ResidualRms => estimator.residual_rms(normalised, cols),
            };
            estimator.set_beta(&beta);
        }
        match self.phase {
            Phase::Annealing => estimator.fit(normalised, cols),
            Phase::Final => {
                // §4.5: after convergence, k = P(I|H)^-3 from the data at hand.
                estimator.adapt_penalty();
                estimator.fit(normalised, cols);
            }
            Phase::Frozen => {}
        }
        // P(I|R_i) first, turned into the weight in place (no second buffer of rows).
        estimator.probabilities(normalised, cols, weights);
        self.inlier_mass = weights.iter().sum();
        let estimator = &self.estimator;
        let p = estimator.noise_shape();
        let delta = (SHAPE_DELTA * self.width()).max(1e-12);
        for (i, w) in weights.iter_mut().enumerate() {
            let scale = row_scale(i);
            let shape_factor = if p == 2.0 {
                1.0
            } else {
                row_norm(normalised, cols, i).max(delta).powf(p - 2.0)
            };
            *w = *w * shape_factor / (scale * scale);
        }
    }

    /// Σ_i P(I|R_i) over the rows of the last `weigh`.
    pub fn inlier_mass(&self) -> f64 {
        self.inlier_mass
    }

    /// P(I|R_i) under the current model (fitted to these residuals first when no update has
    /// fitted one yet, e.g. when the iteration budget was already spent).
    pub fn probabilities(&mut self, normalised: &[f64], cols: usize, out: &mut [f64]) {
        if !self.started {
            self.weigh(normalised, cols, |_| 1.0, out);
        }
        self.prior = self.estimator.probabilities(normalised, cols, out);
    }

    /// P(I|R) of one row under the model of the last `probabilities`.
    pub fn row_probability(&self, row: &[f64]) -> f64 {
        self.estimator.row_probability(row, self.prior)
    }

    /// The narrowest model width min_j(σ_j + β_j), normalised units.
    pub fn width(&self) -> f64 {
        self.estimator
            .effective_scales()
            .into_iter()
            .fold(f64::INFINITY, f64::min)
    }

    /// Standard error of the pose as a displacement of the rows (normalised RMS): a weighted
    /// least-squares fit of 6 parameters to rows with noise σ moves the fitted rows by
    /// σ·√(6/n) RMS, with n = Σ P(I|R_i) the effective number of inliers.
    pub fn precision(&self) -> f64 {
        let models = self.estimator.models();
        let sigma =
            (models.iter().map(|m| m.inlier.sigma.powi(2)).sum::<f64>() / models.len().max(1) as f64).sqrt();
        sigma * (RIGID_DOF / self.inlier_mass.max(1.0)).sqrt()
    }

    /// The final round settled: on a subset of the points its model is fitted once more, on
    /// every point; on every point it freezes.
    fn settle_final(&mut self, on_subset: bool) {
        match self.phase {
            Phase::Final if on_subset => self.subset_settled = true,
            Phase::Final => self.phase = Phase::Frozen,
            Phase::Annealing | Phase::Frozen => {}
        }
    }

    /// Advances the schedule after an update. `below_tolerance`: the update was below the
    /// caller's tolerances; `displacement`: how far it moved the rows (normalised RMS). A level
    /// ends when the update is small against the model width σ+β (or after
    /// MAX_LEVEL_UPDATES); β then shrinks (§4.3), and once β ≪ σ the final round begins (for a
    /// warm start also after a first level that moved the rows by less than WARM_HELD_WIDTHS).
    /// `on_subset`: the update matched a subset of the points (see [`Self::final_fit_on_subset`]).
    pub fn after_update(&mut self, below_tolerance: bool, displacement: f64, on_subset: bool) -> Convergence {
        let settled = below_tolerance || displacement <= LEVEL_TOLERANCE * self.width();
        match self.phase {
            Phase::Annealing => {
                self.level_updates += 1;
                self.level_motion += displacement;
                let warm_guess_held = self.beta.warm().is_some()
                    && self.first_level
                    && self.level_motion <= WARM_HELD_WIDTHS * self.width();
                // Such a first level only seeds the final round, which refines to the full
                // tolerance anyway: it may end at a looser one.
                let held_and_settled = warm_guess_held && displacement <= WARM_HELD_TOLERANCE * self.width();
                if settled || held_and_settled || self.level_updates >= MAX_LEVEL_UPDATES {
                    self.level_updates = 0;
                    self.level_motion = 0.0;
                    self.first_level = false;
                    let stop_ratio = match self.beta.warm() {
                        Some(_) => WARM_FINAL_RATIO,
                        None => self.beta.stop_ratio,
                    };
                    if warm_guess_held || self.estimator.beta_negligible(stop_ratio) {
                        self.phase = Phase::Final;
                        if self.beta.warm().is_some() {
                            self.estimator.set_beta(&[0.0]);
                        }
                    } else {
                        self.estimator.shrink_beta(self.beta.shrink);
                    }
                }
                Convergence::NotYet
            }
            _ if self.precision_stop == PrecisionStop::Allowed
                && displacement <= PRECISION_FRACTION * self.precision() =>
            {
                // Resolved is settled too (a loop that goes on after a subset's update fits
                // the model on every point next).
                self.settle_final(on_subset);
                Convergence::Resolved
            }
            Phase::Final => {
                // After a subset's update settled, one fit on every point sets the model.
                if settled || (self.subset_settled && !on_subset) {
                    self.settle_final(on_subset);
                }
                Convergence::Tolerance
            }
            Phase::Frozen => Convergence::ToleranceOrCycle,
        }
    }
}

/// ‖row‖ of a row-major matrix.
pub(crate) fn row_norm(values: &[f64], cols: usize, row: usize) -> f64 {
    values[row * cols..(row + 1) * cols]
        .iter()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The final round on a subset of the points: its updates stay on the subset until one
    /// settles; the next update, on every point, fits the model once more and freezes it,
    /// settled or not (σ from every point, no second settling).
    #[test]
    fn a_settled_subset_update_leaves_one_fit_on_every_point_before_the_freeze() {
        let residuals: Vec<f64> = (0..2000).map(|k| 0.01 * ((k as f64) * 0.77).sin()).collect();
        let mut weights = vec![0.0; residuals.len()];
        let beta = BetaSchedule {
            start: BetaStart::Fixed(1e-6),
            shrink: 0.5,
            stop_ratio: 1.0,
        };
        let mut schedule = Schedule::new(SieOptions::default(), beta, PrecisionStop::Never);
        schedule.weigh(&residuals, 1, |_| 1.0, &mut weights);
        // β is already ≪ σ: the first settled level begins the final round.
        assert_eq!(schedule.after_update(true, 0.0, false), Convergence::NotYet);
        assert!(schedule.final_fit_on_subset());
        assert_eq!(schedule.after_update(false, 1.0, true), Convergence::Tolerance);
        assert!(
            schedule.final_fit_on_subset(),
            "an unsettled subset update keeps the subset"
        );
        assert_eq!(schedule.after_update(true, 0.0, true), Convergence::Tolerance);
        assert!(!schedule.final_fit_on_subset() && !schedule.model_frozen());
        assert_eq!(schedule.after_update(false, 1.0, false), Convergence::Tolerance);
        assert!(schedule.model_frozen());
    }

    /// Any finite σ > 0 is a warm start, at either end of f64's range; the RMS over several
    /// histograms neither overflows nor underflows. Before: σ = 1e300 was refused as "got inf".
    #[test]
    fn warm_starts_take_any_finite_positive_sigma() {
        for (sigma, expected) in [
            (vec![1e300], 1e300),
            (vec![1e-300], 1e-300),
            (vec![f64::MAX, f64::MAX], f64::MAX),
            (vec![0.03, 0.04], (0.0025f64 / 2.0).sqrt()),
        ] {
            let warm = WarmStart::from_fit(&sigma, 2.0, 2.0, 0.5).unwrap();
            assert!(
                (warm.sigma - expected).abs() <= 1e-15 * expected,
                "{sigma:?}: {}",
                warm.sigma
            );
        }
        let error = WarmStart::from_fit(&[0.01, f64::INFINITY], 2.0, 2.0, 0.5).unwrap_err();
        assert!(error.contains("got inf"), "{error}");
    }
}
