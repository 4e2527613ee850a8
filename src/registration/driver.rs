//! The IRLS driver: β annealing (§4.3), adaptive k (§4.5), convergence and stop reasons,
//! shared by correspondence registration and ICP.
use std::time::Instant;

use nalgebra::Matrix4;

use super::problem::{CloudProblem, CorrespondenceProblem, Problem, Rows};
use super::{
    Error, Hooks, InlierEstimate, Metric, Observer, Point, RegistrationConfig, RegistrationResult,
    StageTimes, StopReason, TraceEntry,
};
use crate::cost::{CostFunction, baseline_weights};
use crate::geometry::transform_change;
use crate::noise::{CloudRole, NoiseModel, NoiseScales, cloud_sigmas};
use crate::parallel::Workers;
use crate::sie::{SieEstimator, SieOptions};

/// A β level has converged when one update moves the correspondences by less than this
/// fraction of the current model width σ+β (normalised RMS displacement).
const LEVEL_TOLERANCE: f64 = 0.01;
/// At most this many updates per β level before β shrinks anyway: with many outliers a level
/// can wander at the scale of σ+β without settling (the authors' driver likewise makes at most
/// 3 model updates per level).
const MAX_LEVEL_ITERATIONS: u32 = 5;
/// Largest residual magnitude `estimate_inliers` accepts (see there).
const MAX_RESIDUAL: f64 = 1e140;
/// δ of eq. (regprob3GGD) relative to σ+β: bounds the weight max(‖r‖, δ)^(p-2) for p < 2.
const SHAPE_DELTA: f64 = 1e-3;

/// Registers matched pairs: `source[i]` corresponds to `target[i]` (point-to-point).
pub fn register_correspondences(
    source: &[Point],
    target: &[Point],
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    if source.len() != target.len() {
        return Err(Error::InvalidArgument(format!(
            "source has {} points but target has {}; correspondences must pair them one to one",
            source.len(),
            target.len()
        )));
    }
    if config.skip_non_finite || config.skip_origin {
        let kept: Vec<u32> = (0..source.len() as u32)
            .filter(|&i| keeps(config, &source[i as usize]) && keeps(config, &target[i as usize]))
            .collect();
        if kept.len() < source.len() {
            let pick = |points: &[Point]| kept.iter().map(|&i| points[i as usize]).collect::<Vec<_>>();
            let (source_kept, target_kept) = (pick(source), pick(target));
            let finite = RegistrationConfig {
                skip_non_finite: false,
                skip_origin: false,
                ..config.clone()
            };
            let result = register_correspondences(&source_kept, &target_kept, init, &finite, hooks)?;
            return Ok(expand(result, &kept, source.len(), Some(&kept)));
        }
    }
    require_points("correspondences", source.len(), 3)?;
    require_finite("source", source)?;
    require_finite("target", target)?;
    let init = checked_initial_guess(init)?;
    let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, source, target)?;
    let mut problem = CorrespondenceProblem::new(source, target, source_sigma, target_sigma);
    let mut result = run(&mut problem, init, config, hooks.observer)?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

fn is_finite(p: &Point) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// Whether a point survives `skip_non_finite` / `skip_origin` (0.0 == -0.0).
fn keeps(config: &RegistrationConfig, p: &Point) -> bool {
    (!config.skip_non_finite || is_finite(p)) && !(config.skip_origin && *p == [0.0; 3])
}

/// Indices of the points kept, or `None` when every point is (nothing to copy).
fn kept_indices(points: &[Point], config: &RegistrationConfig) -> Option<Vec<u32>> {
    if points.iter().all(|p| keeps(config, p)) {
        return None;
    }
    Some(
        (0..points.len() as u32)
            .filter(|&i| keeps(config, &points[i as usize]))
            .collect(),
    )
}

