//! Where SIE starts on two clouds, and which start's result is kept.
//!
//! §4.3 leaves β₀ open ("prior knowledge about the uncertainty of T or … the standard
//! deviation of the initial set of residuals"). The RMS of the initial residuals (the paper's
//! choice) is right when the initial guess is poor, but on partially overlapping scans it also
//! counts the points with no counterpart: the first levels then weigh almost everything and
//! follow the all-points optimum away from a good initial guess. A β₀ far below the RMS keeps a
//! good guess but cannot travel far from a poor one; and when the initial residuals have no
//! peak at all, a scale-free IRLS (L1) finds the basin better than either. None of the three
//! wins everywhere, so ICP runs all of them from the initial guess and keeps the result whose
//! inlier cluster is most significant at its own fitted scale (`significance::at_scale`).
//! docs/performance.md ("Design measurements behind the code") has what each start wins on the
//! real scans.

use nalgebra::{Matrix4, Translation3};

use super::choice::BestOfStarts;
use super::half_turns::{QuarterTurns, RivalProgress, SETTLE_UPDATES, TurnedRivals, inliers_at};
use super::period_shifts::period_shifts;
use super::quarter_turns::QUARTER_TURN_REACH;
use super::scaled_source::fit_scaled;
use crate::registration::hooks::Observer;
use crate::registration::irls::{
    FinalRoundGate, GatedRun, PendingPerPoint, RunPlan, run_pending, run_pending_gated, settle,
};
use crate::registration::problem::{CloudProblem, Problem, moved_apart};
use crate::registration::result::{RegistrationResult, StartKind, StopReason};
use crate::registration::verdict::{Evidence, mean_squared_norm};

/// Before SIE: nothing, or a scale-free IRLS run whose result SIE starts from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Lead {
    /// SIE from the initial guess itself.
    None,
    /// IRLS with the L1 weight 1/max(‖r‖, δ) (no scale to tune) until its updates are small
    /// against the initial residuals.
    ScaleFree,
}

/// One start of SIE on two clouds.
#[derive(Clone, Copy, Debug, PartialEq)]
struct CloudStart {
    /// What runs before SIE.
    lead: Lead,
    /// β₀ as a fraction of the RMS residual at SIE's start (1: the paper's β₀).
    beta_fraction: f64,
}

/// The starts ICP runs from one initial guess, in order: the paper's, a narrow one, and a
/// scale-free lead followed by the paper's.
const CLOUD_STARTS: [CloudStart; 3] = [
    CloudStart {
        lead: Lead::None,
        beta_fraction: 1.0,
    },
    CloudStart {
        lead: Lead::None,
        beta_fraction: NARROW_BETA_FRACTION,
    },
    CloudStart {
        lead: Lead::ScaleFree,
        beta_fraction: 1.0,
    },
];

/// The narrow start's β₀ as a fraction of the RMS residual at the guess.
const NARROW_BETA_FRACTION: f64 = 1.0 / 256.0;

/// The scale-free lead stops when an update moves the source centroid by less than this
/// fraction of the initial RMS residual and rotates it by less than LEAD_ROTATION_TOLERANCE:
/// it only has to reach the basin, SIE does the rest.
const LEAD_TRANSLATION_FRACTION: f64 = 1e-3;
/// See [`LEAD_TRANSLATION_FRACTION`].
const LEAD_ROTATION_TOLERANCE: f64 = 1e-4;

/// A run on a cloud problem with its stage times completed (the index and the normals that
/// matching reached, moved out of the stages that reached them).
pub(crate) fn run_on_clouds(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
) -> (RegistrationResult, PendingPerPoint) {
    let before = problem.setup_time();
    let (mut result, pending) = run_pending(problem, init, first_iteration, plan, observer);
    problem.setup_time().complete(&before, &mut result.times);
    (result, pending)
}

