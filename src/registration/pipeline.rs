//! The registration entry points: check the input, build the problem, run the IRLS driver.

use std::borrow::Cow;
use std::time::Instant;

use nalgebra::Matrix4;

use super::driver::{FinalModel, PendingPerPoint, run, run_pending};
use super::input::{Skip, checked_initial_guess, expand, noise_sigmas, require_finite, require_points};
use super::problem::{CloudProblem, CorrespondenceProblem, Problem, Rows, RunKind};
use super::target::{PrepareOptions, PreparedTarget};
use super::units::Units;
use super::{
    Hooks, Metric, Observer, RegistrationConfig, RegistrationResult, StartKind, Starts, StopReason,
    TraceEntry, Verdict, WarmStart,
};
use crate::cost::CostFunction;
use crate::error::Error;
use crate::geometry::{NonFinite, Point};
use crate::memory;
use crate::noise::{NoiseModel, NoiseScales};
use crate::parallel::Workers;
use crate::sie::hypotheses::{self, Pairs};
use crate::sie::schedule::WARM_BETA_WIDTHS;
use crate::sie::significance::{self, Background};
use crate::sie::starts::{CLOUD_STARTS, LEAD_ROTATION_TOLERANCE, LEAD_TRANSLATION_FRACTION, Lead};

/// Registers matched pairs: `source[i]` corresponds to `target[i]` (point-to-point).
///
/// Errors: a bad setting, lengths that differ, fewer than 3 (kept) pairs, a non-finite
/// coordinate (unless `config.non_finite` skips it), a bad initial guess, a failed noise
/// callback, and [`Error::OutOfMemory`] when the registration's working set cannot be had.
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
    // Asked for up front: a memory limit is an error here, not an abort part-way.
    memory::ensure_available(
        memory::correspondence_registration_bytes(source.len()),
        "the registration of these pairs",
    )?;
    let mut result = register_pairs(source, target, init, config, hooks)?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// [`register_correspondences`] after its checks of the config, the lengths and the memory.
fn register_pairs(
    source: &[Point],
    target: &[Point],
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let skip = Skip::of(config);
    if skip.any() {
        let kept: Vec<u32> = (0..source.len() as u32)
            .filter(|&i| skip.keeps(&source[i as usize]) && skip.keeps(&target[i as usize]))
            .collect();
        if kept.len() < source.len() {
            let pick = |points: &[Point]| kept.iter().map(|&i| points[i as usize]).collect::<Vec<_>>();
            let (source_kept, target_kept) = (pick(source), pick(target));
            let finite = RegistrationConfig {
                non_finite: NonFinite::Reject,
                skip_origin: false,
                ..config.clone()
            };
            let share = kept.len() as f64 / source.len() as f64;
            let result = with_share(hooks, share, |hooks| {
                register_pairs(&source_kept, &target_kept, init, &finite, hooks)
            })?;
            return Ok(expand(result, &kept, source.len(), Some(&kept)));
        }
    }
    require_points("correspondences", source.len(), 3)?;
    require_finite("source", source)?;
    require_finite("target", target)?;
    let init = checked_initial_guess(init)?;
    let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, source, target)?;
    let units = Units::choose(source, target, &sigma_slices(&source_sigma, &target_sigma));
    let result = if units.is_identity() {
        let mut problem = CorrespondenceProblem::new(source, target, source_sigma, target_sigma);
        correspondences_on(&mut problem, source, target, init, config, hooks.observer)?
    } else {
        let (source, target) = (units.points(source), units.points(target));
        let mut problem = CorrespondenceProblem::new(
            &source,
            &target,
            units.sigmas(source_sigma),
            units.sigmas(target_sigma),
        );
        let mut result = in_units(&units, hooks.observer, |observer| {
            correspondences_on(
                &mut problem,
                &source,
                &target,
                units.transform_in(&init),
                config,
                observer,
            )
        })?;
        units.result_out(&mut result);
        result
    };
    Ok(result)
}