/// `register_clouds` on the kept points only (`skip_non_finite`, `skip_origin`); a non-finite
/// normal becomes "no normal".
fn register_finite_clouds(
    source: &[Point],
    target: &[Point],
    target_normals: Option<&[Point]>,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let finite = RegistrationConfig {
        skip_non_finite: false,
        skip_origin: false,
        ..config.clone()
    };
    let source_kept = kept_indices(source, config);
    let target_kept = kept_indices(target, config);
    let pick = |points: &[Point], kept: &Option<Vec<u32>>| -> Vec<Point> {
        match kept {
            Some(kept) => kept.iter().map(|&i| points[i as usize]).collect(),
            None => points.to_vec(),
        }
    };
    let normals: Option<Vec<Point>> = target_normals.map(|normals| {
        pick(normals, &target_kept)
            .into_iter()
            .map(|n| if is_finite(&n) { n } else { [0.0; 3] })
            .collect()
    });
    let source_points = pick(source, &source_kept);
    let target_points = pick(target, &target_kept);
    let result = register_clouds(
        &source_points,
        &target_points,
        normals.as_deref(),
        init,
        &finite,
        hooks,
    )?;
    let source_map = source_kept.unwrap_or_else(|| (0..source.len() as u32).collect());
    Ok(expand(result, &source_map, source.len(), target_kept.as_deref()))
}

/// Maps per-point results of a registration on kept points back to the caller's indexing:
/// `source_kept[i]` is the original index of kept source point i, `target_kept` likewise for
/// target indices (`None`: target indices are unchanged).
fn expand(
    mut result: RegistrationResult,
    source_kept: &[u32],
    source_count: usize,
    target_kept: Option<&[u32]>,
) -> RegistrationResult {
    let mut probabilities = vec![0.0; source_count];
    let mut correspondences = vec![-1i64; source_count];
    for (k, &original) in source_kept.iter().enumerate() {
        probabilities[original as usize] = result.probabilities[k];
        let target = result.correspondences[k];
        correspondences[original as usize] = match target_kept {
            Some(map) if target >= 0 => map[target as usize] as i64,
            _ => target,
        };
    }
    result.inlier_fraction *= source_kept.len() as f64 / source_count.max(1) as f64;
    result.probabilities = probabilities;
    result.correspondences = correspondences;
    result
}

/// ICP of `source` onto `target` (nearest-neighbour matching, kd-tree built once).
/// `target_normals` (one per target point; zero vectors mark points without a normal) are used
/// for point-to-plane; without them normals come from k-NN PCA on the target.
pub fn register_clouds(
    source: &[Point],
    target: &[Point],
    target_normals: Option<&[Point]>,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    if let Some(normals) = target_normals {
        if normals.len() != target.len() {
            return Err(Error::InvalidArgument(format!(
                "target has {} points but {} normals",
                target.len(),
                normals.len()
            )));
        }
    }
    if config.skip_non_finite || config.skip_origin {
        return register_finite_clouds(source, target, target_normals, init, config, hooks);
    }
    require_points("source", source.len(), 3)?;
    require_points("target", target.len(), 3)?;
    require_finite("source", source)?;
    require_finite("target", target)?;
    if let Some(normals) = target_normals {
        require_finite("target normals", normals)?;
        if config.metric == Metric::PointToPlane && normals.iter().all(|n| *n == [0.0; 3]) {
            return Err(Error::InvalidArgument(
                "every target normal is 0 0 0; point-to-plane needs normals (or pass none to estimate them)"
                    .into(),
            ));
        }
    }
    let init = checked_initial_guess(init)?;
    let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, source, target)?;
    let workers = Workers::new(config.threads).map_err(Error::InvalidArgument)?;
    let mut problem = CloudProblem::new(
        source,
        target,
        target_normals,
        source_sigma,
        target_sigma,
        config,
        workers,
    )
    .map_err(Error::InvalidArgument)?;
    let mut result = run(&mut problem, init, config, hooks.observer)?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// SIE on a residual matrix (row-major rows × cols), each row divided by `row_scales[i]` when
