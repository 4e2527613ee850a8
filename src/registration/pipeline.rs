//! The registration entry points: check the input, build the problem, run the IRLS driver.

use std::time::Instant;

use nalgebra::Matrix4;

use super::driver::run;
use super::input::{
    checked_initial_guess, expand, finite_indices, is_finite, noise_sigmas, require_finite, require_points,
};
use super::problem::{CloudProblem, CorrespondenceProblem, Problem};
use super::target::{PrepareOptions, PreparedTarget};
use super::{
    Hooks, Metric, Observer, TraceEntry, RegistrationConfig, RegistrationResult, StartKind, Starts, StopReason,
};
use crate::cost::CostFunction;
use crate::sie::hypotheses::{self, Pairs};
use crate::sie::significance;
use crate::error::Error;
use crate::geometry::Point;
use crate::noise::{NoiseModel, NoiseScales};
use crate::parallel::Workers;

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
    if config.skip_non_finite {
        let kept: Vec<u32> = (0..source.len() as u32)
            .filter(|&i| is_finite(&source[i as usize]) && is_finite(&target[i as usize]))
            .collect();
        if kept.len() < source.len() {
            let pick = |points: &[Point]| kept.iter().map(|&i| points[i as usize]).collect::<Vec<_>>();
            let (source_kept, target_kept) = (pick(source), pick(target));
            let finite = RegistrationConfig {
                skip_non_finite: false,
                ..config.clone()
            };
            let share = kept.len() as f64 / source.len() as f64;
            let result = with_share(hooks, share, |hooks| {
                register_correspondences(&source_kept, &target_kept, init, &finite, hooks)
            })?;
            return Ok(expand(result, &kept, source.len(), Some(&kept)));
        }
    }
    require_points("correspondences", source.len(), 3)?;
    require_finite("source", source)?;
    require_finite("target", target)?;
    let init = checked_initial_guess(init)?;
    let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, source, target)?;
    let mut problem = CorrespondenceProblem::new(source, target, source_sigma, target_sigma);
    let mut result = if config.cost == CostFunction::Sie && config.starts == Starts::Automatic {
        register_from_hypotheses(&mut problem, source, target, init, config, hooks.observer)?
    } else {
        run(&mut problem, init, 1, config, hooks.observer)?
    };
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// Starts whose search significance is at least this fraction of the best one's are refined
/// by SIE too: the search scores on a subset, so close calls are decided on all pairs.
const CLOSE_CALL: f64 = 0.5;
/// At most this many starts are refined.
const MAX_STARTS: usize = 3;

/// Correspondence registration from the hypothesis search's most significant poses (the
/// initial guess among them): SIE from each, starting with β₀ at the pose's cluster radius
/// (per component), and the result whose inlier cluster is most significant on all pairs wins.
fn register_from_hypotheses(
    problem: &mut CorrespondenceProblem<'_>,
    source: &[Point],
    target: &[Point],
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let scales = problem.rows().scale.clone();
    let pairs = Pairs {
        source,
        target,
        scales: &scales,
    };
    let search = hypotheses::search(&pairs, &init, config.seed);
    let background = pairs.background();
    let best_significance = search.candidates.first().map_or(0.0, |h| h.cluster.significance);
    if best_significance <= 0.0 {
        // No pose stands out from chance: the paper's method from the initial guess.
        let mut result = run(problem, init, 1, config, observer)?;
        result.search.hypotheses = search.samples as u32;
        return Ok(result);
    }
    let starts = search
        .candidates
        .iter()
        .filter(|h| h.cluster.significance >= CLOSE_CALL * best_significance)
        .take(MAX_STARTS);
    let mut best: Option<(f64, RegistrationResult)> = None;
    let mut next_iteration = 1;
    let mut starts_run = 0;
    let mut squared_norms = Vec::with_capacity(source.len());
    for start in starts {
        let start_config = RegistrationConfig {
            initial_beta: Some(start.cluster.radius / 3f64.sqrt()),
            ..config.clone()
        };
        let mut result = run(problem, start.transform, next_iteration, &start_config, observer.as_deref_mut())?;
        starts_run += 1;
        next_iteration = result.iterations + 1;
        squared_norms.clear();
        squared_norms.extend(
            problem
                .rows()
                .residual
                .chunks_exact(3)
                .zip(&problem.rows().scale)
                .map(|(r, f)| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) / (f * f)),
        );
        let significance = significance::most_significant(&mut squared_norms, &background).significance;
        result.search.start = if start.is_initial_guess {
            StartKind::InitialGuess
        } else {
            StartKind::Hypothesis
        };
        let cancelled = result.stop_reason == StopReason::Cancelled;
        let better = best.as_ref().is_none_or(|(s, _)| significance > *s);
        if better || cancelled {
            result.search.significance = significance;
            best = Some((significance, result));
        }
        if cancelled {
            break;
        }
    }
    let (_, mut result) = best.expect("at least the best candidate ran");
    result.iterations = next_iteration - 1;
    result.search.hypotheses = search.samples as u32;
    result.search.starts_run = starts_run;
    Ok(result)
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
    let mut result = register_to_prepared(source, &prepared, init, config, hooks, prepared.index_seconds())?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// `register_clouds` on clouds the caller hands over (the C ABI's copies): the target's copy
