//! `register_correspondences`: rigid registration of given pairs (the paper's simulation, §6),
//! from the initial guess or the hypothesis search's starts.

use std::time::Instant;

use nalgebra::Matrix4;

use super::config::RegistrationConfig;
use super::hooks::{Hooks, Observer, in_units, with_share};
use super::input::{
    Selection, Skip, checked_initial_guess, expand, noise_sigmas, require_finite, require_points,
    sigma_slices,
};
use super::irls::{RunPlan, searches_starts};
use super::problem::CorrespondenceProblem;
use super::result::RegistrationResult;
use super::search::{register_from_guess, register_from_hypotheses};
use super::units::Units;
use crate::error::Error;
use crate::memory;
use crate::point::Point;

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
    let mut result = register_kept_pairs(source, target, init, config, hooks)?;
    result.times.total = started.elapsed().as_secs_f64();
    result.ensure_finite()
}

/// The pairs the config keeps (`non_finite`, `skip_origin`: a pair is dropped when either
/// point is), registered, with the per-point results back in the caller's indexing.
fn register_kept_pairs(
    source: &[Point],
    target: &[Point],
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    let skip = Skip::of(config);
    if !skip.any() {
        return register_pairs(source, target, init, config, hooks);
    }
    let kept: Vec<u32> = (0..source.len() as u32)
        .filter(|&i| skip.keeps(&source[i as usize]) && skip.keeps(&target[i as usize]))
        .collect();
    if kept.len() == source.len() {
        return register_pairs(source, target, init, config, hooks);
    }
    let pick = |points: &[Point]| kept.iter().map(|&i| points[i as usize]).collect::<Vec<_>>();
    let (source_kept, target_kept) = (pick(source), pick(target));
    let kept = Selection::of_kept(kept, source.len());
    let result = with_share(hooks, kept.share(), |hooks| {
        register_pairs(&source_kept, &target_kept, init, config, hooks)
    })?;
    Ok(expand(result, &kept, source.len(), Some(kept.first())))
}

/// Registration of pairs that are all kept: checked, in safe units, on their problem.
fn register_pairs(
    source: &[Point],
    target: &[Point],
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    hooks: Hooks<'_>,
) -> Result<RegistrationResult, Error> {
    require_points("correspondences", source.len(), 3)?;
    require_finite("source", source)?;
    require_finite("target", target)?;
    let init = checked_initial_guess(init)?;
    let (source_sigma, target_sigma) = noise_sigmas(config, hooks.noise, source, target)?;
    let units = Units::choose(source, target, &sigma_slices(&source_sigma, &target_sigma));
    if units.is_identity() {
        let mut problem = CorrespondenceProblem::new(source, target, source_sigma, target_sigma);
        return Ok(correspondences_on(
            &mut problem,
            source,
            target,
            init,
            config,
            hooks.observer,
        ));
    }
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
    });
    units.result_out(&mut result);
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
) -> RegistrationResult {
    let plan = RunPlan::from_config(config);
    if searches_starts(config) {
        register_from_hypotheses(problem, source, target, init, &plan, config.seed, observer)
    } else {
        register_from_guess(problem, source, target, init, &plan, observer)
    }
}
