//! SIE beyond the paper's one-axis grid: the paper's correspondence protocol (1000 inliers in
//! [0,1]³, σ = 0.01 per axis, the §6 outliers, start at the identity, error = RMS over the true
//! inliers above their least-squares fit, failure = error above the noise) with motions and
//! outliers the grid does not contain. Each family of `examples/experiments/beyond.rs` runs a
//! fixed set of its instances (the table in docs/results.md, "Beyond the grid", runs 100 per
//! family with every baseline) and must have no failure and a mean error below 1e-6.
#[path = "../examples/experiments/beyond.rs"]
mod beyond;
#[path = "../examples/experiments/simulation.rs"]
mod simulation;

use std::f64::consts::PI;

use beyond::{Draw, Family, families};
use sie::{Hooks, RegistrationConfig, StartKind, Starts, register_correspondences};
use simulation::{ErrorMetric, FAILURE_THRESHOLD, Reference};

/// Registers instances `0..instances` of `family` with SIE's defaults; asserts no failure and a
/// mean error of the successes below 1e-6 (the paper's precision claim).
fn check(family: &Family, instances: usize) {
    let mut errors = Vec::new();
    for k in 0..instances {
        let data = family.instance(k);
        let reference = Reference::new(&data, ErrorMetric::Rms);
        let result = register_correspondences(
            &data.source,
            &data.target,
            None,
            &RegistrationConfig::default(),
            Hooks::default(),
        )
        .expect("valid input");
        let error = reference.error(&result.transform);
        assert!(
            error <= FAILURE_THRESHOLD,
            "{}, instance {k} (seed {}): error {error:.3e} above the noise; {:?}",
            family.label(),
            family.seed(k),
            result.search
        );
        errors.push(error);
    }
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    println!(
        "{}: {instances} instances, no failure, mean error {mean:.2e}",
        family.label()
    );
    assert!(mean < 1e-6, "{}: mean error {mean:.3e}", family.label());
}

fn instances_per_family(family: &Family) -> usize {
    if family.outliers >= 10_000 { 8 } else { 16 }
}

#[test]
fn every_family_with_up_to_as_many_outliers_as_inliers() {
    for family in families().iter().filter(|f| f.outliers <= 1000) {
        check(family, instances_per_family(family));
    }
}

#[test]
fn every_family_with_ten_outliers_per_inlier() {
    for family in families().iter().filter(|f| f.outliers > 1000) {
        check(family, instances_per_family(family));
    }
}

#[test]
fn the_summary_says_which_start_decided() {
    let family = Family {
        draw: Draw::Rotation(PI),
        outliers: 1000,
        structured: 0,
    };
    let data = family.instance(0);
    let reference = Reference::new(&data, ErrorMetric::Rms);
    // From the identity the inliers' pose is far away: a hypothesis decides.
    let config = RegistrationConfig::default();
    let result =
        register_correspondences(&data.source, &data.target, None, &config, Hooks::default()).unwrap();
    assert_eq!(result.search.start, StartKind::Hypothesis);
    assert!(result.search.hypotheses >= 32 && result.search.starts_run >= 1);
    assert!(result.search.significance > 1000.0, "{:?}", result.search);
    assert!(reference.error(&result.transform) < 1e-6);
    // Started at the inliers' fit, the initial guess wins (or a hypothesis in its basin) and
    // the fit is kept.
    let from_truth = register_correspondences(
        &data.source,
        &data.target,
        Some(&reference.mle),
        &config,
        Hooks::default(),
    )
    .unwrap();
    assert!(reference.error(&from_truth.transform) < 1e-6);
    // The paper's method alone: no search, the initial guess decides.
    let paper_only = RegistrationConfig {
        starts: Starts::InitialGuess,
        ..RegistrationConfig::default()
    };
    let local =
        register_correspondences(&data.source, &data.target, None, &paper_only, Hooks::default()).unwrap();
    assert_eq!(local.search.start, StartKind::InitialGuess);
    assert_eq!((local.search.hypotheses, local.search.starts_run), (0, 1));
}
