//! One run's own plan: how it weighs the rows (SIE from a chosen β₀, or a baseline cost),
//! which source points its updates match, and when it stops. Every start of a registration
//! builds its plan from the caller's config; nothing else of the config reaches the loop.

use crate::cost::CostFunction;
use crate::registration::config::{RegistrationConfig, Starts};
use crate::sie::SieOptions;
use crate::sie::schedule::{BetaSchedule, BetaStart};

/// How one run of the IRLS loop goes.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct RunPlan {
    /// What weighs the rows.
    pub(crate) cost: RunCost,
    /// Which source points the updates match (ICP; fixed pairs have no choice).
    pub(crate) matching: Matching,
    /// When the run stops.
    pub(crate) stop: StopRule,
    /// Keep one `TraceEntry` per update in the result (an observer sees them either way).
    pub(crate) record_trace: bool,
    /// How SIE's final round on re-matched pairs moves (`irls::extrapolation`).
    pub(crate) final_round: FinalRound,
}

/// How the updates of SIE's final round on re-matched pairs (ICP) move the pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum FinalRound {
    /// Where updates shrink geometrically along one direction, on to where they lead.
    Extrapolated,
    /// Update by update: a screen's short run (`RunPlan::settling`), whose thresholds were
    /// set on plain updates.
    Plain,
}

/// The cost of a run.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum RunCost {
    /// SIE with these settings and this β schedule (§4.3).
    Sie {
        /// The estimator's settings.
        options: SieOptions,
        /// Where β starts and how it shrinks.
        beta: BetaSchedule,
    },
    /// A fixed robust cost: the caller's baseline, or a scale-free lead.
    Baseline(CostFunction),
}

/// Which source points an update matches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Matching {
    /// The coarse subset while β is annealed or the pose is still travelling (the basin, not
    /// the last digit), every sampled point afterwards.
    CoarseWhileSearching,
    /// The coarse subset on every update: a lead only has to reach the basin.
    CoarseThroughout,
    /// The verdict's evidence subset on every update: a rival screened by its significance
    /// there only has to show where it leads.
    EvidenceThroughout,
}

/// When a run stops (besides convergence as its cost defines it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct StopRule {
    /// Updates at most.
    pub(crate) max_updates: u32,
    /// An update that moves the source centroid by less than this (input units) …
    pub(crate) translation_tolerance: f64,
    /// … and rotates by less than this (radians) is small.
    pub(crate) rotation_tolerance: f64,
}

impl RunPlan {
    /// The caller's run: SIE with β₀ = `initial_beta`, else the warm start's, else the RMS of
    /// the first residuals (§4.3); or the caller's baseline cost.
    pub(crate) fn from_config(config: &RegistrationConfig) -> Self {
        let cost = match config.cost {
            CostFunction::Sie => RunCost::Sie {
                options: config.sie.clone(),
                beta: BetaSchedule {
                    start: match (config.initial_beta, config.warm_start) {
                        (Some(beta), _) => BetaStart::Fixed(beta),
                        (None, Some(warm)) => BetaStart::Warm(warm),
                        (None, None) => BetaStart::ResidualRms,
                    },
                    shrink: config.beta_shrink,
                    stop_ratio: config.beta_stop_ratio,
                },
            },
            cost => RunCost::Baseline(cost),
        };
        RunPlan {
            cost,
            matching: Matching::CoarseWhileSearching,
            stop: StopRule {
                max_updates: config.max_iterations,
                translation_tolerance: config.translation_tolerance,
                rotation_tolerance: config.rotation_tolerance,
            },
            record_trace: config.record_trace,
            final_round: FinalRound::Extrapolated,
        }
    }

    /// A start of the search: SIE from β₀ = `beta` (normalised units).
    pub(crate) fn starting_at_beta(&self, beta: f64) -> Self {
        self.with_beta_start(BetaStart::Fixed(beta))
    }

    /// The caller's run without its warm start (after a warm run whose model did not hold).
    pub(crate) fn cold(&self) -> Self {
        match &self.cost {
            RunCost::Sie {
                beta:
                    BetaSchedule {
                        start: BetaStart::Warm(_),
                        ..
                    },
                ..
            } => self.with_beta_start(BetaStart::ResidualRms),
            _ => self.clone(),
        }
    }

    /// A scale-free lead (L1 IRLS on the coarse subset) that stops once its updates are below
    /// these tolerances: it only has to reach the basin, SIE does the rest.
    pub(crate) fn scale_free_lead(&self, translation_tolerance: f64, rotation_tolerance: f64) -> Self {
        RunPlan {
            cost: RunCost::Baseline(CostFunction::Lp { p: 1.0 }),
            matching: Matching::CoarseThroughout,
            stop: StopRule {
                translation_tolerance,
                rotation_tolerance,
                ..self.stop
            },
            record_trace: self.record_trace,
            final_round: self.final_round,
        }
    }

    /// The caller's cold run on the coarse subset, at most `max_updates` updates, no trace:
    /// where a start leads, for screening it before a full run.
    pub(crate) fn settling(&self, max_updates: u32) -> Self {
        RunPlan {
            matching: Matching::CoarseThroughout,
            stop: StopRule {
                max_updates,
                ..self.stop
            },
            record_trace: false,
            final_round: FinalRound::Plain,
            ..self.cold()
        }
    }

    /// [`RunPlan::settling`] on the evidence subset (a fifth of the coarse one): for rivals
    /// many of which lead nowhere.
    pub(crate) fn settling_on_evidence(&self, max_updates: u32) -> Self {
        RunPlan {
            matching: Matching::EvidenceThroughout,
            ..self.settling(max_updates)
        }
    }

    /// Whether the run is SIE from the paper's β₀ (the RMS of the residuals at its start), not
    /// from a β₀ the caller or a warm start fixed.
    pub(crate) fn starts_at_residual_rms(&self) -> bool {
        matches!(
            self.cost,
            RunCost::Sie {
                beta: BetaSchedule {
                    start: BetaStart::ResidualRms,
                    ..
                },
                ..
            }
        )
    }

    /// Whether the run weighs with SIE.
    pub(crate) fn is_sie(&self) -> bool {
        matches!(self.cost, RunCost::Sie { .. })
    }

    fn with_beta_start(&self, start: BetaStart) -> Self {
        let mut plan = self.clone();
        if let RunCost::Sie { beta, .. } = &mut plan.cost {
            beta.start = start;
        }
        plan
    }
}

/// Whether a registration leaves SIE's start to the search (`Starts::Automatic`, or
/// `Starts::Global`, which is the same for correspondences; SIE, β₀ not fixed by the caller): a
/// fixed β₀ means one run from the initial guess, as the C header says.
pub(crate) fn searches_starts(config: &RegistrationConfig) -> bool {
    config.cost == CostFunction::Sie
        && matches!(config.starts, Starts::Automatic | Starts::Global)
        && config.initial_beta.is_none()
}

/// Whether ICP starts from the global stage's poses (`Starts::Global`, under the same rule).
pub(crate) fn searches_globally(config: &RegistrationConfig) -> bool {
    searches_starts(config) && config.starts == Starts::Global
}
