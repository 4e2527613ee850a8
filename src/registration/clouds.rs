//! `register_clouds` and `register_clouds_to`: ICP of a source cloud onto a target (prepared
//! here, or by the caller for many registrations), from a warm start, SIE's starts or one run.

use std::borrow::Cow;
use std::time::Instant;

use nalgebra::Matrix4;

use super::config::{Metric, RegistrationConfig};
use super::hooks::{Hooks, Observer, in_units, with_share};
use super::input::{
    Selection, Skip, checked_initial_guess, expand, noise_sigmas, require_finite, require_meeting_scales,
    require_points, sigma_slices,
};
use super::irls::{RunPlan, searches_globally, searches_starts};
use super::problem::CloudProblem;
use super::result::RegistrationResult;
use super::search::{
    FeaturePoses, feature_poses, register_from_feature_poses, register_from_starts, register_one_start,
    run_on_clouds,
};
use super::target::{PrepareOptions, PreparedTarget};
use super::verdict::{Evidence, judged_alone};
use super::warm::{WarmRun, run_warm};
use crate::cost::CostFunction;
use crate::error::Error;
use crate::memory;
use crate::noise::NoiseModel;
use crate::parallel::Workers;
use crate::point::{NonFinite, Point};

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
    let clouds = CloudPair {
        source: Cow::Borrowed(source),
        target: Cow::Borrowed(target),
        target_normals: target_normals.map(Cow::Borrowed),
    };
    register_pair(clouds, init, config, hooks)
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
    let clouds = CloudPair {
        source: Cow::Owned(source),
        target: Cow::Owned(target),
        target_normals: target_normals.map(Cow::Owned),
    };
    register_pair(clouds, init, config, hooks)
}

/// Two clouds as a registration gets them: borrowed from a Rust caller, or owned (the C
/// layer's copies, each dropped as soon as the registration is done with it).
struct CloudPair<'a> {
    source: Cow<'a, [Point]>,
    target: Cow<'a, [Point]>,
    target_normals: Option<Cow<'a, [Point]>>,
}

/// `register_clouds` on borrowed or owned clouds, timed.
fn register_pair(
    clouds: CloudPair<'_>,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let started = Instant::now();
    config.validate()?;
    let CloudPair {
        source,
        target,
        target_normals,
    } = clouds;
    let prepared = prepare_for(&source, &target, target_normals.as_deref(), config)?;
    drop((target, target_normals));
    let index_seconds = prepared.index_seconds();
    let mut result = register_to_prepared(source, &prepared, init, config, hooks, index_seconds)?;
    result.times.total = started.elapsed().as_secs_f64();
    result.ensure_finite()
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
    PreparedTarget::new_within_checked_memory(target, target_normals, &PrepareOptions::from_config(config))
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
    result.ensure_finite()
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
    let skip = Skip::of(config);
    // Refused with the caller's index, before any point is dropped or merged.
    if skip.non_finite == NonFinite::Reject {
        require_finite("source", &source)?;
    }
    let selection = Selection::of(&source, skip, "source")?;
    let kept_points = selection.as_ref().map_or(source_count, Selection::kept_points);
    require_points("source", kept_points, 3)?;
    let points: Cow<'_, [Point]> = match &selection {
        Some(selection) => {
            let picked = selection.first().iter().map(|&i| source[i as usize]).collect();
            drop(source);
            Cow::Owned(picked)
        }
        None => source,
    };
    let target_units = target.units();
    require_meeting_scales(&points, target.points(), target_units.length_out(1.0), || {
        target_units.length_out(target.spacing())
    })?;
    let init = checked_initial_guess(init)?;
    let share = selection.as_ref().map_or(1.0, Selection::share);
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
        // The global stage's poses, from the clouds in the units the problem is built in.
        let global = |source: &[Point], init: &Matrix4<f64>| {
            searches_globally(config)
                .then(|| feature_poses(source, target.points(), init, config.seed, &workers))
                .transpose()
        };
        if units.is_identity() {
            let proposed = global(&points, &init)?;
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
            return Ok::<_, Error>(register_cloud_problem(
                &mut problem,
                init,
                proposed.as_ref(),
                config,
                hooks.observer,
            ));
        }
        let moved = units.points(&points);
        drop(points);
        let proposed = global(&moved, &units.transform_in(&init))?;
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
            register_cloud_problem(
                &mut problem,
                units.transform_in(&init),
                proposed.as_ref(),
                &config,
                observer,
            )
        });
        units.result_out(&mut result);
        Ok(result)
    })?;
    if selection.is_none() && target.kept().is_none() {
        return Ok(result);
    }
    let selection =
        selection.unwrap_or_else(|| Selection::of_kept((0..source_count as u32).collect(), source_count));
    Ok(expand(result, &selection, source_count, target.kept()))
}

/// ICP on a built problem (target index and normals ready): a warm start's run first when the
/// caller gave one, then SIE's starts (from the global stage's `proposed` poses when it ran),
/// or the one run of the paper's method (or a baseline).
fn register_cloud_problem(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    proposed: Option<&FeaturePoses>,
    config: &RegistrationConfig,
    mut observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let plan = RunPlan::from_config(config);
    let sie = config.cost == CostFunction::Sie && config.initial_beta.is_none();
    let mut warm_run = None;
    if let Some(warm) = config.warm_start.filter(|_| sie) {
        match run_warm(problem, init, &plan, &warm, observer.as_deref_mut()) {
            WarmRun::Kept(result) => return result,
            WarmRun::Dropped(result) => warm_run = Some(result),
        }
    }
    // Without a warm start, or after one whose model did not hold: the updates are numbered on.
    let cold = plan.cold();
    let first_iteration = warm_run.as_ref().map_or(1, |r| r.iterations + 1);
    let mut result = if let Some(proposed) = proposed {
        register_from_feature_poses(problem, init, proposed, first_iteration, &cold, observer)
    } else if searches_starts(config) {
        register_from_starts(problem, init, first_iteration, &cold, observer)
    } else if cold.is_sie() {
        register_one_start(problem, init, first_iteration, &cold, observer)
    } else {
        // A baseline: no σ to widen the background by, nor to screen rivals at.
        let evidence = Evidence::of_clouds(problem, &init);
        let (mut result, pending) = run_on_clouds(problem, init, first_iteration, &cold, observer);
        judged_alone(&evidence, problem, &mut result);
        pending.spread_last(problem, &mut result);
        result
    };
    if let Some(mut warm_run) = warm_run {
        warm_run.trace.append(&mut result.trace);
        result.trace = warm_run.trace;
        // The warm run, and the rivals that challenged it when its model held.
        result.search.starts_run += warm_run.search.starts_run.max(1);
    }
    result
}
