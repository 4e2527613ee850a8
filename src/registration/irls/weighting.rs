//! How a run weighs its rows: SIE's schedule (§4.3, §4.5) or a baseline cost (§5).

use super::plan::{RunCost, RunPlan};
use crate::cost::{CostFunction, baseline_weight, baseline_weights};
use crate::registration::problem::Rows;
use crate::sie::HistogramModel;
use crate::sie::schedule::{Convergence, PrecisionStop, Schedule};

/// How correspondences are weighted.
pub(crate) enum Weighting {
    Sie(Box<Schedule>),
    Baseline {
        cost: CostFunction,
        scale: f64,
        /// The scale (Student-t) of the final rows' weights …
        final_scale: f64,
        /// … and the largest of them, which their probabilities are relative to.
        largest: f64,
    },
}

/// The fitted noise model as the result reports it.
pub(crate) struct ModelSummary {
    /// σ_j per histogram (the baseline's scale for other costs).
    pub(crate) sigma: Vec<f64>,
    /// β_j per histogram (empty for baselines).
    pub(crate) beta: Vec<f64>,
    /// k of the first histogram (0 for baselines).
    pub(crate) penalty: f64,
    /// Noise shape p (the mean over histograms).
    pub(crate) noise_shape: f64,
}

impl Weighting {
    pub(crate) fn new(plan: &RunPlan, precision_stop: PrecisionStop) -> Self {
        match &plan.cost {
            RunCost::Sie { options, beta } => {
                Weighting::Sie(Box::new(Schedule::new(options.clone(), *beta, precision_stop)))
            }
            RunCost::Baseline(cost) => Weighting::Baseline {
                cost: *cost,
                scale: 0.0,
                final_scale: 0.0,
                largest: 0.0,
            },
        }
    }

    pub(crate) fn annealing(&self) -> bool {
        matches!(self, Weighting::Sie(schedule) if schedule.annealing())
    }

    /// SIE's final round fitting its model, no subset's update settled yet (never for
    /// baselines): the updates may match the medium subset.
    pub(crate) fn final_fit_on_subset(&self) -> bool {
        matches!(self, Weighting::Sie(schedule) if schedule.final_fit_on_subset())
    }

    /// SIE's final round with its model held fixed (never for baselines).
    pub(crate) fn model_frozen(&self) -> bool {
        matches!(self, Weighting::Sie(schedule) if schedule.model_frozen())
    }

    /// The model's width σ+β (normalised); infinite for baselines (they never travel coarse).
    pub(crate) fn width(&self) -> f64 {
        match self {
            Weighting::Sie(schedule) => schedule.width(),
            Weighting::Baseline { .. } => f64::INFINITY,
        }
    }

    /// The smallest σ the data can show (SIE only).
    pub(crate) fn set_resolution(&mut self, resolution: f64) {
        if let Weighting::Sie(schedule) = self {
            schedule.set_resolution(resolution);
        }
    }

    /// Fits the cost to this iteration's residuals (`normalised`: divided by F) and fills
    /// `weights`.
    pub(crate) fn update(&mut self, rows: &Rows, normalised: &[f64], cols: usize, weights: &mut Vec<f64>) {
        weights.resize(rows.len(), 0.0);
        match self {
            Weighting::Sie(schedule) => schedule.weigh(normalised, cols, |row| rows.scale.get(row), weights),
            Weighting::Baseline { cost, scale, .. } => {
                *scale = baseline_weights(*cost, normalised, cols, weights);
                if let Some(scales) = rows.scale.per_row() {
                    for (w, f) in weights.iter_mut().zip(scales) {
                        *w /= f * f;
                    }
                }
            }
        }
    }

    /// Which convergence tests apply after this update (SIE: only once β ≪ σ).
    pub(crate) fn after_update(
        &mut self,
        below_tolerance: bool,
        displacement: f64,
        on_subset: bool,
    ) -> Convergence {
        match self {
            Weighting::Sie(schedule) => schedule.after_update(below_tolerance, displacement, on_subset),
            Weighting::Baseline { .. } => Convergence::ToleranceOrCycle,
        }
    }