/// given; β is the regulariser (0 for none). Fits with k = k₀, then adapts k from P(I|H) and
/// refits (§4.5), and returns P(I|R_i) per row. Scaled residuals above 1e140 in magnitude are
/// refused (their squares would overflow in the fit).
pub fn estimate_inliers(
    residuals: &[f64],
    cols: usize,
    row_scales: Option<&[f64]>,
    beta: f64,
    options: &SieOptions,
) -> Result<InlierEstimate, Error> {
    options.validate().map_err(Error::InvalidArgument)?;
    if cols == 0 {
        return Err(Error::InvalidArgument("cols must be >= 1".into()));
    }
    if residuals.len() % cols != 0 {
        return Err(Error::InvalidArgument(format!(
            "{} residual values do not form rows of {cols}",
            residuals.len()
        )));
    }
    let rows = residuals.len() / cols;
    require_points("residual rows", rows, 1)?;
    if let Some(i) = residuals.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite(format!("residuals[{i}] is {}", residuals[i])));
    }
    if !(beta.is_finite() && beta >= 0.0) {
        return Err(Error::InvalidArgument(format!(
            "beta must be finite and >= 0, got {beta}"
        )));
    }
    let normalised: Vec<f64> = match row_scales {
        None => residuals.to_vec(),
        Some(scales) => {
            if scales.len() != rows {
                return Err(Error::InvalidArgument(format!(
                    "{} row scales for {rows} rows",
                    scales.len()
                )));
            }
            if let Some(i) = scales.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
                return Err(Error::InvalidArgument(format!(
                    "row_scales[{i}] is {}; scales must be finite and > 0",
                    scales[i]
                )));
            }
            residuals
                .chunks_exact(cols)
                .zip(scales)
                .flat_map(|(row, s)| row.iter().map(move |r| r / s))
                .collect()
        }
    };
    // Squares of the residuals are summed (RMS start, histogram moments): beyond this they
    // overflow and the fit would end with an infinite σ.
    if let Some(i) = normalised.iter().position(|v| v.abs() > MAX_RESIDUAL) {
        return Err(Error::InvalidArgument(format!(
            "residual {i} is {:e} after row scaling; magnitudes above {MAX_RESIDUAL:e} cannot be squared \
             and summed without overflow (rescale the residuals)",
            normalised[i]
        )));
    }
    let mut sie = SieEstimator::new(options.clone());
    sie.prepare(&normalised, cols);
    sie.set_beta(&[beta]);
    sie.fit(&normalised, cols);
    sie.adapt_penalty();
    sie.fit(&normalised, cols);
    let mut probabilities = vec![0.0; rows];
    let prior = sie.probabilities(&normalised, cols, &mut probabilities);
    Ok(InlierEstimate {
        probabilities,
        models: sie.models().to_vec(),
        prior,
    })
}

fn require_points(what: &str, count: usize, minimum: usize) -> Result<(), Error> {
    if count < minimum {
        return Err(Error::TooFewPoints(format!(
            "{what}: {count} given, at least {minimum} needed"
        )));
    }
    Ok(())
}

fn require_finite(what: &str, points: &[Point]) -> Result<(), Error> {
    match points.iter().position(|p| !is_finite(p)) {
        None => Ok(()),
        Some(i) => Err(Error::NonFinite(format!(
            "{what}[{i}] = {:?} is not finite",
            points[i]
        ))),
    }
}

/// The initial guess must be a rigid transform (`geometry::check_rigid`); it is then projected
/// exactly onto SO(3).
pub fn checked_initial_guess(init: Option<&Matrix4<f64>>) -> Result<Matrix4<f64>, Error> {
    let Some(t) = init else {
        return Ok(Matrix4::identity());
    };
    crate::geometry::check_rigid(t, "initial guess").map_err(Error::InvalidArgument)?;
    Ok(crate::geometry::orthonormalised(t))
}

