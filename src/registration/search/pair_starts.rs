//! Where correspondence registration starts: from the initial guess alone, or from the
//! hypothesis search's most significant poses (SIE from each, its β₀ at the pose's cluster
//! radius, the most significant result kept).

use nalgebra::Matrix4;

use super::choice::BestOfStarts;
use super::hypotheses::{self, Pairs};
use crate::point::Point;
use crate::registration::hooks::Observer;
use crate::registration::irls::{RunPlan, run};
use crate::registration::problem::{CorrespondenceProblem, Problem, Rows};
use crate::registration::result::{RegistrationResult, StartKind};
use crate::registration::verdict::{Evidence, judged_alone};

/// Starts whose search significance is at least this fraction of the best one's are refined
/// by SIE too: the search scores on a subset, so close calls are decided on all pairs.
const CLOSE_CALL: f64 = 0.5;
/// At most this many starts are refined.
const MAX_STARTS: usize = 3;

/// Correspondence registration from the hypothesis search's most significant poses (the
/// initial guess among them): SIE from each, starting with β₀ at the pose's cluster radius
/// (per component), and the most significant result at its own scale wins.
pub(crate) fn register_from_hypotheses(
    problem: &mut CorrespondenceProblem<'_>,
    source: &[Point],
    target: &[Point],
    init: Matrix4<f64>,
    plan: &RunPlan,
    seed: u64,
    mut observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let scales = row_scales(problem.rows());
    let pairs = Pairs {
        source,
        target,
        scales: &scales,
    };
    let search = hypotheses::search(&pairs, &init, seed);
    let best_significance = search.candidates.first().map_or(0.0, |h| h.cluster.significance);
    if best_significance <= 0.0 {
        // No pose stands out from chance: the paper's method from the initial guess.
        let mut result = register_from_guess(problem, source, target, init, plan, observer);
        result.search.hypotheses = search.samples as u32;
        return result;
    }
    let mut best = BestOfStarts::new(Evidence::of_pairs(pairs.background()));
    let starts = search
        .candidates
        .iter()
        .filter(|h| h.cluster.significance >= CLOSE_CALL * best_significance)
        .take(MAX_STARTS);
    for start in starts {
        let start_plan = plan.starting_at_beta(start.cluster.radius / 3f64.sqrt());
        let result = run(
            problem,
            start.transform,
            best.next_iteration,
            &start_plan,
            observer.as_deref_mut(),
        );
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
    result
}

/// One run from the initial guess by `plan` (the paper's method, or a baseline), judged
/// against the background of unrelated pairs.
pub(crate) fn register_from_guess(
    problem: &mut CorrespondenceProblem<'_>,
    source: &[Point],
    target: &[Point],
    init: Matrix4<f64>,
    plan: &RunPlan,
    observer: Option<&mut Observer<'_>>,
) -> RegistrationResult {
    let scales = row_scales(problem.rows());
    let evidence = Evidence::of_pairs(
        Pairs {
            source,
            target,
            scales: &scales,
        }
        .background(),
    );
    let mut result = run(problem, init, 1, plan, observer);
    judged_alone(&evidence, problem, &mut result);
    result
}

/// F_i of every row.
fn row_scales(rows: &Rows) -> Vec<f64> {
    (0..rows.len()).map(|i| rows.scale.get(i)).collect()
}
