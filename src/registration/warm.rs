//! A sequence's warm start: the previous registration's noise model as the first start, and
//! whether that model held on the new frame (otherwise the registration runs as without it).

use nalgebra::Matrix4;

use super::hooks::Observer;
use super::irls::RunPlan;
use super::problem::{CloudProblem, Problem, moved_apart};
use super::result::{RegistrationResult, StartKind, StopReason, Verdict};
use super::search::{BestOfStarts, challenge_with_rivals, run_on_clouds};
use super::verdict::{Evidence, judged_alone};
use crate::sie::WarmStart;
use crate::sie::schedule::WARM_BETA_WIDTHS;

impl WarmStart {
    /// The noise model a registration ended with, to start the next one from (`None` for a
    /// baseline cost, a result without a usable σ, or one not GOOD).
    ///
    /// A warm run is kept only when its result is GOOD (`run_warm`), and after a frame that was
    /// not GOOD it rarely is (the same loose scene or the same bad guess again): the warm run
    /// would be paid for and then dropped for the cold search. Such a frame runs cold.
    pub fn of(result: &RegistrationResult) -> Option<WarmStart> {
        if result.beta.is_empty() || result.quality.verdict != Verdict::Good {
            return None;
        }
        Self::from_fit(
            &result.sigma,
            result.penalty,
            result.noise_shape,
            result.inlier_fraction,
        )
        .ok()
    }
}

/// What became of a warm run.
pub(crate) enum WarmRun {
    /// Its model held and its result is GOOD (or the caller cancelled it): the registration's
    /// result, judged.
    Kept(RegistrationResult),
    /// Its model did not hold, or its result was not GOOD: only its trace, update and start
    /// counts go on.
    Dropped(RegistrationResult),
}

/// SIE from the initial guess by `plan` (which starts from `warm`), kept when the model held
/// and the result, challenged by its rivals, is GOOD.
pub(crate) fn run_warm(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    plan: &RunPlan,
    warm: &WarmStart,
    mut observer: Option<&mut Observer<'_>>,
) -> WarmRun {
    let (mut result, pending) = run_on_clouds(problem, init, 1, plan, observer.as_deref_mut());
    result.search.start = StartKind::WarmStart;
    let typical_scale = problem.rows().scale.median();
    let moved = moved_apart(problem.probe_points(), &init, &result.transform) / typical_scale;
    if result.stop_reason == StopReason::Cancelled {
        let evidence = Evidence::around(problem, &result);
        judged_alone(&evidence, problem, &mut result);
        // `around` left the rows at the result: the final evaluation's, bit for bit.
        pending.spread_last(problem, &mut result);
        return WarmRun::Kept(result);
    }
    if warm_model_held(warm, &result, moved) {
        // As a cold single start: judged against its near misses, challenged by its rivals
        // (half and quarter turns, period shifts).
        let mut best = BestOfStarts::new(Evidence::around(problem, &result));
        if best.offer(problem, result, Some(pending), StartKind::WarmStart) {
            challenge_with_rivals(problem, &mut best, &plan.cold(), &init, observer);
        }
        let judged = best.finish(problem);
        // A model can "hold" at a wrong guess that it never left: after a standstill the
        // guess is zero motion, and a street's ground and fronts, which run along the motion,
        // fit there as well as before while β₀ = 2σ is too narrow to see the 0.5 m the vehicle
        // moved (nothing moved, so the reach rule sees nothing). The verdict does (the motion
        // along the street is loose there): a result not GOOD goes to the cold search, which
        // starts wide. (A cancelled run ends as the best.)
        return if judged.stop_reason == StopReason::Cancelled || judged.quality.verdict == Verdict::Good {
            WarmRun::Kept(judged)
        } else {
            WarmRun::Dropped(judged)
        };
    }
    WarmRun::Dropped(result)
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
        && result.sigma_rms() <= WARM_SIGMA_GROWTH * warm.sigma
        && result.inlier_fraction >= WARM_INLIER_SHARE * warm.inlier_fraction
        && moved <= WARM_REACH_WIDTHS * (1.0 + WARM_BETA_WIDTHS) * warm.sigma
}

/// See [`warm_model_held`].
const WARM_REACH_WIDTHS: f64 = 3.0;

/// See [`warm_model_held`].
const WARM_SIGMA_GROWTH: f64 = 2.0;
/// See [`warm_model_held`].
const WARM_INLIER_SHARE: f64 = 0.5;
