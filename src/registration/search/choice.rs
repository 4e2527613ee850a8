//! The choice between the results of several starts on one problem: each is judged on every
//! row at the scale its own fit claims (`significance::at_scale`), the most significant one is
//! kept, and how the others relate to it (the same pose or another) goes into its report.

use nalgebra::Matrix4;

use crate::registration::irls::{FinalModel, PendingPerPoint};
use crate::registration::problem::{Problem, moved_apart};
use crate::registration::result::{RegistrationResult, StartKind, StopReason, TraceEntry};
use crate::registration::verdict::{Evidence, verdict};

/// The most significant result of SIE from several starts on one problem, each judged on
/// every row at the scale its own fit claims (`significance::at_scale`).
pub(crate) struct BestOfStarts {
    pub(crate) evidence: Evidence,
    best: Option<Best>,
    /// Where every start ended.
    ends: Vec<End>,
    /// Number of the next update (the runs are numbered on).
    pub(crate) next_iteration: u32,
    /// The median row scale at the last offer (the units `moved_apart` compares poses in).
    typical_scale: f64,
    pub(crate) starts_run: u32,
    /// Every start's trace entries, in the order they ran (the result reports all updates).
    pub(crate) trace: Vec<TraceEntry>,
}

/// Where a start ended, and how precisely its data place it there (both as row
/// displacements, the units `moved_apart` compares poses in).
struct End {
    transform: Matrix4<f64>,
    significance: f64,
    /// The pose's standard error: σ·√(6 / inliers).
    precision: f64,
    /// The fitted inlier σ (RMS over the histograms).
    sigma: f64,
}

impl End {
    /// How far from `best` a start may end and still be at the same pose: a few standard
    /// errors, and never less than the best's noise width. ICP's discrete matching stops
    /// starts within the noise of each other (0.1° and 1.4 cm apart at σ 3.9 cm on real scans)
    /// where √N makes the standard error tiny; the best's inlier model cannot tell such poses
    /// apart. (Not the other's σ: a start that fitted wide noise elsewhere is a rival.)
    fn same_pose_within(&self, best: &End) -> f64 {
        (SAME_POSE_ERRORS * self.precision.max(best.precision)).max(SAME_POSE_WIDTHS * best.sigma)
    }
}

/// The best start so far.
struct Best {
    significance: f64,
    result: RegistrationResult,
    /// What its per-point results are rebuilt from (ICP starts).
    model: Option<FinalModel>,
    /// Its per-point results were dropped while later starts ran (see `BestOfStarts::park`).
    parked: bool,
}

impl BestOfStarts {
    pub(crate) fn new(evidence: Evidence) -> Self {
        BestOfStarts {
            evidence,
            best: None,
            ends: Vec::new(),
            next_iteration: 1,
            typical_scale: 1.0,
            starts_run: 0,
            trace: Vec::new(),
        }
    }

    /// Scores a run's result (its rows, at its transform, are the problem's last rows) and
    /// keeps it if it is the best so far; pending per-point results are spread only when it
    /// is kept (after the result it replaces is freed). False when the run was cancelled: no
    /// more starts.
    pub(crate) fn offer(
        &mut self,
        problem: &mut dyn Problem,
        mut result: RegistrationResult,
        pending: Option<PendingPerPoint>,
        start: StartKind,
    ) -> bool {
        self.starts_run += 1;
        self.next_iteration = result.iterations + 1;
        self.trace.append(&mut result.trace);
        let cluster = self.evidence.assess(problem, &mut result);
        // Before the rows may be taken below; `finish` compares poses in these units.
        self.typical_scale = problem.rows().scale.median();
        let significance = cluster.significance;
        let precision = result.sigma_rms() * (6.0 / (cluster.count.max(1) as f64)).sqrt();
        self.ends.push(End {
            transform: result.transform,
            significance,
            precision,
            sigma: result.sigma_rms(),
        });
        result.search.start = start;
        result.search.significance = significance;
        let cancelled = result.stop_reason == StopReason::Cancelled;
        // A cancelled run's transform is the one the caller stopped at: report it. A start that
        // ends at the best pose so far (within its precision) replaces it only when clearly more
        // significant (a better noise model there): near-ties between equal poses are rounding,
        // and the earlier start (the paper's) is kept.
        let replaces = match &self.best {
            None => true,
            Some(Best {
                significance: best_significance,
                result: best,
                ..
            }) => {
                significance > *best_significance
                    && (significance > SAME_POSE_TIE * *best_significance || {
                        let best_precision = self
                            .ends
                            .iter()
                            .find(|end| end.transform == best.transform)
                            .map_or(precision, |end| end.precision);
                        let apart = moved_apart(problem.probe_points(), &best.transform, &result.transform)
                            / self.typical_scale;
                        apart > SAME_POSE_ERRORS * precision.max(best_precision)
                    })
            }
        };
        if cancelled || replaces {
            self.best = None;
            let model = pending.map(|pending| pending.spread_last(problem, &mut result));
            self.best = Some(Best {
                significance,
                result,
                model,
                parked: false,
            });
        }
        !cancelled
    }

