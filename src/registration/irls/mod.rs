//! The IRLS loop (eq. regprob2) shared by correspondence registration and ICP: match, weigh
//! (SIE's schedule of §4.3/§4.5, or a baseline cost), solve, stop; then the report at the
//! transform reached. Each run follows its own [`RunPlan`].

mod extrapolation;
mod per_point;
mod plan;
mod weighting;

use std::ops::ControlFlow;
use std::time::Instant;

use nalgebra::Matrix4;

use super::covariance::RowWeight;
use super::hooks::Observer;
use super::problem::{Problem, RowScales, Rows, StepPoints};
use super::result::{
    Quality, RegistrationResult, SearchReport, StageTimes, StartKind, StopReason, TraceEntry,
};
use crate::geometry::transform_change;
use crate::sie::schedule::{Convergence, PrecisionStop};
use extrapolation::Extrapolation;
pub(crate) use per_point::{FinalModel, PendingPerPoint};
pub(crate) use plan::{FinalRound, Matching, RunPlan, searches_globally, searches_starts};
use weighting::Weighting;

/// Residuals divided by F, the IRLS weights (eq. regprob2), and the final evaluation's
/// per-row probabilities (an update needs only the weights: one row buffer less at the peak).
#[derive(Default)]
struct Workspace {
    normalised: Vec<f64>,
    weights: Vec<f64>,
    probabilities: Vec<f64>,
}

/// What a run carries from update to update and into its report.
struct RunState {
    weighting: Weighting,
    work: Workspace,
    times: StageTimes,
}

/// sqrt(Σ w_i‖r_i‖² / Σ w_i) over the rows of weight > 0, scaled by the largest norm so that
/// residuals whose squares overflow (coordinates near 1e160) still give a finite answer; rows
/// whose norm is not finite are left out (a garbage point far out). 0 without weight.
fn weighted_rms(residual: &[f64], cols: usize, weights: &[f64]) -> f64 {
    let norm = |i: usize| {
        let row = &residual[i * cols..(i + 1) * cols];
        let largest = row.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if largest > 0.0 && largest.is_finite() {
            largest * row.iter().map(|v| (v / largest).powi(2)).sum::<f64>().sqrt()
        } else {
            largest
        }
    };
    let counted = || {
        weights
            .iter()
            .enumerate()
            .filter(|(_, w)| **w > 0.0)
            .map(move |(i, &w)| (w, norm(i)))
            .filter(|(_, n)| n.is_finite())
    };
    let largest = counted().fold(0.0f64, |m, (_, n)| m.max(n));
    let weight_sum: f64 = counted().map(|(w, _)| w).sum();
    if largest == 0.0 || weight_sum <= 0.0 {
        return 0.0;
    }
    let scaled: f64 = counted().map(|(w, n)| w * (n / largest).powi(2)).sum();
    largest * (scaled / weight_sum).sqrt()
}

/// The pose's uncertainty measures the slope of the weighted residual P(u)·u over ± this
/// fraction of the inliers' spread (`covariance::RowWeight`).
const SLOPE_STEP: f64 = 0.25;

/// An update that moved the rows by more than this many model widths σ+β: the pose is still
/// travelling (see [`iterate`]).
const TRAVEL_WIDTHS: f64 = 1.0;

/// Updates on the medium subset while SIE fits its final model, at most: a fit that has not
/// settled by then (very uneven per-point noise leaves the subset's optimum wandering within
/// its own spread) goes on on every point, as without the subset.
const MEDIUM_SUBSET_UPDATES: u32 = 16;

/// Rounding of coordinates of this magnitude, as a normalised residual (divided by the median
/// row scale F): a few hundred ulps, far below any measured noise.
pub(crate) fn resolution(magnitude: f64, row_scales: &RowScales) -> f64 {
    const ULPS: f64 = 1024.0;
    ULPS * f64::EPSILON * magnitude / row_scales.median()
}

/// The residuals divided by their rows' F: the rows' own residuals when every F is 1,
/// otherwise written into `buffer`.
fn normalised<'a>(rows: &'a Rows, cols: usize, buffer: &'a mut Vec<f64>) -> &'a [f64] {
    let Some(scales) = rows.scale.per_row() else {
        return &rows.residual;
    };
    buffer.clear();
    // Exact: grown by doubling, a 10 M-row buffer would hold 16.7 M.
    buffer.reserve_exact(rows.residual.len());
    buffer.extend(
        rows.residual
            .chunks_exact(cols)
            .zip(scales)
            .flat_map(|(row, f)| row.iter().map(move |r| r / f)),
    );
    buffer
}

