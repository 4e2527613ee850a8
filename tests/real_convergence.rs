//! Right runs end converged, not at the iteration cap (issue: verdicts a user can trust). The
//! slambook Kinect frames are the real-scan table's pairs whose updates cycled at ~1e-4 m: SIE
//! reached the ground truth and then spent all 200 updates flipping matches (frames 4 → 3 from
//! the identity and from every perturbed start, `ITERATION_LIMIT`), because no update got below
//! the fixed 1e-6 tolerances. The run now stops once an update is below a tenth of the pose's
//! statistical precision (σ·√(6/n)), and says converged.
#![cfg(feature = "io")]
#![allow(dead_code)]

mod common;
#[path = "../examples/experiments/scans.rs"]
mod scans;
#[path = "../examples/experiments/simulation.rs"]
mod simulation;
#[path = "../examples/common/slambook.rs"]
mod slambook;

use common::data_dir;
use sie::{Hooks, RegistrationResult, StopReason, Verdict, register_clouds};

/// SIE on the pair from `init` (the identity when `None`) by `config`.
fn register_pair(
    case: &scans::PairCase,
    init: Option<&nalgebra::Matrix4<f64>>,
    config: &sie::RegistrationConfig,
) -> RegistrationResult {
    register_clouds(&case.source, &case.target, None, init, config, Hooks::default()).expect("valid frames")
}

/// One run's line in the test's output: the pair, its errors and how it ended.
fn describe(case: &scans::PairCase, result: &RegistrationResult) -> String {
    let (degrees, metres) = case.errors(&result.transform);
    format!(
        "{} {} -> {}: {degrees:.3} deg, {metres:.4} m, {:?} after {} updates ({} starts), \
         verdict {:?} (margin {:.3}, σ/spacing {:.2})",
        case.settings.name,
        case.source_name,
        case.target_name,
        result.stop_reason,
        result.iterations,
        result.search.starts_run,
        result.quality.verdict,
        result.quality.margin,
        result.quality.sigma_to_spacing
    )
}

#[test]
fn kinect_frames_that_cycled_at_the_cap_now_converge_where_right() {
    let Some(dir) = data_dir() else { return };
    let cases = scans::depth_pairs(&dir).expect("slambook frames");
    let mut right = 0;
    for case in &cases {
        let methods = case.methods();
        let sie = &methods[0];
        assert_eq!(sie.key, "sie");
        let result = register_pair(case, None, &sie.config);
        let errors = case.errors(&result.transform);
        println!("{}", describe(case, &result));
        if case.success(errors) {
            right += 1;
            assert_eq!(
                result.stop_reason,
                StopReason::Converged,
                "{} {} -> {}: right but {:?}",
                case.settings.name,
                case.source_name,
                case.target_name,
                result.stop_reason
            );
        }
    }
    // The table's SIE gets most of these pairs right from the identity.
    assert!(right >= cases.len() / 2, "{right} of {} right", cases.len());
}

/// Right runs are GOOD: on the Kinect frames (both noise models, from the identity and from
/// the perturbed starts of the real-scan table), starts that end within the noise of each
/// other are one pose, not rivals. Before: a right run was DOUBTFUL with a margin of 1.000–1.02
/// whenever another start stopped 0.1° / a few mm away (19 of these 24 right runs were GOOD,
/// now 22; 79 of the real-scan table's 104 right SIE runs, now 92).
#[test]
fn right_runs_on_the_kinect_frames_are_good() {
    let Some(dir) = data_dir() else { return };
    let cases = scans::depth_pairs(&dir).expect("slambook frames");
    let (mut right, mut right_and_good) = (0, 0);
    for (seed, case) in cases.iter().enumerate() {
        let sie = &case.methods()[0];
        for (start, init) in case.starts(seed as u64) {
            let result = register_pair(case, Some(&init), &sie.config);
            let errors = case.errors(&result.transform);
            let good = result.quality.verdict == Verdict::Good;
            println!("[{start}] {}", describe(case, &result));
            if case.success(errors) {
                right += 1;
                right_and_good += usize::from(good);
            }
        }
    }
    assert!(right >= 16, "only {right} right runs");
    assert!(
        right_and_good * 10 >= right * 9,
        "{right_and_good} of {right} right runs GOOD (at least 90 % expected)"
    );
}

/// Odometry's frames: each Kinect frame onto the one before from a constant-velocity guess
/// (the previous pair's motion), with the default registration. Frame 5 onto 4 is fixed weakly
/// along one direction (conditioning 0.06), where plain updates creep by a fifth of the pose's
/// standard error until the update cap; a right run must still converge and be GOOD, or
/// `Odometry` sets a right frame aside.
#[test]
fn kinect_frames_from_a_constant_velocity_guess_converge_where_right() {
    let Some(dir) = data_dir() else { return };
    let cases = scans::depth_pairs(&dir).expect("slambook frames");
    let constant: Vec<_> = cases
        .iter()
        .filter(|case| case.settings.noise == sie::NoiseModel::Constant)
        .collect();
    let mut right = 0;
    for pair in constant.windows(2) {
        let (previous, case) = (pair[0], pair[1]);
        let result = register_pair(
            case,
            Some(&previous.ground_truth),
            &sie::RegistrationConfig::default(),
        );
        let errors = case.errors(&result.transform);
        println!("{}", describe(case, &result));
        if case.success(errors) {
            right += 1;
            assert_eq!(result.stop_reason, StopReason::Converged, "{}", case.source_name);
            assert_eq!(result.quality.verdict, Verdict::Good, "{}", case.source_name);
        }
    }
    assert!(right >= 2, "{right} of {} right", constant.len() - 1);
}