    /// Per-row probabilities at the final transform: P(I|r) for SIE, weight / max weight otherwise.
    pub(crate) fn final_probabilities(
        &mut self,
        normalised: &[f64],
        cols: usize,
        probabilities: &mut Vec<f64>,
    ) {
        probabilities.resize(normalised.len() / cols, 0.0);
        match self {
            Weighting::Sie(schedule) => {
                schedule.probabilities(normalised, cols, probabilities);
            }
            Weighting::Baseline {
                cost,
                final_scale,
                largest,
                ..
            } => {
                // The weights computed in place: no second buffer at the registration's peak.
                *final_scale = baseline_weights(*cost, normalised, cols, probabilities);
                *largest = probabilities.iter().cloned().fold(0.0, f64::max);
                for p in probabilities.iter_mut() {
                    *p = if *largest > 0.0 { *p / *largest } else { 0.0 };
                }
            }
        }
    }

    /// The probability [`Weighting::final_probabilities`] gives one normalised residual row
    /// (any values, not only the final rows'), under the same final model.
    pub(crate) fn row_probability(&self, row: &[f64]) -> f64 {
        match self {
            Weighting::Sie(schedule) => schedule.row_probability(row),
            Weighting::Baseline {
                cost,
                final_scale,
                largest,
                ..
            } => {
                if *largest > 0.0 {
                    baseline_weight(*cost, row, final_scale * final_scale) / largest
                } else {
                    0.0
                }
            }
        }
    }

    /// Σ P(I|R_i) of the last update over `considered` source points (SIE), or the baseline's
    /// weights relative to the largest: the trace's inlier fraction.
    pub(crate) fn inlier_fraction(&self, weights: &[f64], considered: f64) -> f64 {
        match self {
            Weighting::Sie(schedule) => schedule.inlier_mass() / considered,
            Weighting::Baseline { .. } => {
                let largest = weights.iter().cloned().fold(0.0, f64::max);
                if largest > 0.0 {
                    weights.iter().sum::<f64>() / (considered * largest)
                } else {
                    0.0
                }
            }
        }
    }

    pub(crate) fn summary(&self) -> ModelSummary {
        match self {
            Weighting::Sie(schedule) => {
                let models = schedule.estimator().models();
                ModelSummary {
                    sigma: models.iter().map(|m| m.inlier.sigma).collect(),
                    beta: models.iter().map(|m| m.beta).collect(),
                    penalty: models.first().map_or(0.0, |m| m.penalty),
                    noise_shape: schedule.estimator().noise_shape(),
                }
            }
            Weighting::Baseline { scale, .. } => ModelSummary {
                sigma: vec![*scale],
                beta: Vec::new(),
                penalty: 0.0,
                noise_shape: 2.0,
            },
        }
    }

    /// The fitted histograms (none for baselines).
    pub(crate) fn histograms(&self) -> Vec<HistogramModel> {
        match self {
            Weighting::Sie(schedule) => schedule.estimator().models().to_vec(),
            Weighting::Baseline { .. } => Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row's probability alone is what the final probabilities gave it, for a baseline whose
    /// scale is estimated from all the rows (Student-t) as for one with a fixed scale.
    #[test]
    fn a_row_alone_has_its_final_probability() {
        let residuals: Vec<f64> = (0..300)
            .map(|k| 0.05 * ((k as f64) * 0.77).sin() * (1.0 + (k % 7) as f64))
            .collect();
        for cost in [
            CostFunction::StudentT { dof: 5.0 },
            CostFunction::Cauchy { scale: 0.1 },
        ] {
            let mut weighting = Weighting::Baseline {
                cost,
                scale: 0.0,
                final_scale: 0.0,
                largest: 0.0,
            };
            let mut probabilities = Vec::new();
            weighting.final_probabilities(&residuals, 3, &mut probabilities);
            for (row, p) in residuals.chunks_exact(3).zip(&probabilities) {
                let alone = weighting.row_probability(row);
                assert!((alone - p).abs() < 1e-12, "{cost:?}: {alone} vs {p}");
            }
        }
    }
}