/// One run of the IRLS loop (eq. regprob2) by `plan`; for SIE with its β schedule: run to
/// convergence, shrink β, repeat until β ≪ σ, then a final round with adaptive k (§4.3, §4.5).
/// Updates are numbered from `first_iteration` (the runs from several starts of one
/// registration are numbered on). Every per-point result is filled.
pub(crate) fn run(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let (mut result, per_point) = run_pending(problem, init, first_iteration, plan, observer);
    per_point.spread(problem, &mut result);
    result
}

/// [`run`] with the per-point results left pending (`result.probabilities` and
/// `result.correspondences` empty); the problem's rows are the final evaluation's.
pub(crate) fn run_pending(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
) -> (RegistrationResult, PendingPerPoint) {
    let mut state = RunState::new(problem, plan);
    let end = iterate(problem, init, first_iteration, plan, &mut state, observer, None);
    report(problem, end, state)
}

/// Asked before each update of SIE's final round, at the pose reached, whether the run is
/// worth going on (`ControlFlow::Break`: not).
pub(crate) type FinalRoundGate<'a> = dyn FnMut(&mut dyn Problem, &Matrix4<f64>) -> ControlFlow<()> + 'a;

/// How a run with a [`FinalRoundGate`] ended.
pub(crate) enum GatedRun {
    /// As [`run_pending`] (boxed: the result is large).
    Finished(Box<RegistrationResult>, PendingPerPoint),
    /// The gate stopped it in its final round.
    Dropped {
        /// The number of the last update made.
        iterations: u32,
        /// The updates made, when the plan records them.
        trace: Vec<TraceEntry>,
    },
}

/// [`run_pending`], with `gate` asked before each update of the final round whether to go on.
pub(crate) fn run_pending_gated(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
    gate: &mut FinalRoundGate<'_>,
) -> GatedRun {
    let mut state = RunState::new(problem, plan);
    let end = iterate(
        problem,
        init,
        first_iteration,
        plan,
        &mut state,
        observer,
        Some(gate),
    );
    if end.dropped {
        return GatedRun::Dropped {
            iterations: end.iterations,
            trace: end.trace,
        };
    }
    let (result, pending) = report(problem, end, state);
    GatedRun::Finished(Box::new(result), pending)
}

/// The updates of `plan` from `init` without the report (no final evaluation, no per-point
/// results): where a run leads, for screening a start before paying for a full run.
pub(crate) fn settle(problem: &mut dyn Problem, init: Matrix4<f64>, plan: &RunPlan) -> Matrix4<f64> {
    let mut state = RunState::new(problem, plan);
    iterate(problem, init, 1, plan, &mut state, None, None).transform
}

impl RunState {
    /// A run's start: `plan`'s weighting (a precision stop only where the pairs re-match),
    /// empty buffers, no time spent.
    fn new(problem: &dyn Problem, plan: &RunPlan) -> Self {
        let precision_stop = if problem.rematches() {
            PrecisionStop::Allowed
        } else {
            PrecisionStop::Never
        };
        RunState {
            weighting: Weighting::new(plan, precision_stop),
            work: Workspace::default(),
            times: StageTimes::default(),
        }
    }
}

/// Where the loop ended.
struct LoopEnd {
    transform: Matrix4<f64>,
    stop: StopReason,
    /// The number of the last update made.
    iterations: u32,
    /// Of the last solve (`geometry::Solve::conditioning`).
    conditioning: f64,
    trace: Vec<TraceEntry>,
    /// The final-round gate stopped the run.
    dropped: bool,
}

/// Wall time since the last lap, added to a stage.
struct Laps(Instant);

impl Laps {
    fn lap(&mut self, stage: &mut f64) {
        let now = Instant::now();
        *stage += (now - self.0).as_secs_f64();
        self.0 = now;
    }
}

