//! ICP with no initial guess to trust (`Starts::Global`): SIE from the most significant pose the
//! descriptor matches propose (`feature_poses`); the other proposals and the initial guess are
//! settled by a few updates (on the evidence subset first: one that reaches the best's basin
//! there needs nothing more) and screened against it, and those that could rival it (half its
//! screened significance or more) are run in full, the most significant result at its own scale
//! kept (`BestOfStarts`); then its rivals (`challenge_with_rivals`). A start that ends at another
//! pose nearly as significant lowers the kept one's margin, so a global stage whose candidates
//! disagree is not called GOOD.

use nalgebra::Matrix4;

use super::choice::BestOfStarts;
use super::cloud_starts::{challenge_with_rivals, run_on_clouds};
use super::feature_poses::FeaturePoses;
use super::half_turns::SETTLE_UPDATES;
use crate::registration::hooks::Observer;
use crate::registration::irls::{RunPlan, settle};
use crate::registration::problem::{CloudProblem, Problem, moved_apart};
use crate::registration::result::{RegistrationResult, StartKind, StopReason};
use crate::registration::verdict::{Evidence, MIN_MARGIN};

/// At most this many proposed poses are considered (most significant first), besides the
/// initial guess.
const MAX_PROPOSALS: usize = 4;
/// A settled start within this many fitted σ (RMS over the source points) of the best result
/// is in its basin (`cloud_starts`' near-miss distance).
const SAME_BASIN_SIGMAS: f64 = 10.0;

/// SIE by `plan` from the proposed poses and the initial guess, as the module describes. The
/// background of the significance is the spread of the residuals at the initial guess (a pose
/// unrelated to the truth when the global stage is needed), widened around the first start's
/// result as `register_from_starts` does.
pub(crate) fn register_from_feature_poses(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    proposed: &FeaturePoses,
    first_iteration: u32,
    plan: &RunPlan,
    mut observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let evidence = Evidence::of_clouds(problem, &init);
    let mut best = BestOfStarts::new(evidence);
    best.next_iteration = first_iteration;
    let starts = proposed
        .poses
        .iter()
        .filter(|pose| **pose != init)
        .take(MAX_PROPOSALS)
        .map(|pose| (*pose, StartKind::FeatureMatch))
        .chain(std::iter::once((init, StartKind::InitialGuess)));
    let settling = plan.settling(SETTLE_UPDATES);
    let settling_on_evidence = plan.settling_on_evidence(SETTLE_UPDATES);
    for (from, kind) in starts {
        if let Some((pose, sigma)) = best.best_pose() {
            // In the best's basin already: a full run would only end there again.
            let in_basin = |problem: &CloudProblem<'_>, settled: &Matrix4<f64>| {
                let typical_scale = problem.rows().scale.median();
                moved_apart(problem.probe_points(), &pose, settled)
                    <= SAME_BASIN_SIGMAS * sigma * typical_scale
            };
            // First on the evidence subset (a fifth of the coarse one's cost): most proposals
            // lead into the best's basin, and that is all they need to show.
            let quick = settle(problem, from, &settling_on_evidence);
            if in_basin(problem, &quick) {
                continue;
            }
            let settled = settle(problem, from, &settling);
            if in_basin(problem, &settled) {
                continue;
            }
            // Screened on the evidence subset: worth a full run only if it could lower the
            // best's margin below MIN_MARGIN.
            let cols = problem.cols();
            let own = best.evidence.screen(problem.evaluate_evidence(&pose), cols);
            if best.evidence.screen(problem.evaluate_evidence(&settled), cols) * MIN_MARGIN < own {
                continue;
            }
        }
        best.park();
        let (result, pending) =
            run_on_clouds(problem, from, best.next_iteration, plan, observer.as_deref_mut());
        if best.starts_run == 0 && result.stop_reason != StopReason::Cancelled {
            best.evidence.widen_around(problem, &result);
        }
        if !best.offer(problem, result, Some(pending), kind) {
            return finish(problem, best, proposed);
        }
    }
    challenge_with_rivals(problem, &mut best, plan, &init, observer);
    finish(problem, best, proposed)
}

fn finish(problem: &mut CloudProblem<'_>, best: BestOfStarts, proposed: &FeaturePoses) -> RegistrationResult {
    let mut result = best.finish(problem);
    result.search.hypotheses = proposed.samples as u32;
    result
}