/// Correspondence registration on a built problem: SIE from the hypothesis stage's starts, or
/// the paper's method (or a baseline) from the initial guess.
fn correspondences_on(
    problem: &mut CorrespondenceProblem<'_>,
    source: &[Point],
    target: &[Point],
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    if config.cost == CostFunction::Sie && config.starts == Starts::Automatic {
        register_from_hypotheses(problem, source, target, init, config, observer)
    } else {
        let scales = row_scales(problem.rows());
        let evidence = Evidence {
            background: Pairs {
                source,
                target,
                scales: &scales,
            }
            .background(),
            spacing: None,
            exact_start: false,
        };
        let mut result = run(problem, init, 1, config, observer)?;
        judged_alone(&evidence, problem, &mut result);
        Ok(result)
    }
}

fn sigma_slices<'a>(source: &'a Option<Vec<f64>>, target: &'a Option<Vec<f64>>) -> Vec<&'a [f64]> {
    [source, target]
        .into_iter()
        .flatten()
        .map(Vec::as_slice)
        .collect()
}

/// Runs `register` in changed units with an observer that sees every trace entry in the
/// caller's units.
fn in_units<R>(
    units: &Units,
    observer: Option<&mut Observer<'_>>,
    register: impl FnOnce(Option<&mut Observer<'_>>) -> R,
) -> R {
    let Some(outer) = observer else {
        return register(None);
    };
    let mut converted = |entry: &TraceEntry| {
        let mut entry = entry.clone();
        units.entry_out(&mut entry);
        outer(&entry)
    };
    register(Some(&mut converted))
}

/// Starts whose search significance is at least this fraction of the best one's are refined
/// by SIE too: the search scores on a subset, so close calls are decided on all pairs.
const CLOSE_CALL: f64 = 0.5;
/// At most this many starts are refined.
const MAX_STARTS: usize = 3;

/// Correspondence registration from the hypothesis search's most significant poses (the
/// initial guess among them): SIE from each, starting with β₀ at the pose's cluster radius
/// (per component), and the most significant result at its own scale wins.
fn register_from_hypotheses(
    problem: &mut CorrespondenceProblem<'_>,
    source: &[Point],
    target: &[Point],
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let scales = row_scales(problem.rows());
    let pairs = Pairs {
        source,
        target,
        scales: &scales,
    };
    let search = hypotheses::search(&pairs, &init, config.seed);
    let best_significance = search.candidates.first().map_or(0.0, |h| h.cluster.significance);
    if best_significance <= 0.0 {
        // No pose stands out from chance: the paper's method from the initial guess.
        let mut result = run(problem, init, 1, config, observer)?;
        let evidence = Evidence {
            background: pairs.background(),
            spacing: None,
            exact_start: false,
        };
        judged_alone(&evidence, problem, &mut result);
        result.search.hypotheses = search.samples as u32;
        return Ok(result);
    }
    let mut best = BestOfStarts::new(Evidence {
        background: pairs.background(),
        spacing: None,
        exact_start: false,
    });
    let starts = search
        .candidates
        .iter()
        .filter(|h| h.cluster.significance >= CLOSE_CALL * best_significance)
        .take(MAX_STARTS);
    for start in starts {
        let start_config = RegistrationConfig {
            initial_beta: Some(start.cluster.radius / 3f64.sqrt()),
            ..config.clone()
        };
        let result = run(
            problem,
            start.transform,
            best.next_iteration,
            &start_config,
            observer.as_deref_mut(),
        )?;
        let kind = if start.is_initial_guess {
            StartKind::InitialGuess
        } else {
            StartKind::Hypothesis
        };
        if !best.offer(problem, result, None, kind) {
            break;
        }
    }
    let mut result = best.finish(problem);
    result.search.hypotheses = search.samples as u32;
    Ok(result)
}

/// The most significant result of SIE from several starts on one problem, each judged on
/// every row at the scale its own fit claims (`significance::at_scale`).
struct BestOfStarts {
    evidence: Evidence,
    best: Option<Best>,
    /// Every start's final transform, significance and precision (pose standard error as a
    /// row displacement).
    ends: Vec<(Matrix4<f64>, f64, f64)>,
    /// Number of the next update (the runs are numbered on).
    next_iteration: u32,
    /// The median row scale at the last offer (the units `moved_apart` compares poses in).
    typical_scale: f64,
    starts_run: u32,
    /// Every start's trace entries, in the order they ran (the result reports all updates).
    trace: Vec<TraceEntry>,
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
    fn new(evidence: Evidence) -> Self {
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
    fn offer(
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
        let precision = fitted_sigma(&result) * (6.0 / (cluster.count.max(1) as f64)).sqrt();
        self.ends.push((result.transform, significance, precision));
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
                            .find(|end| end.0 == best.transform)
                            .map_or(precision, |end| end.2);
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

    /// Drops the best result's per-point results before another start runs (`finish`
    /// rebuilds them): at 10 M points they are 153 MiB of the registration's peak, and
    /// rebuilding costs one pass over the source points.
    fn park(&mut self) {
        if let Some(best) = self.best.as_mut().filter(|best| best.model.is_some()) {
            best.result.probabilities = Vec::new();
            best.result.correspondences = Vec::new();
            best.parked = true;
        }
    }

    /// The best result, with how the other starts' results relate to it: how many ended at
    /// the same pose (within a few standard errors of either), and the significance of the best
    /// one that did not.
    fn finish(self, problem: &mut dyn Problem) -> RegistrationResult {
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
        for (transform, significance, precision) in &self.ends {
            let apart = moved_apart(problem.probe_points(), &result.transform, transform) / typical_scale;
            let best_precision = self
                .ends
                .iter()
                .find(|end| end.0 == result.transform)
                .map_or(*precision, |end| end.2);
            if apart <= SAME_POSE_ERRORS * precision.max(best_precision) {
                agreeing += 1;
            } else {
                runner_up = runner_up.max(*significance);
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

/// What a result is judged by: the background of its significance, and (ICP) the typical
/// spacing of the target points as a normalised residual.
struct Evidence {
    background: Background,
    spacing: Option<f64>,
    /// The initial guess already fits every row to rounding: no other start is needed.
    exact_start: bool,
}

impl Evidence {
    /// ICP: the background is the spread of the residuals at the initial guess (over the
    /// evidence subset, see [`CloudProblem::evaluate_evidence`]), the spacing the median
    /// distance between neighbouring target points.
    fn of_clouds(problem: &mut CloudProblem<'_>, init: &Matrix4<f64>) -> Self {
        let cols = problem.cols();
        let magnitude = problem.coordinate_magnitude();
        // Residuals at the rounding level already: the guess is exact, and the spread of the
        // target itself is the background a wrong pose would show.
        let exact =
            |rows: &Rows, spread: f64| spread <= super::driver::resolution(magnitude, &rows.scale).powi(2);
        let spread = mean_squared_norm(problem.evaluate_evidence(init), cols);
        let typical_scale = problem.rows().scale.median();
        // The subset says so only when every point does.
        let exact_start = exact(problem.rows(), spread) && {
            let rows = problem.evaluate_all(init);
            exact(rows, mean_squared_norm(rows, cols))
        };
        let spread = if exact_start {
            (problem.target_spread() / typical_scale).powi(2)
        } else {
            spread
        };
        Evidence {
            background: Background {
                spread_squared: spread.max(f64::MIN_POSITIVE),
                dims: cols,
            },
            spacing: Some(problem.target_spacing() / typical_scale),
            exact_start,
        }
    }

    /// ICP near a right pose (a warm start's kept run, or the first start's result when the
    /// guess was close): the residuals at the initial guess are mostly inliers there, not the
    /// background a wrong pose would show. This background is the spread of the residuals at
    /// the result displaced by `DISPLACED_WIDTHS` fitted σ along each axis in turn: what a pose
    /// that wrong shows. On unrelated clouds (noise onto noise) that spread is the result's own, and
    /// nothing stands out. Leaves the problem's rows at the result.
    fn around(problem: &mut CloudProblem<'_>, result: &RegistrationResult) -> Self {
        let cols = problem.cols();
        let typical_scale = problem.rows().scale.median();
        let step = (DISPLACED_WIDTHS * fitted_sigma(result) * typical_scale)
            .min(DISPLACED_SCENE_FRACTION * problem.target_spread());
        let mut spread = 0.0;
        for axis in 0..3 {
            let mut displaced = result.transform;
            displaced[(axis, 3)] += step;
            spread += mean_squared_norm(problem.evaluate_evidence(&displaced), cols) / 3.0;
        }
        problem.evaluate_all(&result.transform);
        Evidence {
            background: Background {
                spread_squared: spread.max(f64::MIN_POSITIVE),
                dims: cols,
            },
            spacing: Some(problem.target_spacing() / typical_scale),
            exact_start: false,
        }
    }

    /// Takes the wider of this background and `around`'s at `result` (a guess near the right
    /// pose has mostly inliers at it). Leaves the problem's rows at the result.
    fn widen_around(&mut self, problem: &mut CloudProblem<'_>, result: &RegistrationResult) {
        let around = Evidence::around(problem, result).background.spread_squared;
        self.background.spread_squared = self.background.spread_squared.max(around);
    }

    /// Fills `result.quality` but for the verdict and the margin (which need every start) and
    /// returns the cluster at the result's fitted scale. The problem's rows must be the result's.
    fn assess(&self, problem: &dyn Problem, result: &mut RegistrationResult) -> significance::Cluster {
        let sigma = fitted_sigma(result);
        let cluster = significance::at_scale(
            squared_norms(problem.rows(), problem.cols()),
            &self.background,
            sigma,
        );
        result.quality.significance = cluster.significance;
        result.quality.sigma_to_spacing = self.spacing.map_or(0.0, |spacing| {
            if spacing > 0.0 {
                sigma / spacing
            } else {
                f64::INFINITY
            }
        });
        cluster
    }
}

/// Mean of the rows' squared residual norms (0 without rows).
fn mean_squared_norm(rows: &Rows, cols: usize) -> f64 {
    squared_norms(rows, cols).sum::<f64>() / rows.len().max(1) as f64
}

/// σ of a result (the RMS over its histograms).
fn fitted_sigma(result: &RegistrationResult) -> f64 {
    (result.sigma.iter().map(|s| s * s).sum::<f64>() / result.sigma.len().max(1) as f64).sqrt()
}

/// Conditioning below this: some direction of the pose rests on a thousandth of the
/// constraint of the best-constrained one (inliers on one plane or one line).
const MIN_CONDITIONING: f64 = 1e-3;
/// A start that ended elsewhere with more than half the significance makes the result a
/// close call.
const MIN_MARGIN: f64 = 2.0;

/// The verdict from the evidence in `result.quality` and the fitted histograms.
fn verdict(result: &RegistrationResult) -> Verdict {
    let quality = &result.quality;
    // NaN counts as no support.
    if quality.significance.is_nan() || quality.significance <= 0.0 {
        return Verdict::Unsupported;
    }
    // A histogram without spread (exact data) has every sample at its peak.
    let peak = result
        .histograms
        .iter()
        .all(|h| h.peak_found || h.inlier.sigma == 0.0);
    let good = peak
        && quality.conditioning >= MIN_CONDITIONING
        && quality.margin >= MIN_MARGIN
        && quality.sigma_to_spacing <= 1.0;
    if good { Verdict::Good } else { Verdict::Doubtful }
}

/// Between two results at the same pose, the later must be this many times as significant to
/// replace the earlier.
const SAME_POSE_TIE: f64 = 1.05;

/// Two starts' results are the same pose when they are this many standard errors apart or
/// closer (as row displacements).
const SAME_POSE_ERRORS: f64 = 3.0;

/// RMS distance between where two transforms put `probe` (a problem's probe points), in input
/// units.
fn moved_apart(probe: &[Point], a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    let difference = a - b;
    let (sum, count) = probe.iter().fold((0.0, 0usize), |(sum, n), p| {
        let d = crate::geometry::transform_point(&difference, p);
        (sum + d[0] * d[0] + d[1] * d[1] + d[2] * d[2], n + 1)
    });
    if count == 0 {
        0.0
    } else {
        (sum / count as f64).sqrt()
    }
}

/// F_i of every row.
fn row_scales(rows: &Rows) -> Vec<f64> {
    (0..rows.len()).map(|i| rows.scale.get(i)).collect()
}

/// ‖r_i‖² / F_i² of every row.
fn squared_norms(rows: &Rows, cols: usize) -> impl Iterator<Item = f64> + '_ {
    rows.residual.chunks_exact(cols).enumerate().map(|(i, r)| {
        let f = rows.scale.get(i);
        r.iter().map(|v| v * v).sum::<f64>() / (f * f)
    })
}

/// Runs `register` with `hooks` whose observer sees inlier fractions scaled by `share` (kept
/// / given source points): dropped points count 0, as in the result.
fn with_share<R>(hooks: Hooks<'_>, share: f64, register: impl FnOnce(Hooks<'_>) -> R) -> R {
    let Hooks { noise, observer } = hooks;
    // Coerced to the shorter lifetime of the wrapper below.
    let noise = noise.map(|n| n as &mut dyn NoiseScales);
    let Some(outer) = observer else {
        return register(Hooks {
            noise,
            observer: None,
        });
    };
    let mut scaled = |entry: &TraceEntry| {
        let mut entry = entry.clone();
        entry.inlier_fraction *= share;
        outer(&entry)
    };
    register(Hooks {
        noise,
        observer: Some(&mut scaled),
    })
}

/// ICP of `source` onto `target` (nearest-neighbour matching, kd-tree built once).
/// `target_normals` (one per target point; zero vectors mark points without a normal) are used
/// for point-to-plane; without them normals come from k-NN PCA on the target.
///
/// The same as preparing the target (`PreparedTarget::new` with
/// `PrepareOptions::from_config(config)`) and calling `register_clouds_to`, bit for bit; prepare
/// it yourself when one target serves several registrations.
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
    let prepared = prepare_for(source, target, target_normals, config)?;
    let mut result = register_to_prepared(
        Cow::Borrowed(source),
        &prepared,
        init,
        config,
        hooks,
        prepared.index_seconds(),
    )?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// `register_clouds` on clouds the caller hands over (the C ABI's copies): the target's copy
/// is dropped once it is prepared and the source's once the problem holds it in pass order
/// (240 MB each at 10 M points). The same result, bit for bit.
pub(crate) fn register_owned_clouds(
    source: Vec<Point>,
    target: Vec<Point>,
    target_normals: Option<Vec<Point>>,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    let prepared = prepare_for(&source, &target, target_normals.as_deref(), config)?;
    drop((target, target_normals));
    let index_seconds = prepared.index_seconds();
    let mut result = register_to_prepared(Cow::Owned(source), &prepared, init, config, hooks, index_seconds)?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// `register_clouds`' checks of the source and the memory, then the target prepared (and
/// checked) with the config's options.
fn prepare_for(
    source: &[Point],
    target: &[Point],
    target_normals: Option<&[Point]>,
    config: &RegistrationConfig,
) -> Result<PreparedTarget, Error> {
    if !Skip::of(config).any() {
        require_points("source", source.len(), 3)?;
        require_points("target", target.len(), 3)?;
        require_finite("source", source)?;
    }
    // Asked for up front: a memory limit is an error here, not an abort part-way.
    memory::ensure_available(
        memory::cloud_registration_bytes(source.len(), target.len()),
        "the registration of these clouds",
    )?;
    PreparedTarget::new(target, target_normals, &PrepareOptions::from_config(config))
}

/// ICP of `source` onto a prepared target: `register_clouds` without building the target's
/// kd-tree (normals estimated by an earlier registration are reused). The result is the one
/// `register_clouds` gives on the same clouds, bit for bit, whatever registrations ran on the
/// target before or run on it concurrently from other threads.
///
/// Errors as `register_clouds`; besides, a point-to-plane config whose `normal_neighbours`
/// differs from the one the target's normals are estimated with (`PrepareOptions`) is
/// refused. `config.non_finite` applies to the source; the target's is fixed when it is
/// prepared.
pub fn register_clouds_to(
    source: &[Point],
    target: &PreparedTarget,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    register_source_to(Cow::Borrowed(source), target, init, config, hooks)
}

/// `register_clouds_to` on a source the caller hands over (the C ABI's copy), dropped once the
/// problem holds it in pass order. The same result, bit for bit.
pub(crate) fn register_owned_to(
    source: Vec<Point>,
    target: &PreparedTarget,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    register_source_to(Cow::Owned(source), target, init, config, hooks)
}

/// `register_clouds_to` on a borrowed or owned source, timed.
fn register_source_to(
    source: Cow<'_, [Point]>,
    target: &PreparedTarget,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    // Asked for up front: a memory limit is an error here, not an abort part-way.
    memory::ensure_available(
        memory::prepared_registration_bytes(source.len(), target.len()),
        "the registration onto this target",
    )?;
    let mut result = register_to_prepared(source, target, init, config, hooks, 0.0)?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// `register_clouds_to` after `config.validate()`; `index_seconds` is what preparing the target
/// cost this call. An owned `source` (and any copy made of it) is dropped as soon as the
/// problem is built.
fn register_to_prepared(
    source: Cow<'_, [Point]>,
    target: &PreparedTarget,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
    index_seconds: f64,
) -> Result<RegistrationResult, Error> {
    if config.metric == Metric::PointToPlane {
        if target.given_normals_all_zero() {
            return Err(Error::InvalidArgument(
                "every target normal is 0 0 0; point-to-plane needs normals (or pass none to estimate them)"
                    .into(),
            ));
        }
        if !target.has_given_normals() && target.normal_neighbours() != config.normal_neighbours {
            return Err(Error::InvalidArgument(format!(
                "the prepared target estimates normals from {} neighbours but normal_neighbours is {}; \
                 prepare the target with the same normal_neighbours",
                target.normal_neighbours(),
                config.normal_neighbours
            )));
        }
    }
    let source_count = source.len();
    let source_kept = Skip::of(config).kept_indices(&source);
    let points: Cow<'_, [Point]> = match &source_kept {
        Some(kept) => {
            let picked = kept.iter().map(|&i| source[i as usize]).collect();
            drop(source);
            Cow::Owned(picked)
        }
        None => source,
    };
    require_points("source", points.len(), 3)?;
    require_finite("source", &points)?;
    let init = checked_initial_guess(init)?;
    let share = points.len() as f64 / source_count.max(1) as f64;
    let result = with_share(hooks, share, |hooks| {
        let target_points = if hooks.noise.is_some() || config.noise != NoiseModel::Constant {
            target.points_in_caller_order()
        } else {
            Vec::new()
        };
        let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, &points, &target_points)?;
        let workers = Workers::new(config.threads).map_err(Error::InvalidArgument)?;
        // The target fixed the lengths when it was prepared; the noise scales fix their own.
        let units = target
            .units()
            .with_noise_of(&sigma_slices(&source_sigma, &target_sigma));
        if units.is_identity() {
            let mut problem = CloudProblem::new(
                &points,
                target,
                source_sigma,
                target_sigma,
                config,
                workers,
                index_seconds,
            )
            .map_err(Error::InvalidArgument)?;
            drop(points);
            return register_cloud_problem(&mut problem, init, config, hooks.observer);
        }
        let moved = units.points(&points);
        drop(points);
        let mut problem = CloudProblem::new(
            &moved,
            target,
            units.sigmas(source_sigma),
            units.sigmas(target_sigma),
            config,
            workers,
            index_seconds,
        )
        .map_err(Error::InvalidArgument)?;
        drop(moved);
        let config = units.config_in(config);
        let mut result = in_units(&units, hooks.observer, |observer| {
            register_cloud_problem(&mut problem, units.transform_in(&init), &config, observer)
        })?;
        units.result_out(&mut result);
        Ok(result)
    })?;
    if source_kept.is_none() && target.kept().is_none() {
        return Ok(result);
    }
    let source_map = source_kept.unwrap_or_else(|| (0..source_count as u32).collect());
    Ok(expand(result, &source_map, source_count, target.kept()))
}

/// ICP on a built problem (target index and normals ready): SIE's starts, or the baseline's
/// single run.
fn register_cloud_problem(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let sie = config.cost == CostFunction::Sie && config.initial_beta.is_none();
    let mut warm_run = None;
    if let Some(warm) = config.warm_start.filter(|_| sie) {
        let (mut result, pending) = run_pending(problem, init, 1, config, observer.as_deref_mut())?;
        result.search.start = StartKind::WarmStart;
        let typical_scale = problem.rows().scale.median();
        let moved = moved_apart(problem.probe_points(), &init, &result.transform) / typical_scale;
        if result.stop_reason == StopReason::Cancelled || warm_model_held(&warm, &result, moved) {
            let evidence = Evidence::around(problem, &result);
            judged_alone(&evidence, problem, &mut result);
            // `around` left the rows at the result: the final evaluation's, bit for bit.
            pending.spread_last(problem, &mut result);
            return Ok(result);
        }
        // Only its trace and update count go on: no per-point results are built for it.
        warm_run = Some(result);
    }
    // Without a warm start, or after one whose model did not hold: the updates are numbered on.
    let cold = RegistrationConfig {
        warm_start: None,
        ..config.clone()
    };
    let first_iteration = warm_run.as_ref().map_or(1, |r| r.iterations + 1);
    let mut result = if sie && config.starts == Starts::Automatic {
        register_from_starts(problem, init, first_iteration, &cold, observer)?
    } else {
        let mut evidence = Evidence::of_clouds(problem, &init);
        let (mut result, pending) = run_pending(problem, init, first_iteration, &cold, observer)?;
        // As for the first of several starts (`register_from_starts`); a baseline has no σ.
        // Either way the rows are the final evaluation's (again) after this.
        if config.cost == CostFunction::Sie {
            evidence.widen_around(problem, &result);
        }
        judged_alone(&evidence, problem, &mut result);
        pending.spread_last(problem, &mut result);
        result
    };
    if let Some(mut warm_run) = warm_run {
        warm_run.trace.append(&mut result.trace);
        result.trace = warm_run.trace;
        result.search.starts_run += 1;
    }
    Ok(result)
}

/// A warm run's model held when the run converged on an inlier peak no wider than twice the
/// previous σ, holding at least half the previous inlier fraction, and the guess was within
/// the first model's reach: the run moved the source points (RMS, normalised `moved`) by at
/// most three of its widths σ+β₀ (farther, the first residuals of the true inliers were
/// outliers to the model, and where the run ended is a local answer). Otherwise the guess
/// was not in the previous fit's basin (or the scene changed): the noise model must be found
/// again. Measured on the Kinect frames from a constant-velocity guess: the two warm runs that
/// ended 0.2–0.6 m off had moved 23σ and 38σ with σ and the inlier fraction as before; right
/// ones moved 2–10σ.
fn warm_model_held(warm: &WarmStart, result: &RegistrationResult, moved: f64) -> bool {
    result.stop_reason == StopReason::Converged
        && result.histograms.iter().all(|h| h.peak_found)
        && fitted_sigma(result) <= WARM_SIGMA_GROWTH * warm.sigma
        && result.inlier_fraction >= WARM_INLIER_SHARE * warm.inlier_fraction
        && moved <= WARM_REACH_WIDTHS * (1.0 + WARM_BETA_WIDTHS) * warm.sigma
}

/// See [`warm_model_held`].
const WARM_REACH_WIDTHS: f64 = 3.0;

/// See [`warm_model_held`].
const WARM_SIGMA_GROWTH: f64 = 2.0;
/// See [`warm_model_held`].
const WARM_INLIER_SHARE: f64 = 0.5;

/// The quality of a result that had no other start to compare with.
fn judged_alone(evidence: &Evidence, problem: &dyn Problem, result: &mut RegistrationResult) {
    evidence.assess(problem, result);
    result.search.significance = result.quality.significance;
    result.quality.margin = f64::INFINITY;
    result.quality.verdict = verdict(result);
}

/// ICP from the initial guess by each of `sie::starts::CLOUD_STARTS`; the most significant
/// result at its own scale wins. The background of the significance is the spread of the
/// residuals at the initial guess (over the evidence subset), widened by `Evidence::around`.
fn register_from_starts(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    first_iteration: u32,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let cols = problem.cols();
    let evidence = Evidence::of_clouds(problem, &init);
    // The RMS of every initial residual scales the later starts (the narrow β₀, the lead's
    // tolerance); it needs a pass over every source point, made only when a later start runs.
    let mut initial_rms = None;
    let mut rms = |problem: &mut CloudProblem<'_>| {
        *initial_rms.get_or_insert_with(|| {
            (mean_squared_norm(problem.evaluate_all(&init), cols) / cols as f64).sqrt()
        })
    };
    let starts = if evidence.exact_start {
        &CLOUD_STARTS[..1]
    } else {
        &CLOUD_STARTS[..]
    };
    let mut best = BestOfStarts::new(evidence);
    best.next_iteration = first_iteration;
    for start in starts {
        best.park();
        let (from, kind) = match start.lead {
            Lead::None => (init, StartKind::InitialGuess),
            Lead::ScaleFree => {
                let lead = RegistrationConfig {
                    cost: CostFunction::Lp { p: 1.0 },
                    translation_tolerance: LEAD_TRANSLATION_FRACTION * rms(problem),
                    rotation_tolerance: LEAD_ROTATION_TOLERANCE,
                    ..config.clone()
                };
                problem.set_run_kind(RunKind::Lead);
                let led = run_pending(problem, init, best.next_iteration, &lead, observer.as_deref_mut());
                problem.set_run_kind(RunKind::Registration);
                let (mut led, pending) = led?;
                if led.stop_reason == StopReason::Cancelled {
                    best.offer(problem, led, Some(pending), StartKind::ScaleFreeLead);
                    break;
                }
                best.next_iteration = led.iterations + 1;
                best.trace.append(&mut led.trace);
                (led.transform, StartKind::ScaleFreeLead)
            }
        };
        let kind = if start.beta_fraction < 1.0 {
            StartKind::NarrowBeta
        } else {
            kind
        };
        let start_config = RegistrationConfig {
            initial_beta: (start.beta_fraction < 1.0).then(|| start.beta_fraction * rms(problem)),
            ..config.clone()
        };
        let (result, pending) = run_pending(
            problem,
            from,
            best.next_iteration,
            &start_config,
            observer.as_deref_mut(),
        )?;
        // Only a converged run can show the guess was right (one stopped at the cap while β was
        // still wide has not looked closely yet).
        let stayed = kind == StartKind::InitialGuess
            && result.stop_reason == StopReason::Converged
            && stayed_near(problem, &init, &result);
        // A guess near the right pose has residuals that are mostly inliers, not the background
        // a wrong pose would show (judged against them alone, the right pose of every frame of a
        // 100-frame odometry run from constant-velocity guesses was UNSUPPORTED). The first
        // start's result shifted by 10σ shows one; the wider of the two backgrounds judges
        // every start.
        if best.starts_run == 0 {
            // Leaves the rows at the result: the final evaluation's again, bit for bit.
            best.evidence.widen_around(problem, &result);
        }
        if !best.offer(problem, result, Some(pending), kind) || stayed {
            break;
        }
    }
    Ok(best.finish(problem))
}

/// The initial guess was already right to within the noise: the paper's start (the widest β)
/// moved the source points by at most `STAYED_SIGMAS`·σ RMS. Narrower starts from the same
/// guess cannot be pulled elsewhere by data that did not pull the widest one (a sequence's
/// constant-velocity guess is the common case: one start, the paper's cost).
fn stayed_near(problem: &dyn Problem, init: &Matrix4<f64>, result: &RegistrationResult) -> bool {
    let typical_scale = problem.rows().scale.median();
    let moved = moved_apart(problem.probe_points(), init, &result.transform) / typical_scale;
    moved <= STAYED_SIGMAS * fitted_sigma(result)
}

/// See [`stayed_near`].
const STAYED_SIGMAS: f64 = 3.0;

/// See [`Evidence::around`]: ten σ is far outside the inlier peak (99 % of Gaussian inliers lie
/// within 2.6σ per component) and still a near miss next to a poor initial guess.
const DISPLACED_WIDTHS: f64 = 10.0;
/// … and at most this fraction of the target's spread: a shift that moves a good part of the
/// source off the target would widen any residuals, a fitted σ that large (noise onto noise)
/// has no room to be told from chance.
const DISPLACED_SCENE_FRACTION: f64 = 0.05;