/// is dropped once it is prepared (240 MB at 10 M points). The same result, bit for bit.
pub(crate) fn register_owned_clouds(
    source: &[Point],
    target: Vec<Point>,
    target_normals: Option<Vec<Point>>,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    let prepared = prepare_for(source, &target, target_normals.as_deref(), config)?;
    drop((target, target_normals));
    let mut result = register_to_prepared(source, &prepared, init, config, hooks, prepared.index_seconds())?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// `register_clouds`' checks, in its order, then the target prepared with the config's options.
fn prepare_for(
    source: &[Point],
    target: &[Point],
    target_normals: Option<&[Point]>,
    config: &RegistrationConfig,
) -> Result<PreparedTarget, Error> {
    if let Some(normals) = target_normals {
        if normals.len() != target.len() {
            return Err(Error::InvalidArgument(format!(
                "target has {} points but {} normals",
                target.len(),
                normals.len()
            )));
        }
    }
    if !config.skip_non_finite {
        require_points("source", source.len(), 3)?;
        require_points("target", target.len(), 3)?;
        require_finite("source", source)?;
    }
    PreparedTarget::new(target, target_normals, &PrepareOptions::from_config(config))
}

/// ICP of `source` onto a prepared target: `register_clouds` without building the target's
/// kd-tree (normals estimated by an earlier registration are reused). The result is the one
/// `register_clouds` gives on the same clouds, bit for bit, whatever registrations ran on the
/// target before or run on it concurrently from other threads.
///
/// Errors as `register_clouds`; besides, a point-to-plane config whose `normal_neighbours`
/// differs from the one the target's normals are estimated with (`PrepareOptions`) is
/// refused. `config.skip_non_finite` applies to the source; the target's is fixed when it is
/// prepared.
pub fn register_clouds_to(
    source: &[Point],
    target: &PreparedTarget,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    let mut result = register_to_prepared(source, target, init, config, hooks, 0.0)?;
    result.times.total = started.elapsed().as_secs_f64();
    Ok(result)
}

/// `register_clouds_to` after `config.validate()`; `index_seconds` is what preparing the target
/// cost this call.
fn register_to_prepared(
    source: &[Point],
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
    let source_kept = if config.skip_non_finite {
        finite_indices(source)
    } else {
        None
    };
    let kept_points: Option<Vec<Point>> = source_kept
        .as_ref()
        .map(|kept| kept.iter().map(|&i| source[i as usize]).collect());
    let points = kept_points.as_deref().unwrap_or(source);
    require_points("source", points.len(), 3)?;
    require_finite("source", points)?;
    let init = checked_initial_guess(init)?;
    let share = points.len() as f64 / source.len().max(1) as f64;
    let result = with_share(hooks, share, |hooks| {
        let target_points = if hooks.noise.is_some() || config.noise != NoiseModel::Constant {
            target.points_in_caller_order()
        } else {
            Vec::new()
        };
        let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, points, &target_points)?;
        let workers = Workers::new(config.threads).map_err(Error::InvalidArgument)?;
        let mut problem = CloudProblem::new(
            points,
            target,
            source_sigma,
            target_sigma,
            config,
            workers,
            index_seconds,
        )
        .map_err(Error::InvalidArgument)?;
        register_cloud_problem(&mut problem, init, config, hooks.observer)
    })?;
    if source_kept.is_none() && target.kept().is_none() {
        return Ok(result);
    }
    let source_map = source_kept.unwrap_or_else(|| (0..source.len() as u32).collect());
    Ok(expand(result, &source_map, source.len(), target.kept()))
}