/// The updates: match, weigh, solve, until the plan's stop rule or the cost's convergence, or
/// until `gate` stops the run in its final round.
fn iterate(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    state: &mut RunState,
    mut observer: Option<&mut Observer<'_>>,
    mut gate: Option<&mut FinalRoundGate<'_>>,
) -> LoopEnd {
    let RunState {
        weighting,
        work,
        times,
    } = state;
    let cols = problem.cols();
    let anchor = problem.source_anchor();
    let stop_rule = plan.stop;
    let mut transform = init;
    // The transform before the last update, for the 2-cycle test below.
    let mut previous = init;
    let mut stop = StopReason::IterationLimit;
    let mut rank_deficient = false;
    let mut conditioning = 0.0;
    let mut iterations = first_iteration.saturating_sub(1);
    let mut trace = Vec::new();
    let mut laps = Laps(Instant::now());
    // An update that moved the rows by more than the model's width: the pose is still travelling,
    // and a coarse subset of the matches steers as well as all of them (no convergence is
    // declared on such an update).
    let mut travelling = false;
    let mut extrapolation = Extrapolation::default();
    // The medium subset ends for the rest of the run when its solve is rank-deficient (the
    // subset does not fix the pose where every point may: very uneven per-point noise leaves a
    // few rows most of the weight) or after MEDIUM_SUBSET_UPDATES updates without settling.
    let mut medium_subset_refused = false;
    let mut medium_subset_updates = 0;
    let mut dropped = false;
    for iteration in first_iteration..first_iteration.saturating_add(stop_rule.max_updates) {
        if iteration > first_iteration && !weighting.annealing() {
            if let Some(worth_going_on) = gate.as_mut() {
                dropped = worth_going_on(&mut *problem, &transform).is_break();
                if dropped {
                    break;
                }
            }
        }
        laps.lap(&mut 0.0);
        let searching = weighting.annealing() || travelling;
        let points = match plan.matching {
            Matching::EvidenceThroughout => StepPoints::Evidence,
            Matching::CoarseThroughout => StepPoints::Coarse,
            Matching::CoarseWhileSearching if searching => StepPoints::Coarse,
            Matching::CoarseWhileSearching
                if !medium_subset_refused
                    && weighting.final_fit_on_subset()
                    && problem.steps_on_subset(StepPoints::Medium) =>
            {
                StepPoints::Medium
            }
            Matching::CoarseWhileSearching => StepPoints::Sample,
        };
        // The plan's answer is the optimum of every sampled point: an update on a subset of
        // them (coarse while travelling, medium while the final model is fitted) only steers
        // there, and neither settles the model nor ends the run.
        let on_subset = plan.matching == Matching::CoarseWhileSearching && problem.steps_on_subset(points);
        problem.linearise(&transform, points);
        laps.lap(&mut times.matching);
        let rows = problem.rows();
        if rows.is_empty() {
            stop = StopReason::Degenerate;
            break;
        }
        if iteration == first_iteration {
            weighting.set_resolution(resolution(problem.coordinate_magnitude(), &rows.scale));
        }
        let normalised = normalised(rows, cols, &mut work.normalised);
        weighting.update(rows, normalised, cols, &mut work.weights);
        laps.lap(&mut times.weighting);
        let solve = problem.solve(&transform, &work.weights);
        laps.lap(&mut times.solve);
        let Some(solve) = solve else {
            stop = StopReason::Degenerate;
            break;
        };
        if points == StepPoints::Medium {
            if solve.rank_deficient {
                medium_subset_refused = true;
                continue;
            }
            medium_subset_updates += 1;
            medium_subset_refused = medium_subset_updates >= MEDIUM_SUBSET_UPDATES;
        }
        iterations = iteration;
        let rows = problem.rows();
        let (rotation_change, translation_change) = transform_change(&transform, &solve.transform, &anchor);
        let displacement = problem.displacement(&transform, &solve.transform);
        let (cycle_rotation, cycle_translation) = transform_change(&previous, &solve.transform, &anchor);
        previous = transform;
        transform = solve.transform;
        rank_deficient = solve.rank_deficient;
        conditioning = solve.conditioning;
        if plan.record_trace || observer.is_some() {
            let entry = trace_entry(
                iteration,
                weighting,
                rows,
                cols,
                work,
                &transform,
                (rotation_change, translation_change),
            );
            let cancelled = observer
                .as_mut()
                .is_some_and(|observe| observe(&entry).is_break());
            if plan.record_trace {
                trace.push(entry);
            }
            if cancelled {
                stop = StopReason::Cancelled;
                break;
            }
        }
        let below_tolerance = translation_change <= stop_rule.translation_tolerance
            && rotation_change <= stop_rule.rotation_tolerance;
        // ICP's discrete matching can alternate between two correspondence sets whose optima
        // differ by more than the tolerance: T_{k+1} = T_{k-1}. Further updates only repeat the
        // pair, so a fixed model that returns within tolerance to where it was two updates ago
        // has converged (either member is as good an answer as the data gives).
        let two_cycle = iteration > first_iteration + 1
            && cycle_translation <= stop_rule.translation_tolerance
            && cycle_rotation <= stop_rule.rotation_tolerance;
        travelling = displacement > TRAVEL_WIDTHS * weighting.width();
        let converged = !(searching && travelling)
            && match weighting.after_update(below_tolerance, displacement, on_subset) {
                Convergence::NotYet => false,
                Convergence::Tolerance => below_tolerance,
                Convergence::ToleranceOrCycle => below_tolerance || two_cycle,
                Convergence::Resolved => true,
            }
            && !on_subset;
        if converged {
            stop = StopReason::Converged;
            break;
        }
        // SIE's final round with its model frozen, on re-matched pairs (ICP): the updates then
        // iterate one map of the pose, and creep where the surfaces fix it weakly.
        if plan.final_round == FinalRound::Extrapolated
            && weighting.model_frozen()
            && !travelling
            && problem.rematches()
        {
            transform = extrapolation.next(&*problem, &previous, &transform, weighting.width());
        }
    }
    if rank_deficient && stop != StopReason::Cancelled {
        stop = StopReason::Degenerate;
    }
    LoopEnd {
        transform,
        stop,
        iterations,
        conditioning,
        trace,
        dropped,
    }
}