/// [`run_on_clouds`] with `gate` asked before each final-round update whether to go on
/// (`irls::run_pending_gated`).
fn run_on_clouds_gated(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
    gate: &mut FinalRoundGate<'_>,
) -> GatedRun {
    let before = problem.setup_time();
    let mut run = run_pending_gated(problem, init, first_iteration, plan, observer, gate);
    if let GatedRun::Finished(result, _) = &mut run {
        problem.setup_time().complete(&before, &mut result.times);
    }
    run
}

/// ICP from the initial guess by each of [`CLOUD_STARTS`], each with its own plan; the most
/// significant result at its own scale wins. The background of the significance is the spread
/// of the residuals at the initial guess (over the evidence subset), widened by
/// `Evidence::around`. `plan` is the caller's run (SIE from the paper's β₀, no warm start).
pub(crate) fn register_from_starts(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    mut observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let evidence = Evidence::of_clouds(problem, &init);
    // The RMS of every initial residual scales the later starts (the narrow β₀, the lead's
    // tolerance); it needs a pass over every source point, made only when a later start runs.
    let mut initial_rms = None;
    let mut rms =
        |problem: &mut CloudProblem<'_>| *initial_rms.get_or_insert_with(|| residual_rms(problem, &init));
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
                let lead =
                    plan.scale_free_lead(LEAD_TRANSLATION_FRACTION * rms(problem), LEAD_ROTATION_TOLERANCE);
                let (mut led, pending) =
                    run_on_clouds(problem, init, best.next_iteration, &lead, observer.as_deref_mut());
                if led.stop_reason == StopReason::Cancelled {
                    best.offer(problem, led, Some(pending), StartKind::ScaleFreeLead);
                    break;
                }
                best.next_iteration = led.iterations + 1;
                best.trace.append(&mut led.trace);
                (led.transform, StartKind::ScaleFreeLead)
            }
        };
        let (kind, start_plan) = if start.beta_fraction < 1.0 {
            let narrow = plan.starting_at_beta(start.beta_fraction * rms(problem));
            (StartKind::NarrowBeta, narrow)
        } else {
            (kind, plan.clone())
        };
        let (result, pending) = run_on_clouds(
            problem,
            from,
            best.next_iteration,
            &start_plan,
            observer.as_deref_mut(),
        );
        // Only a converged run can show the guess was right (one stopped at the cap while β was
        // still wide has not looked closely yet).
        let moved = (kind == StartKind::InitialGuess && result.stop_reason == StopReason::Converged)
            .then(|| moved_in_widths(problem, &init, &result));
        // A guess near the right pose has residuals that are mostly inliers, not the background
        // a wrong pose would show (judged against them alone, the right pose of every frame of a
        // 100-frame odometry run from constant-velocity guesses was UNSUPPORTED). The first
        // start's result shifted by 10σ shows one; the wider of the two backgrounds judges
        // every start.
        if best.starts_run == 0 {
            // Leaves the rows at the result: the final evaluation's again, bit for bit.
            best.evidence.widen_around(problem, &result);
        }
        if !best.offer(problem, result, Some(pending), kind) {
            return best.finish(problem);
        }
        let Some(moved) = moved else { continue };
        // Near its guess and right in every direction its surfaces fix, a first start leaves
        // the other starts (from the same guess) little to find: one ending along its loose
        // direction must be clearly more significant to replace it (`choice`), and the rivals
        // still run.
        if moved <= STAYED_SIGMAS
            || (moved <= REACHED_SIGMAS && best.best_is_good_alone_but_for_conditioning())
        {
            break;
        }
        // Further, a result GOOD on its own evidence ends the search too when it corrected
        // the guess locally or the paper's run from it stays there (as one start's must,
        // `register_one_start`): the other starts are for a first start that is weak or does
        // not hold. So does one GOOD but for its conditioning within a local correction's
        // reach, when that run stays: it is no local correction while a direction is left
        // free, and from further away the other starts may find a pose the loose one missed.
        // (An exact fit, σ = 0, has no widths to count: `moved` is NaN there and neither rule
        // applies.)
        if moved > REACHED_SIGMAS
            && (best.best_is_good_alone()
                || (best.best_is_good_alone_but_for_conditioning()
                    && within_local_reach(problem, &best, &init)))
        {
            if corrected_locally(problem, &best, &init) {
                break;
            }
            match rerun_from_best(problem, &mut best, &start_plan, observer.as_deref_mut()) {
                RerunEnd::Cancelled => return best.finish(problem),
                RerunEnd::SamePose => break,
                RerunEnd::Elsewhere => {}
            }
        }
    }
    challenge_with_rivals(problem, &mut best, plan, &init, observer);
    best.finish(problem)
}