    /// The best result's transform and fitted σ (RMS over the histograms), if a start ran.
    pub(crate) fn best_pose(&self) -> Option<(Matrix4<f64>, f64)> {
        self.best
            .as_ref()
            .map(|best| (best.result.transform, best.result.sigma_rms()))
    }

    /// Counts a start that is no rival to the best (`half_turns`): its updates are numbered
    /// and traced, its pose is not compared.
    pub(crate) fn pass_over(&mut self, mut result: RegistrationResult) {
        self.starts_run += 1;
        self.next_iteration = result.iterations + 1;
        self.trace.append(&mut result.trace);
    }

    /// Drops the best result's per-point results before another start runs (`finish`
    /// rebuilds them): at 10 M points they are 153 MiB of the registration's peak, and
    /// rebuilding costs one pass over the source points.
    pub(crate) fn park(&mut self) {
        if let Some(best) = self.best.as_mut().filter(|best| best.model.is_some()) {
            best.result.probabilities = Vec::new();
            best.result.correspondences = Vec::new();
            best.parked = true;
        }
    }

    /// The best result, with how the other starts' results relate to it: how many ended at
    /// the same pose (within a few standard errors of either, or the noise width), and the significance of the best
    /// one that did not.
    pub(crate) fn finish(self, problem: &mut dyn Problem) -> RegistrationResult {
        let typical_scale = self.typical_scale;
        let Best {
            mut result,
            model,
            parked,
            ..
        } = self.best.expect("at least one start ran");
        result.iterations = self.next_iteration - 1;
        result.trace = self.trace;
        result.search.starts_run = self.starts_run;
        let (mut agreeing, mut runner_up) = (0, 0.0f64);
        let best_end = self.ends.iter().find(|end| end.transform == result.transform);
        for end in &self.ends {
            let apart =
                moved_apart(problem.probe_points(), &result.transform, &end.transform) / typical_scale;
            if apart <= end.same_pose_within(best_end.unwrap_or(end)) {
                agreeing += 1;
            } else {
                runner_up = runner_up.max(end.significance);
            }
        }
        result.search.agreeing_starts = agreeing;
        result.search.runner_up_significance = runner_up;
        result.quality.margin = if runner_up > 0.0 {
            result.quality.significance / runner_up
        } else {
            f64::INFINITY
        };
        result.quality.verdict = verdict(&result);
        // Last: the rows the agreement above was measured with are the last start's.
        if let Some(model) = model.filter(|_| parked) {
            model.evaluate_again(problem).spread_last(problem, &mut result);
        }
        result
    }
}

/// Between two results at the same pose, the later must be this many times as significant to
/// replace the earlier.
const SAME_POSE_TIE: f64 = 1.05;

/// Two starts' results are the same pose when they are this many standard errors apart or
/// closer (as row displacements) …
const SAME_POSE_ERRORS: f64 = 3.0;
/// … or, when judging rivals, this many noise widths.
const SAME_POSE_WIDTHS: f64 = 1.0;
