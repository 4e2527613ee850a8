//! The IRLS loop (eq. regprob2) shared by correspondence registration and ICP: match, weigh
//! (SIE's schedule of §4.3/§4.5, or a baseline cost), solve, stop.
use std::time::Instant;

use nalgebra::Matrix4;

use super::problem::{Problem, RowScales, Rows};
use super::{
    Error, Observer, Quality, RegistrationConfig, RegistrationResult, SearchReport, StageTimes, StartKind,
    StopReason, TraceEntry,
};
use crate::cost::{CostFunction, baseline_weights};
use crate::geometry::transform_change;
use crate::sie::schedule::{BetaSchedule, Convergence, PrecisionStop, Schedule};

/// How correspondences are weighted.
enum Weighting {
    Sie(Box<Schedule>),
    Baseline { cost: CostFunction, scale: f64 },
}

/// The fitted noise model as the result reports it.
struct ModelSummary {
    /// σ_j per histogram (the baseline's scale for other costs).
    sigma: Vec<f64>,
    /// β_j per histogram (empty for baselines).
    beta: Vec<f64>,
    /// k of the first histogram (0 for baselines).
    penalty: f64,
    /// Mean shape exponent p.
    noise_shape: f64,
}

/// Residuals divided by F, the IRLS weights (eq. regprob2), and the final evaluation's
/// per-row probabilities (an update needs only the weights: one row buffer less at the peak).
#[derive(Default)]
struct Workspace {
    normalised: Vec<f64>,
    weights: Vec<f64>,
    probabilities: Vec<f64>,
}

impl Weighting {
    fn new(config: &RegistrationConfig, precision_stop: PrecisionStop) -> Self {
        match config.cost {
            CostFunction::Sie => Weighting::Sie(Box::new(Schedule::new(
                config.sie.clone(),
                BetaSchedule {
                    initial: config.initial_beta,
                    shrink: config.beta_shrink,
                    stop_ratio: config.beta_stop_ratio,
                    warm: config.warm_start.filter(|_| config.initial_beta.is_none()),
                },
                precision_stop,
            ))),
            cost => Weighting::Baseline { cost, scale: 0.0 },
        }
    }

    fn annealing(&self) -> bool {
        matches!(self, Weighting::Sie(schedule) if schedule.annealing())
    }

    /// The model's width σ+β (normalised); infinite for baselines (they never travel coarse).
    fn width(&self) -> f64 {
        match self {
            Weighting::Sie(schedule) => schedule.width(),
            Weighting::Baseline { .. } => f64::INFINITY,
        }
    }