/// Per-point σ of both clouds (§4.4), or `None` when noise is constant.
type Sigmas = (Option<Vec<f64>>, Option<Vec<f64>>);

fn noise_sigmas(
    config: &RegistrationConfig,
    callback: Option<&mut dyn NoiseScales>,
    source: &[Point],
    target: &[Point],
) -> Result<Sigmas, Error> {
    let mut builtin = config.noise;
    let scales: &mut dyn NoiseScales = match callback {
        Some(cb) => cb,
        None if config.noise == NoiseModel::Constant => return Ok((None, None)),
        None => &mut builtin,
    };
    let s = cloud_sigmas(scales, CloudRole::Source, source).map_err(Error::Callback)?;
    let t = cloud_sigmas(scales, CloudRole::Target, target).map_err(Error::Callback)?;
    Ok((Some(s), Some(t)))
}

/// How correspondences are weighted.
enum Weighting {
    /// `frozen`: the final round has settled at the model's scale and stops refitting, so IRLS
    /// can converge on a fixed model instead of chasing histogram bin-count jitter.
    Sie {
        estimator: SieEstimator,
        annealing: bool,
        frozen: bool,
    },
    Baseline {
        cost: CostFunction,
        scale: f64,
    },
}

/// Residuals divided by F, and the IRLS weights (eq. regprob2).
struct Workspace {
    normalised: Vec<f64>,
    weights: Vec<f64>,
    probabilities: Vec<f64>,
}

impl Weighting {
    fn new(config: &RegistrationConfig) -> Self {
        match config.cost {
            CostFunction::Sie => Weighting::Sie {
                estimator: SieEstimator::new(config.sie.clone()),
                annealing: true,
                frozen: false,
            },
            cost => Weighting::Baseline { cost, scale: 0.0 },
        }
    }

    /// Fits the cost to this iteration's residuals and fills `work.weights`.
    fn update(
        &mut self,
        rows: &Rows,
        cols: usize,
        config: &RegistrationConfig,
        first: bool,
        work: &mut Workspace,
    ) {
        let n = rows.len();
        work.weights.resize(n, 0.0);
        work.probabilities.resize(n, 0.0);
        match self {
            Weighting::Sie {
                estimator,
                annealing,
                frozen,
            } => {
                if first {
                    estimator.prepare(&work.normalised, cols);
                    let beta = match config.initial_beta {
                        Some(b) => vec![b],
                        None => estimator.residual_rms(&work.normalised, cols),
                    };
                    estimator.set_beta(&beta);
                }
                if !*frozen {
                    if !*annealing {
                        // §4.5: after convergence, k = P(I|H)^-3 from the data at hand.
                        estimator.adapt_penalty();
                    }
                    estimator.fit(&work.normalised, cols);
                }
                estimator.probabilities(&work.normalised, cols, &mut work.probabilities);
                let p = estimator.mean_shape();
                let width = estimator
                    .effective_scales()
                    .into_iter()
                    .fold(f64::INFINITY, f64::min);
                let delta = (SHAPE_DELTA * width).max(1e-12);
                for i in 0..n {
                    // eq. (regprob3) / (regprob3GGD): w = σ^-p·max(‖r‖,δ)^(p-2)·P(I|r); σ^-p is common
                    // to all rows and dropped, F(i)^-2 carries the per-row noise (§4.4).
                    let shape_factor = if p == 2.0 {
                        1.0
                    } else {
                        row_norm(&work.normalised, cols, i).max(delta).powf(p - 2.0)
                    };
                    work.weights[i] = work.probabilities[i] * shape_factor / rows.scale[i].powi(2);
                }
            }
            Weighting::Baseline { cost, scale } => {
                *scale = baseline_weights(*cost, &work.normalised, cols, &mut work.weights);
                for (w, f) in work.weights.iter_mut().zip(&rows.scale) {
                    *w /= f * f;
                }
            }
        }
    }