/// Everything at the transform the loop reached, for every source point. The work buffers are
/// freed as soon as they are done with: the final rows and the per-point results are the
/// registration's peak (8 bytes a point each at 10 M points is 76 MiB).
fn report(problem: &mut dyn Problem, end: LoopEnd, state: RunState) -> (RegistrationResult, PendingPerPoint) {
    let RunState {
        mut weighting,
        mut work,
        mut times,
    } = state;
    let cols = problem.cols();
    let source_count = problem.source_count();
    work.weights = Vec::new();
    let mut laps = Laps(Instant::now());
    problem.evaluate_all(&end.transform);
    laps.lap(&mut times.evaluation);
    let rows = problem.rows();
    let normalised = normalised(rows, cols, &mut work.normalised);
    weighting.final_probabilities(normalised, cols, &mut work.probabilities);
    let spread = weighted_rms(normalised, cols, &work.probabilities) / (cols as f64).sqrt();
    work.normalised = Vec::new();
    // ICP's solves miss sliding along surfaces (point-to-point sees the points' spread,
    // point-to-plane noisy per-point normals): the surfaces' own measure too, the weaker wins.
    let (conditioning, loose_direction) =
        match problem.surface_conditioning(&end.transform, &work.probabilities) {
            Some(surfaces) if surfaces.ratio < end.conditioning => (surfaces.ratio, surfaces.loosest),
            _ => (end.conditioning, None),
        };
    let rows = problem.rows();
    let weight_sum = work.probabilities.iter().fold(0.0, |sum, p| sum + p);
    let rmse = weighted_rms(&rows.residual, cols, &work.probabilities);
    let weight = RowWeight {
        probability: &|row: &[f64]| weighting.row_probability(row),
        step: SLOPE_STEP * spread,
    };
    let uncertainty = problem.pose_uncertainty(&end.transform, &work.probabilities, &weight);
    let model = weighting.summary();
    let result = RegistrationResult {
        transform: end.transform,
        stop_reason: end.stop,
        converged: end.stop == StopReason::Converged,
        iterations: end.iterations,
        sigma: model.sigma,
        beta: model.beta,
        penalty: model.penalty,
        noise_shape: model.noise_shape,
        inlier_fraction: weight_sum / source_count as f64,
        rmse,
        probabilities: Vec::new(),
        correspondences: Vec::new(),
        histograms: weighting.histograms(),
        trace: end.trace,
        times,
        search: SearchReport {
            start: StartKind::InitialGuess,
            hypotheses: 0,
            starts_run: 1,
            significance: 0.0,
            agreeing_starts: 1,
            runner_up_significance: 0.0,
        },
        quality: Quality {
            conditioning,
            loose_direction,
            margin: f64::INFINITY,
            ..Quality::default()
        },
        uncertainty,
    };
    let pending = PendingPerPoint {
        row_probabilities: std::mem::take(&mut work.probabilities),
        model: FinalModel {
            weighting,
            transform: end.transform,
        },
    };
    (result, pending)
}

/// `transform` is the one this iteration's update reached; `(rotation_change,
/// translation_change)` the update's size.
fn trace_entry(
    iteration: u32,
    weighting: &Weighting,
    rows: &Rows,
    cols: usize,
    work: &Workspace,
    transform: &Matrix4<f64>,
    (rotation_change, translation_change): (f64, f64),
) -> TraceEntry {
    let model = weighting.summary();
    let n = rows.len();
    // The summary's meaning, Σ P / source points (unmatched count 0), over the points this
    // iteration looked at (all of them, or the sample).
    let considered = rows.considered.max(n).max(1) as f64;
    let rmse = weighted_rms(&rows.residual, cols, &work.weights[..n]);
    TraceEntry {
        iteration,
        annealing: weighting.annealing(),
        sigma: model.sigma.first().copied().unwrap_or(0.0),
        beta: model.beta.first().copied().unwrap_or(0.0),
        penalty: model.penalty,
        inlier_fraction: weighting.inlier_fraction(&work.weights, considered),
        rmse,
        translation_change,
        rotation_change,
        correspondences: n,
        transform: *transform,
    }
}