    /// Fits the cost to this iteration's residuals (`normalised`: divided by F) and fills
    /// `weights`.
    fn update(&mut self, rows: &Rows, normalised: &[f64], cols: usize, weights: &mut Vec<f64>) {
        weights.resize(rows.len(), 0.0);
        match self {
            Weighting::Sie(schedule) => schedule.weigh(normalised, cols, |row| rows.scale.get(row), weights),
            Weighting::Baseline { cost, scale } => {
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
    fn after_update(&mut self, below_tolerance: bool, displacement: f64) -> Convergence {
        match self {
            Weighting::Sie(schedule) => schedule.after_update(below_tolerance, displacement),
            Weighting::Baseline { .. } => Convergence::ToleranceOrCycle,
        }
    }

    /// Per-row probabilities at the final transform: P(I|r) for SIE, weight / max weight otherwise.
    fn final_probabilities(&mut self, normalised: &[f64], cols: usize, probabilities: &mut Vec<f64>) {
        probabilities.resize(normalised.len() / cols, 0.0);
        match self {
            Weighting::Sie(schedule) => {
                schedule.probabilities(normalised, cols, probabilities);
            }
            Weighting::Baseline { cost, .. } => {
                // The weights computed in place: no second buffer at the registration's peak.
                baseline_weights(*cost, normalised, cols, probabilities);
                let largest = probabilities.iter().cloned().fold(0.0, f64::max);
                for p in probabilities.iter_mut() {
                    *p = if largest > 0.0 { *p / largest } else { 0.0 };
                }
            }
        }
    }

    fn summary(&self) -> ModelSummary {
        match self {
            Weighting::Sie(schedule) => {
                let models = schedule.estimator().models();
                ModelSummary {
                    sigma: models.iter().map(|m| m.inlier.sigma).collect(),
                    beta: models.iter().map(|m| m.beta).collect(),
                    penalty: models.first().map_or(0.0, |m| m.penalty),
                    noise_shape: schedule.estimator().mean_shape_exponent(),
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

/// See `travelling` in [`run`].
const TRAVEL_WIDTHS: f64 = 1.0;

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

/// The IRLS loop (eq. regprob2) with SIE's β schedule: run to convergence, halve β, repeat
/// until β ≪ σ, then a final round with adaptive k (§4.3, §4.5). At most
/// `config.max_iterations` updates, numbered from `first_iteration` (the runs from several
/// starts of one registration are numbered on).
pub(crate) fn run(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    first_iteration: u32,
    config: &RegistrationConfig,
    observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let (mut result, per_point) = run_pending(problem, init, first_iteration, config, observer)?;
    per_point.spread(problem, &mut result);
    Ok(result)
}

/// A run's final per-row probabilities, not yet spread over the source points: a result
/// that is discarded (a start that does not win, a lead) never allocates its 16 bytes a
/// source point, and one that is kept allocates them after the result it replaces is freed.
pub(crate) struct PendingPerPoint {
    row_probabilities: Vec<f64>,
    model: FinalModel,
}

/// What a run's per-point results are computed from: its final noise model and transform.
/// Kept instead of the results themselves (16 bytes a source point) while later starts run.
pub(crate) struct FinalModel {
    weighting: Weighting,
    transform: Matrix4<f64>,
}

impl FinalModel {
    /// The run's final evaluation again: the problem's rows at the final transform and their
    /// probabilities under the final model. The same bits as the first time: matching is
    /// exact (a cached match is reused only when no other target can have come nearer),
    /// normals and noise scales are fixed per point, and the model is not refitted.
    pub(crate) fn evaluate_again(mut self, problem: &mut dyn Problem) -> PendingPerPoint {
        let cols = problem.cols();
        problem.evaluate_all(&self.transform);
        let mut buffer = Vec::new();
        let normalised = normalised(problem.rows(), cols, &mut buffer);
        let mut row_probabilities = Vec::new();
        self.weighting
            .final_probabilities(normalised, cols, &mut row_probabilities);
        PendingPerPoint {
            row_probabilities,
            model: self,
        }
    }
}

impl PendingPerPoint {
    /// Fills `result.probabilities` and `result.correspondences`; returns the model they
    /// came from. The problem's rows must still be the run's final evaluation; they stay.
    pub(crate) fn spread(self, problem: &dyn Problem, result: &mut RegistrationResult) -> FinalModel {
        let rows = problem.rows();
        self.fill(&rows.source, &rows.target, problem.source_count(), result)
    }

    /// [`PendingPerPoint::spread`] for rows that are read for the last time: the problem's
    /// rows are taken (empty until its next linearise or evaluation) and their residuals
    /// freed first, so that the per-point results need no more memory than the final
    /// evaluation did (at 10 M points, 76 MiB less at the registration's peak).
    pub(crate) fn spread_last(
        self,
        problem: &mut dyn Problem,
        result: &mut RegistrationResult,
    ) -> FinalModel {
        let source_count = problem.source_count();
        let (source, target) = problem.take_row_indices();
        self.fill(&source, &target, source_count, result)
    }

    /// Row `i`'s probability and target go to source point `source[i]`; one per-point vector
    /// at a time, the row probabilities freed before the second.
    fn fill(
        self,
        source: &[u32],
        target: &[u32],
        source_count: usize,
        result: &mut RegistrationResult,
    ) -> FinalModel {
        assert!(
            source.len() == self.row_probabilities.len() && target.len() == source.len(),
            "per-point results spread from rows other than the final evaluation's"
        );
        let mut probabilities = vec![0.0; source_count];
        for (&s, &p) in source.iter().zip(&self.row_probabilities) {
            probabilities[s as usize] = p;
        }
        drop(self.row_probabilities);
        let mut correspondences = vec![-1i64; source_count];
        for (&s, &t) in source.iter().zip(target) {
            correspondences[s as usize] = i64::from(t);
        }
        result.probabilities = probabilities;
        result.correspondences = correspondences;
        self.model
    }
}

/// [`run`] with the per-point results left pending (`result.probabilities` and
/// `result.correspondences` empty); the problem's rows are the final evaluation's.
pub(crate) fn run_pending(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    first_iteration: u32,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<(RegistrationResult, PendingPerPoint), Error> {
    let cols = problem.cols();
    let anchor = problem.source_anchor();
    let mut transform = init;
    // The transform before the last update, for the 2-cycle test below.
    let mut previous = init;
    let precision_stop = if problem.rematches() {
        PrecisionStop::Allowed
    } else {
        PrecisionStop::Never
    };
    let mut weighting = Weighting::new(config, precision_stop);
    let mut work = Workspace::default();
    let mut stop = StopReason::IterationLimit;
    let mut rank_deficient = false;
    let mut conditioning = 0.0;
    let mut iterations = first_iteration.saturating_sub(1);
    let mut trace = Vec::new();
    let (index, normals) = problem.setup_seconds();
    let mut times = StageTimes {
        index,
        normals,
        ..StageTimes::default()
    };
    let mut clock = Instant::now();
    let mut lap = |stage: &mut f64| {
        let now = Instant::now();
        *stage += (now - clock).as_secs_f64();
        clock = now;
    };
    // ICP estimates target normals as matching first reaches them: that time is moved from
    // the stage that triggered it to `normals`.
    let move_normals_time =
        |problem: &dyn Problem, times: &mut StageTimes, stage: fn(&mut StageTimes) -> &mut f64| {
            let spent = problem.setup_seconds().1 - times.normals;
            *stage(times) -= spent;
            times.normals += spent;
        };
    // An update that moved the rows by more than the model's width: the pose is still travelling,
    // and a coarse subset of the matches steers as well as all of them (no convergence is
    // declared on such an update).
    let mut travelling = false;
    for iteration in first_iteration..first_iteration.saturating_add(config.max_iterations) {
        lap(&mut 0.0);
        let coarse_allowed = weighting.annealing() || travelling;
        problem.set_annealing(coarse_allowed);
        problem.linearise(&transform);
        lap(&mut times.matching);
        move_normals_time(problem, &mut times, |t| &mut t.matching);
        let rows = problem.rows();
        if rows.is_empty() {
            stop = StopReason::Degenerate;
            break;
        }
        if iteration == first_iteration {
            if let Weighting::Sie(schedule) = &mut weighting {
                schedule.set_resolution(resolution(problem.coordinate_magnitude(), &rows.scale));
            }
        }
        let normalised = normalised(rows, cols, &mut work.normalised);
        weighting.update(rows, normalised, cols, &mut work.weights);
        lap(&mut times.weighting);
        let solve = problem.solve(&transform, &work.weights);
        lap(&mut times.solve);
        let Some(solve) = solve else {
            stop = StopReason::Degenerate;
            break;
        };
        iterations = iteration;
        let rows = problem.rows();
        let (rotation_change, translation_change) = transform_change(&transform, &solve.transform, &anchor);
        let displacement = problem.displacement(&transform, &solve.transform);
        let (cycle_rotation, cycle_translation) = transform_change(&previous, &solve.transform, &anchor);
        previous = transform;
        transform = solve.transform;
        rank_deficient = solve.rank_deficient;
        conditioning = solve.conditioning;
        if config.record_trace || observer.is_some() {
            let entry = trace_entry(
                iteration,
                &weighting,
                rows,
                cols,
                &work,
                &transform,
                (rotation_change, translation_change),
            );
            let cancelled = observer
                .as_mut()
                .is_some_and(|observe| observe(&entry).is_break());
            if config.record_trace {
                trace.push(entry);
            }
            if cancelled {
                stop = StopReason::Cancelled;
                break;
            }
        }
        let below_tolerance = translation_change <= config.translation_tolerance
            && rotation_change <= config.rotation_tolerance;
        // ICP's discrete matching can alternate between two correspondence sets whose optima
        // differ by more than the tolerance: T_{k+1} = T_{k-1}. Further updates only repeat the
        // pair, so a fixed model that returns within tolerance to where it was two updates ago
        // has converged (either member is as good an answer as the data gives).
        let two_cycle = iteration > first_iteration + 1
            && cycle_translation <= config.translation_tolerance
            && cycle_rotation <= config.rotation_tolerance;
        travelling = displacement > TRAVEL_WIDTHS * weighting.width();
        let converged = !(coarse_allowed && travelling)
            && match weighting.after_update(below_tolerance, displacement) {
                Convergence::NotYet => false,
                Convergence::Tolerance => below_tolerance,
                Convergence::ToleranceOrCycle => below_tolerance || two_cycle,
                Convergence::Resolved => true,
            };
        if converged {
            stop = StopReason::Converged;
            break;
        }
    }
    if rank_deficient && stop != StopReason::Cancelled {
        stop = StopReason::Degenerate;
    }

    // Report everything at the returned transform, for every source point. The work buffers
    // are freed as soon as they are done with: the final rows and the per-point results are
    // the registration's peak (8 bytes a point each at 10 M points is 76 MiB).
    let source_count = problem.source_count();
    work.weights = Vec::new();
    lap(&mut 0.0);
    problem.evaluate_all(&transform);
    lap(&mut times.evaluation);
    move_normals_time(problem, &mut times, |t| &mut t.evaluation);
    let rows = problem.rows();
    let normalised = normalised(rows, cols, &mut work.normalised);
    weighting.final_probabilities(normalised, cols, &mut work.probabilities);
    work.normalised = Vec::new();
    let weight_sum = work.probabilities.iter().fold(0.0, |sum, p| sum + p);
    let rmse = weighted_rms(&rows.residual, cols, &work.probabilities);
    let ModelSummary {
        sigma,
        beta,
        penalty,
        noise_shape,
    } = weighting.summary();
    let histograms = match &weighting {
        Weighting::Sie(schedule) => schedule.estimator().models().to_vec(),
        Weighting::Baseline { .. } => Vec::new(),
    };
    let result = RegistrationResult {
        transform,
        stop_reason: stop,
        converged: stop == StopReason::Converged,
        iterations,
        sigma,
        beta,
        penalty,
        noise_shape,
        inlier_fraction: weight_sum / source_count as f64,
        rmse,
        probabilities: Vec::new(),
        correspondences: Vec::new(),
        histograms,
        trace,
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
            margin: f64::INFINITY,
            ..Quality::default()
        },
    };
    let pending = PendingPerPoint {
        row_probabilities: std::mem::take(&mut work.probabilities),
        model: FinalModel { weighting, transform },
    };
    Ok((result, pending))
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
    let inlier_fraction = match weighting {
        Weighting::Sie(schedule) => schedule.inlier_mass() / considered,
        Weighting::Baseline { .. } => {
            let largest = work.weights.iter().cloned().fold(0.0, f64::max);
            if largest > 0.0 {
                work.weights.iter().sum::<f64>() / (considered * largest)
            } else {
                0.0
            }
        }
    };
    let rmse = weighted_rms(&rows.residual, cols, &work.weights[..n]);
    TraceEntry {
        iteration,
        annealing: weighting.annealing(),
        sigma: model.sigma.first().copied().unwrap_or(0.0),
        beta: model.beta.first().copied().unwrap_or(0.0),
        penalty: model.penalty,
        inlier_fraction,
        rmse,
        translation_change,
        rotation_change,
        correspondences: n,
        transform: *transform,
    }
}