/// One start of SIE from `init` (the single-start setting), confirmed when it travelled beyond
/// a local correction: a result more than `REACHED_SIGMAS` from its guess, not within
/// [`LOCAL_REACH`] or not fixed in every direction, has not shown that the paper's run, started
/// at it, stays there (at a wrong pose with few inliers the wide first levels, which weigh the
/// rest of the overlap, pull it away; at a right one they fit it again). The run from the result
/// is offered as another start, and replaces the first when it ends at the same pose (the last
/// update is then the result, as with one run). Then the rivals challenge the best; when that
/// far result is still not GOOD on its own evidence, the search's narrow start runs from the
/// guess too (and its rivals, when it wins). A β₀ the caller fixed runs once.
pub(crate) fn register_one_start(
    problem: &mut CloudProblem<'_>,
    init: Matrix4<f64>,
    first_iteration: u32,
    plan: &RunPlan,
    mut observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let mut evidence = Evidence::of_clouds(problem, &init);
    let (result, pending) = run_on_clouds(problem, init, first_iteration, plan, observer.as_deref_mut());
    let travelled = plan.starts_at_residual_rms()
        && result.stop_reason == StopReason::Converged
        && moved_in_widths(problem, &init, &result) > REACHED_SIGMAS;
    // As for the first of several starts (`register_from_starts`), rows left at the result.
    evidence.widen_around(problem, &result);
    let mut best = BestOfStarts::new(evidence);
    best.next_iteration = first_iteration;
    if !best.offer(problem, result, Some(pending), StartKind::InitialGuess) {
        return best.finish(problem);
    }
    let far = travelled && !corrected_locally(problem, &best, &init);
    if far && rerun_from_best(problem, &mut best, plan, observer.as_deref_mut()) == RerunEnd::Cancelled {
        return best.finish(problem);
    }
    challenge_with_rivals(problem, &mut best, plan, &init, observer.as_deref_mut());
    // A guess whose wide first levels went far and found nothing GOOD there may still sit on a
    // narrow peak: a small overlap, whose residuals a β₀ as wide as the RMS of all of them
    // drowns in the rest. The search's narrow start looks there; its rivals run if it wins.
    if far && !best.best_is_good_alone() {
        let narrow = plan.starting_at_beta(NARROW_BETA_FRACTION * residual_rms(problem, &init));
        let before = best.best_pose().map(|(transform, _)| transform);
        best.park();
        let (result, pending) = run_on_clouds(
            problem,
            init,
            best.next_iteration,
            &narrow,
            observer.as_deref_mut(),
        );
        if !best.offer(problem, result, Some(pending), StartKind::NarrowBeta) {
            return best.finish(problem);
        }
        if best.best_pose().map(|(transform, _)| transform) != before {
            challenge_with_rivals(problem, &mut best, plan, &init, observer);
        }
    }
    best.finish(problem)
}

/// RMS of every residual at `init`, per residual component: the scale of the later starts (the
/// narrow β₀, the lead's tolerance). A pass over every source point.
fn residual_rms(problem: &mut CloudProblem<'_>, init: &Matrix4<f64>) -> f64 {
    let cols = problem.cols();
    (mean_squared_norm(problem.evaluate_all(init), cols) / cols as f64).sqrt()
}