/// ICP on a built problem (target index and normals ready): SIE's starts, or the baseline's
/// single run.
fn register_cloud_problem(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    if config.cost == CostFunction::Sie && config.starts == Starts::Automatic && config.initial_beta.is_none() {
        register_from_widths(problem, init, config, observer)
    } else {
        run(problem, init, 1, config, observer)
    }
}

/// ICP from the initial guess with β₀ at several fractions of the RMS residual: the paper's
/// β₀ (the RMS) lets the non-overlap pull a partial-overlap pair towards the all-points
/// optimum; narrower starts ignore it but cannot travel as far. The result whose inlier
/// cluster is most significant against the initial residuals' spread wins.
fn register_from_widths(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> Result<RegistrationResult, Error> {
    let ladder: Vec<f64> = std::env::var("SIE_LADDER")
        .ok()
        .map(|v| v.split(',').map(|x| x.parse().unwrap()).collect())
        .unwrap_or(vec![1.0, 1.0 / 16.0, 1.0 / 256.0]);
    let cols = problem.cols();
    let squared_norms = |rows: &super::problem::Rows| -> Vec<f64> {
        rows.residual
            .chunks_exact(cols)
            .zip(&rows.scale)
            .map(|(r, f)| r.iter().map(|v| v * v).sum::<f64>() / (f * f))
            .collect()
    };
    let initial = squared_norms(problem.evaluate_all(&init));
    let spread = initial.iter().sum::<f64>() / initial.len().max(1) as f64;
    let background = significance::Background {
        spread_squared: spread.max(f64::MIN_POSITIVE),
        dims: cols,
    };
    let rms_component = (spread / cols as f64).sqrt();
    let mut best: Option<(f64, RegistrationResult)> = None;
    let mut next_iteration = 1;
    let mut starts_run = 0;
    for &fraction in &ladder {
        let mut start = init;
        // A negative fraction: an L1 start first (scale-free), then SIE with β₀ = |fraction|·RMS
        // (0: the paper's β₀ at the L1 result).
        if fraction <= 0.0 {
            let l1 = RegistrationConfig {
                cost: CostFunction::Lp { p: 1.0 },
                ..config.clone()
            };
            let first = run(problem, init, next_iteration, &l1, observer.as_deref_mut())?;
            next_iteration = first.iterations + 1;
            start = first.transform;
        }
        let start_config = RegistrationConfig {
            initial_beta: (fraction != 1.0 && fraction != 0.0).then_some(fraction.abs() * rms_component),
            ..config.clone()
        };
        let mut result = run(problem, start, next_iteration, &start_config, observer.as_deref_mut())?;
        starts_run += 1;
        next_iteration = result.iterations + 1;
        let mut norms = squared_norms(problem.rows());
        let significance = significance::most_significant(&mut norms, &background).significance;
        if std::env::var("SIE_LADDER_DEBUG").is_ok() {
            eprintln!("  ladder {fraction}: significance {significance:.1} sigma {:?} P {:.3}", result.sigma, result.inlier_fraction);
        }
        let cancelled = result.stop_reason == StopReason::Cancelled;
        if cancelled || best.as_ref().is_none_or(|(s, _)| significance > *s) {
            result.search.significance = significance;
            best = Some((significance, result));
        }
        if cancelled {
            break;
        }
    }
    let (_, mut result) = best.expect("at least one start ran");
    result.iterations = next_iteration - 1;
    result.search.starts_run = starts_run;
    Ok(result)
}