    /// Per-row probabilities at the final transform: P(I|r) for SIE, weight / max weight otherwise.
    fn final_probabilities(&mut self, rows: &Rows, cols: usize, work: &mut Workspace) {
        let n = rows.len();
        work.probabilities.resize(n, 0.0);
        match self {
            Weighting::Sie { estimator, .. } => {
                estimator.probabilities(&work.normalised, cols, &mut work.probabilities);
            }
            Weighting::Baseline { cost, .. } => {
                work.weights.resize(n, 0.0);
                baseline_weights(*cost, &work.normalised, cols, &mut work.weights);
                let largest = work.weights.iter().cloned().fold(0.0, f64::max);
                for (p, w) in work.probabilities.iter_mut().zip(&work.weights) {
                    *p = if largest > 0.0 { w / largest } else { 0.0 };
                }
            }
        }
    }

    fn sigma_beta_penalty(&self) -> (Vec<f64>, Vec<f64>, f64, f64) {
        match self {
            Weighting::Sie { estimator, .. } => (
                estimator.models().iter().map(|m| m.shape.sigma).collect(),
                estimator.models().iter().map(|m| m.beta).collect(),
                estimator.models().first().map_or(0.0, |m| m.penalty),
                estimator.mean_shape(),
            ),
            Weighting::Baseline { scale, .. } => (vec![*scale], Vec::new(), 0.0, 2.0),
        }
    }
}

fn row_norm(values: &[f64], cols: usize, row: usize) -> f64 {
    values[row * cols..(row + 1) * cols]
        .iter()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt()
}

fn normalise(rows: &Rows, cols: usize, out: &mut Vec<f64>) {
    out.clear();
    out.extend(
        rows.residual
            .chunks_exact(cols)
            .zip(&rows.scale)
            .flat_map(|(row, f)| row.iter().map(move |r| r / f)),
    );
}