/// A result is confirmed by the paper's run from it (`rerun_from_best`) unless it lies within
/// this fraction of the target's spread (RMS distance from its centroid, as
/// [`QUARTER_TURN_REACH`]) of the caller's guess and its surfaces fix every direction of its
/// pose: a local correction of the guess. What the rerun catches is a result that slid along a
/// direction its surfaces leave free, or one that travelled across the scene into another
/// basin (about a spread or more); a sequence's frames and most real pairs from a near guess
/// are neither, and pay for no second run.
const LOCAL_REACH: f64 = 0.5;

/// Whether the best result corrected the guess `init` locally (see [`LOCAL_REACH`]).
fn corrected_locally(problem: &CloudProblem<'_>, best: &BestOfStarts, init: &Matrix4<f64>) -> bool {
    best.best_is_constrained() && within_local_reach(problem, best, init)
}

/// Whether the best result moved the source by less than [`LOCAL_REACH`] of the target's
/// spread from the guess `init`.
fn within_local_reach(problem: &CloudProblem<'_>, best: &BestOfStarts, init: &Matrix4<f64>) -> bool {
    best.best_pose().is_some_and(|(transform, _)| {
        moved_apart(problem.probe_points(), init, &transform) < LOCAL_REACH * problem.target_spread()
    })
}

/// Where a run from the best result's own pose ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RerunEnd {
    /// At the same pose (it replaced the best: the later run is the one that stayed).
    SamePose,
    /// Elsewhere (offered as another start).
    Elsewhere,
    /// The caller cancelled it.
    Cancelled,
}

/// Runs `plan` from the best result's pose and offers the result (`BestOfStarts::offer_rerun`).
fn rerun_from_best(
    problem: &mut CloudProblem<'_>,
    best: &mut BestOfStarts,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
) -> RerunEnd {
    let Some((end, _)) = best.best_pose() else {
        return RerunEnd::Elsewhere;
    };
    best.park();
    let (rerun, pending) = run_on_clouds(problem, end, best.next_iteration, plan, observer);
    match best.offer_rerun(problem, rerun, pending) {
        None => RerunEnd::Cancelled,
        Some(true) => RerunEnd::SamePose,
        Some(false) => RerunEnd::Elsewhere,
    }
}

