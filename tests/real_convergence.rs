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

use common::data_dir;
use sie::{Hooks, StopReason, register_clouds};

#[test]
fn kinect_frames_that_cycled_at_the_cap_now_converge_where_right() {
    let Some(dir) = data_dir() else { return };
    let cases = scans::depth_pairs(&dir).expect("slambook frames");
    let mut right = 0;
    for case in &cases {
        let methods = case.methods();
        let sie = &methods[0];
        assert_eq!(sie.key, "sie");
        let result = register_clouds(
            &case.source,
            &case.target,
            None,
            None,
            &sie.config,
            Hooks::default(),
        )
        .expect("valid frames");
        let errors = case.errors(&result.transform);
        println!(
            "{} {} -> {}: {:.3} deg, {:.4} m, {:?} after {} updates ({} starts), verdict {:?}",
            case.settings.name,
            case.source_name,
            case.target_name,
            errors.0,
            errors.1,
            result.stop_reason,
            result.iterations,
            result.search.starts_run,
            result.quality.verdict
        );
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