/// The IRLS loop (eq. regprob2) with SIE's β schedule: run to convergence, halve β, repeat
/// until β ≪ σ, then a final round with adaptive k (§4.3, §4.5).
fn run(
    problem: &mut dyn Problem,
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let cols = problem.cols();
    let anchor = problem.source_centroid();
    let mut transform = init;
    // The transform before the last update, for the 2-cycle test below.
    let mut previous = init;
    let mut weighting = Weighting::new(config);
    let mut work = Workspace {
        normalised: Vec::new(),
        weights: Vec::new(),
        probabilities: Vec::new(),
    };
    let mut stop = StopReason::IterationLimit;
    let mut rank_deficient = false;
    let mut iterations = 0;
    let mut trace = Vec::new();
    let mut level_iterations = 0u32;
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
    for iteration in 1..=config.max_iterations {
        lap(&mut 0.0);
        problem.set_annealing(matches!(weighting, Weighting::Sie { annealing: true, .. }));
        problem.linearise(&transform);
        lap(&mut times.matching);
        move_normals_time(problem, &mut times, |t| &mut t.matching);
        let rows = problem.rows();
        if rows.is_empty() {
            stop = StopReason::Degenerate;
            break;
        }
        normalise(rows, cols, &mut work.normalised);
        weighting.update(rows, cols, config, iteration == 1, &mut work);
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
        if config.record_trace || observer.is_some() {
            let entry = trace_entry(
                iteration,
                &weighting,
                rows,
                cols,
                &work,
                rotation_change,
                translation_change,
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
        let two_cycle = iteration > 2
            && cycle_translation <= config.translation_tolerance
            && cycle_rotation <= config.rotation_tolerance;
        if let Weighting::Sie {
            estimator,
            annealing,
            frozen,
        } = &mut weighting
        {
            let width = estimator
                .effective_scales()
                .into_iter()
                .fold(f64::INFINITY, f64::min);
            let settled = below_tolerance || displacement <= LEVEL_TOLERANCE * width;
            level_iterations += 1;
            if *annealing {
                if settled || level_iterations >= MAX_LEVEL_ITERATIONS {
                    level_iterations = 0;
                    if estimator.beta_negligible(config.beta_stop_ratio) {
                        *annealing = false;
                    } else {
                        estimator.shrink_beta(config.beta_shrink);
                    }
                }
                continue;
            }
            let was_frozen = *frozen;
            *frozen |= settled;
            if was_frozen && two_cycle {
                stop = StopReason::Converged;
                break;
            }
        } else if two_cycle {
            stop = StopReason::Converged;
            break;
        }
        if below_tolerance {
            stop = StopReason::Converged;
            break;
        }
    }
    if rank_deficient && stop != StopReason::Cancelled {
        stop = StopReason::Degenerate;
    }

    // Report everything at the returned transform, for every source point.
    let source_count = problem.source_count();
    lap(&mut 0.0);
    problem.evaluate_all(&transform);
    lap(&mut times.evaluation);
    move_normals_time(problem, &mut times, |t| &mut t.evaluation);
    let rows = problem.rows();
    normalise(rows, cols, &mut work.normalised);
    weighting.final_probabilities(rows, cols, &mut work);
    let mut probabilities = vec![0.0; source_count];
    let mut correspondences = vec![-1i64; source_count];
    let (mut weight_sum, mut weighted_square) = (0.0, 0.0);
    for (i, &p) in work.probabilities.iter().enumerate() {
        let s = rows.source[i] as usize;
        probabilities[s] = p;
        correspondences[s] = rows.target[i] as i64;
        weight_sum += p;
        weighted_square += p * row_norm(&rows.residual, cols, i).powi(2);
    }
    let (sigma, beta, penalty, noise_shape) = weighting.sigma_beta_penalty();
    let histograms = match &weighting {
        Weighting::Sie { estimator, .. } => estimator.models().to_vec(),
        Weighting::Baseline { .. } => Vec::new(),
    };
    Ok(RegistrationResult {
        transform,
        stop_reason: stop,
        converged: stop == StopReason::Converged,
        iterations,
        sigma,
        beta,
        penalty,
        noise_shape,
        inlier_fraction: weight_sum / source_count as f64,
        rmse: if weight_sum > 0.0 {
            (weighted_square / weight_sum).sqrt()
        } else {
            0.0
        },
        probabilities,
        correspondences,
        histograms,
        trace,
        times,
    })
}

fn trace_entry(
    iteration: u32,
    weighting: &Weighting,
    rows: &Rows,
    cols: usize,
    work: &Workspace,
    rotation_change: f64,
    translation_change: f64,
) -> TraceEntry {
    let (sigma, beta, penalty, _) = weighting.sigma_beta_penalty();
    let n = rows.len();
    let mean_probability = match weighting {
        Weighting::Sie { .. } => work.probabilities.iter().sum::<f64>() / n as f64,
        Weighting::Baseline { .. } => {
            let largest = work.weights.iter().cloned().fold(0.0, f64::max);
            if largest > 0.0 {
                work.weights.iter().sum::<f64>() / (n as f64 * largest)
            } else {
                0.0
            }
        }
    };
    let weight_sum: f64 = work.weights.iter().sum();
    let weighted_square: f64 = (0..n)
        .map(|i| work.weights[i] * row_norm(&rows.residual, cols, i).powi(2))
        .sum();
    TraceEntry {
        iteration,
        annealing: matches!(weighting, Weighting::Sie { annealing: true, .. }),
        sigma: sigma.first().copied().unwrap_or(0.0),
        beta: beta.first().copied().unwrap_or(0.0),
        penalty,
        inlier_fraction: mean_probability,
        rmse: if weight_sum > 0.0 {
            (weighted_square / weight_sum).sqrt()
        } else {
            0.0
        },
        translation_change,
        rotation_change,
        correspondences: n,
    }
}