/// Runs SIE by `plan` from each rival pose of the best result so far that stays a rival once
/// settled, offered as another start: a better rival wins, one nearly as good lowers the
/// margin. The rivals are its half turns (`half_turns`), its shifts by a period of structure
/// its inliers repeat (`period_shifts`, screened as shifted: they need no settling to come
/// near) and, when its surfaces fix every direction and it moved the source by more than
/// [`QUARTER_TURN_REACH`] of the target's spread from the caller's guess `init`, its quarter
/// turns (`quarter_turns`; one that settles back within [`REACHED_SIGMAS`] of the best is the
/// best's own basin, not run; a plane's result, doubted for the directions it leaves free,
/// would only trade one free pose for a tied other). A rival far behind the best that stops
/// gaining on it in its final round is stopped there (`RivalProgress`). Then a fit that scales
/// the source (`scaled_source`) challenges the best.
pub(crate) fn challenge_with_rivals(
    problem: &mut CloudProblem<'_>,
    best: &mut BestOfStarts,
    plan: &RunPlan,
    init: &Matrix4<f64>,
    mut observer: Option<&mut Observer<'_>>,
) {
    let Some((transform, sigma)) = best.best_pose() else {
        return;
    };
    let quarter = if best.best_is_constrained()
        && moved_apart(problem.probe_points(), init, &transform)
            > QUARTER_TURN_REACH * problem.target_spread()
    {
        QuarterTurns::Tried
    } else {
        QuarterTurns::Skipped
    };
    let turns = TurnedRivals::of(problem, &best.evidence, &transform, sigma, quarter);
    let shifts: Vec<Matrix4<f64>> = period_shifts(best.best_surfaces())
        .into_iter()
        .map(|shift| Translation3::from(shift).to_homogeneous() * transform)
        .filter(|shifted| turns.rivals(problem, &best.evidence, shifted))
        .collect();
    let rivals = turns
        .poses
        .iter()
        .copied()
        .chain(shifts.into_iter().map(|pose| (pose, StartKind::PeriodShift)));
    let settling = plan.settling(SETTLE_UPDATES);
    let settling_on_evidence = plan.settling_on_evidence(SETTLE_UPDATES);
    // What the rivals are counted against, once one is run: the best's inliers among every row.
    let mut best_inliers = None;
    for (rival, kind) in rivals {
        let settled = if kind == StartKind::QuarterTurn {
            settle(problem, rival, &settling_on_evidence)
        } else {
            settle(problem, rival, &settling)
        };
        if kind == StartKind::QuarterTurn && best.best_apart_in_sigmas(problem, &settled) <= REACHED_SIGMAS {
            continue;
        }
        if !turns.rivals(problem, &best.evidence, &settled) {
            continue;
        }
        let own = *best_inliers.get_or_insert_with(|| inliers_at(problem, &transform, sigma));
        best.park();
        let mut progress = RivalProgress::new(own, sigma);
        let run = run_on_clouds_gated(
            problem,
            rival,
            best.next_iteration,
            plan,
            observer.as_deref_mut(),
            &mut |problem, pose| progress.worth_going_on(problem, pose),
        );
        let (result, pending) = match run {
            GatedRun::Finished(result, pending) => (*result, pending),
            GatedRun::Dropped { iterations, trace } => {
                best.pass_over_unfinished(iterations, trace);
                continue;
            }
        };
        // The rows are the rival's final evaluation: every row, as `own` counted.
        if result.stop_reason != StopReason::Cancelled && !turns.nearly_as_good(problem, sigma, own) {
            best.pass_over(result);
            continue;
        }
        if !best.offer(problem, result, Some(pending), kind) {
            return;
        }
    }
    // Last, at the pose that stays: whether a scaled source explains the data better. Only a
    // result that is GOOD on its own evidence has a verdict to lose.
    if best.best_is_good_alone() {
        if let Some((transform, sigma)) = best.best_pose() {
            let fit = fit_scaled(
                problem,
                &best.evidence,
                &transform,
                sigma,
                best.best_inlier_fraction(),
            );
            best.scaled_source = fit.and_then(|fit| fit.rival());
        }
    }
}

/// How far the paper's start (the widest β) moved the source points from the initial guess, in
/// fitted σ (RMS). Within `STAYED_SIGMAS` the guess was already right to within the noise:
/// narrower starts from the same guess cannot be pulled elsewhere by data that did not pull the
/// widest one. Within `REACHED_SIGMAS`, a result GOOD on its own evidence (no other start to
/// compare with) ends the search too: a sequence's constant-velocity guess, off by the
/// acceleration, is the common case (one start, the paper's cost). Further, such a result ends
/// it when it corrected the guess locally ([`LOCAL_REACH`]), or else once the paper's run from
/// the result stays there (two runs instead of three starts).
fn moved_in_widths(problem: &dyn Problem, init: &Matrix4<f64>, result: &RegistrationResult) -> f64 {
    let typical_scale = problem.rows().scale.median();
    moved_apart(problem.probe_points(), init, &result.transform) / (typical_scale * result.sigma_rms())
}

/// See [`moved_in_widths`].
const STAYED_SIGMAS: f64 = 3.0;
/// See [`moved_in_widths`]: the near-miss distance of `Evidence::around`.
const REACHED_SIGMAS: f64 = 10.0;
