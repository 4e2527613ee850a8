//! Poses a near-symmetric scene explains nearly as well as the result (project issue 29). An
//! object turned half a turn about one of its principal axes lies on itself but for its few
//! asymmetric details (a box with a bump at one end): ICP from a guess near the flip stays there
//! with most points inliers, and a single start has nothing to compare that with. The rivals are
//! the result's inliers turned half a turn about each of their principal axes through their
//! centroid. Each is screened on the evidence subset by its scale-free significance; one that
//! comes near the result's is refined by SIE and offered as another start, so that a better
//! rival wins and one nearly as good makes the result a close call (its margin). The same
//! screens and count judge the result's quarter turns (`quarter_turns`, settled without the
//! first screen) and period shifts (`period_shifts`).

use std::ops::ControlFlow;

use nalgebra::{Matrix3, Matrix4, Vector3};

use super::quarter_turns::quarter_turns;
use crate::geometry::{centroid, principal_axes};
use crate::registration::problem::{CloudProblem, Problem, Rows};
use crate::registration::result::StartKind;
use crate::registration::significance::inlier_radius_squared;
use crate::registration::verdict::{Evidence, MIN_MARGIN};

/// A half turn is settled (a short SIE run on the coarse subset) when its scale-free
/// significance on the evidence subset, as turned, reaches this fraction of the result's. As
/// turned it is off by the asymmetric details' pull on the centroid and the axes (a box with a
/// bump: centimetres, several σ), so it scores far below what it settles to: a twentieth.
const TURNED_SHARE: f64 = 0.05;

/// Updates a half turn settles for: enough to close the few σ its turn is off by.
pub(crate) const SETTLE_UPDATES: u32 = 15;

/// A refined half turn is no rival when, at the result's inlier radius, it holds fewer of the
/// residuals than the result by more than this many standard deviations of that count
/// (√count): it explains clearly less of the data at the same precision (a room's
/// walls turned onto themselves, without its furniture).
const FEWER_INLIERS_DEVIATIONS: f64 = 3.0;

/// A rival in its final round holding less than this share of the result's inliers (at the
/// result's inlier radius, every row) is far behind: see [`RivalProgress`].
const FAR_BEHIND_SHARE: f64 = 0.5;

/// Final-round updates between two counts of a far-behind rival's inliers.
const PROGRESS_PERIOD: u32 = 10;

/// A far-behind rival that gained no more than this many standard deviations of the result's
/// count (√own) over the last [`PROGRESS_PERIOD`] updates has stopped gaining: within the
/// count's own noise.
const PROGRESS_DEVIATIONS: f64 = 1.0;

/// Fewer inliers than this on the evidence subset do not give principal axes worth turning
/// about.
const MIN_INLIERS: usize = 12;

/// Whether a result's quarter turns challenge it (`cloud_starts::challenge_with_rivals` says
/// when).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum QuarterTurns {
    /// Only the half turns.
    Skipped,
    /// The quarter turns too.
    Tried,
}

/// The turns of a result worth settling, and the result's own scale-free significance on the
/// evidence subset that they are judged against.
pub(crate) struct TurnedRivals {
    pub(crate) poses: Vec<(Matrix4<f64>, StartKind)>,
    own: f64,
}

impl TurnedRivals {
    /// Those half turns of the pose `transform` (fitted σ `sigma`) that score at least
    /// [`TURNED_SHARE`] of the pose's own significance on the evidence subset, and when
    /// `quarter` says so its quarter turns (`quarter_turns`: off by decimetres as turned,
    /// beyond what the screen sees, they are all settled). Leaves the problem's rows at the
    /// evidence subset's.
    pub(crate) fn of(
        problem: &mut CloudProblem<'_>,
        evidence: &Evidence,
        transform: &Matrix4<f64>,
        sigma: f64,
        quarter: QuarterTurns,
    ) -> Self {
        let cols = problem.cols();
        let inliers = problem.evidence_points_within(transform, inlier_radius_squared(sigma, cols));
        // The rows are the evidence subset's at `transform` still.
        let own = evidence.screen(problem.rows(), cols);
        if inliers.len() < MIN_INLIERS {
            return TurnedRivals {
                poses: Vec::new(),
                own,
            };
        }
        let half = half_turns_about_axes(&inliers)
            .into_iter()
            .map(|turn| (turn * transform, StartKind::HalfTurn));
        let quarter = match quarter {
            QuarterTurns::Skipped => Vec::new(),
            QuarterTurns::Tried => {
                let source_centroid = Vector3::from(centroid(problem.probe_points()));
                let target_centroid = Vector3::from(problem.target_centroid());
                quarter_turns(&inliers, transform, source_centroid, target_centroid)
            }
        }
        .into_iter()
        .map(|pose| (pose, StartKind::QuarterTurn));
        let poses = half
            .chain(quarter)
            .filter(|(rival, kind)| {
                *kind == StartKind::QuarterTurn
                    || evidence.screen(problem.evaluate_evidence(rival), cols) >= TURNED_SHARE * own
            })
            .collect();
        TurnedRivals { poses, own }
    }

    /// Whether the problem's rows (a refined half turn's final evaluation) explain the data
    /// nearly as well as the best result or better: as many rows within the best's inlier
    /// radius (its σ, `sigma`) as its `own` count, less at most [`FEWER_INLIERS_DEVIATIONS`]
    /// standard deviations (√own).
    pub(crate) fn nearly_as_good(&self, problem: &CloudProblem<'_>, sigma: f64, own: usize) -> bool {
        let cols = problem.cols();
        let rivals = inliers_within(problem.rows(), cols, inlier_radius_squared(sigma, cols)) as f64;
        let own = own as f64;
        rivals >= own - FEWER_INLIERS_DEVIATIONS * own.sqrt()
    }

    /// Whether a settled half turn scores at least half the result's significance on the
    /// evidence subset: a rival that could lower the result's margin below `MIN_MARGIN`, worth
    /// a full run. Leaves the problem's rows at the evidence subset's.
    pub(crate) fn rivals(
        &self,
        problem: &mut CloudProblem<'_>,
        evidence: &Evidence,
        settled: &Matrix4<f64>,
    ) -> bool {
        let cols = problem.cols();
        evidence.screen(problem.evaluate_evidence(settled), cols) * MIN_MARGIN >= self.own
    }
}

/// The rows within the inlier radius of σ = `sigma` among every row of the final evaluation at
/// `transform` (what [`TurnedRivals::nearly_as_good`] compares with). Leaves the problem's rows
/// there.
pub(crate) fn inliers_at(problem: &mut dyn Problem, transform: &Matrix4<f64>, sigma: f64) -> usize {
    let cols = problem.cols();
    inliers_within(
        problem.evaluate_all(transform),
        cols,
        inlier_radius_squared(sigma, cols),
    )
}

/// Rows whose normalised squared residual is at most `radius_squared`.
fn inliers_within(rows: &Rows, cols: usize, radius_squared: f64) -> usize {
    rows.residual
        .chunks_exact(cols)
        .enumerate()
        .filter(|(i, r)| {
            let f = rows.scale.get(*i);
            r.iter().map(|v| v * v).sum::<f64>() <= radius_squared * f * f
        })
        .count()
}

/// How a refined rival's final round gains on the result. That round, on every row, is most of
/// a rival's cost, and one far behind (less than [`FAR_BEHIND_SHARE`] of the result's inliers)
/// often only slides along the surfaces until the update cap. One far behind that stopped
/// gaining ([`PROGRESS_DEVIATIONS`]) is not worth going on; one that gains goes on, as a
/// point-to-point final round that slides from a third of the result's count to more than it
/// (docs/performance.md, "Rivals far behind that stop gaining").
pub(crate) struct RivalProgress {
    /// The result's count of inliers among every row.
    own: usize,
    /// The result's σ, whose inlier radius the counts use.
    sigma: f64,
    /// Final-round updates asked about so far.
    updates: u32,
    /// The count at the last check.
    last_count: Option<usize>,
}

impl RivalProgress {
    /// Before a rival's final round, against the result's `own` count at its `sigma`.
    pub(crate) fn new(own: usize, sigma: f64) -> Self {
        RivalProgress {
            own,
            sigma,
            updates: 0,
            last_count: None,
        }
    }

    /// The final-round gate of a rival (`irls::FinalRoundGate`), asked before each update at
    /// the pose reached: counts the inliers every [`PROGRESS_PERIOD`] updates (which leaves the
    /// problem's rows there) and stops a rival far behind that stopped gaining.
    pub(crate) fn worth_going_on(
        &mut self,
        problem: &mut dyn Problem,
        pose: &Matrix4<f64>,
    ) -> ControlFlow<()> {
        let due = self.updates % PROGRESS_PERIOD == 0;
        self.updates += 1;
        if !due || self.gaining_or_near(inliers_at(problem, pose, self.sigma)) {
            ControlFlow::Continue(())
        } else {
            ControlFlow::Break(())
        }
    }

    /// Whether a rival whose count is now `count` is near the result or still gaining on it
    /// since the last count.
    fn gaining_or_near(&mut self, count: usize) -> bool {
        let own = self.own as f64;
        let far_behind = (count as f64) < FAR_BEHIND_SHARE * own;
        let stalled = self
            .last_count
            .is_some_and(|last| count as f64 <= last as f64 + PROGRESS_DEVIATIONS * own.sqrt());
        self.last_count = Some(count);
        !(far_behind && stalled)
    }
}

/// The rigid motions turning `points` half a turn about each of their principal axes through
/// their centroid: x ↦ R·(x − c) + c with R = 2·e·eᵀ − I.
fn half_turns_about_axes(points: &[[f64; 3]]) -> Vec<Matrix4<f64>> {
    let (centroid, axes) = principal_axes(points);
    axes.column_iter()
        .map(|axis| {
            let rotation = 2.0 * axis * axis.transpose() - Matrix3::identity();
            let mut turn = Matrix4::identity();
            turn.fixed_view_mut::<3, 3>(0, 0).copy_from(&rotation);
            turn.fixed_view_mut::<3, 1>(0, 3)
                .copy_from(&(centroid - rotation * centroid));
            turn
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform_point;

    /// Counts measured on rivals' final rounds (of the result's 28 370 and 38 115 inliers): a
    /// point-to-point rival sliding from a third of the result's count to more than it goes on
    /// from its first slow gain (+284, 1.7 √own); a quarter turn of a LiDAR pair stuck at 0.44
    /// of it (+38, 0.2 √own) stops at its second count; a rival near the result never stops.
    #[test]
    fn far_behind_rivals_go_on_only_while_they_gain() {
        let mut sliding = RivalProgress::new(28_370, 0.01);
        assert!(
            sliding.gaining_or_near(9_205),
            "the first count has nothing to gain on"
        );
        assert!(sliding.gaining_or_near(9_489));
        assert!(sliding.gaining_or_near(9_886));
        let mut stuck = RivalProgress::new(38_115, 0.01);
        assert!(stuck.gaining_or_near(16_596));
        assert!(!stuck.gaining_or_near(16_634));
        let mut near = RivalProgress::new(38_115, 0.01);
        assert!(near.gaining_or_near(20_000));
        assert!(
            near.gaining_or_near(20_000),
            "half the result's count is not far behind"
        );
    }

    /// Points of a 4 × 2 × 1 box's corners off the origin: the half turns are about x, y and z
    /// through the centre, each maps the corners onto themselves, and each is a rotation.
    #[test]
    fn half_turns_of_a_box_map_its_corners_onto_themselves() {
        let centre = [1.0, -2.0, 0.5];
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|i| {
                let s = |bit: usize, half: f64| if i >> bit & 1 == 1 { half } else { -half };
                [
                    centre[0] + s(0, 2.0),
                    centre[1] + s(1, 1.0),
                    centre[2] + s(2, 0.5),
                ]
            })
            .collect();
        let turns = half_turns_about_axes(&corners);
        assert_eq!(turns.len(), 3);
        for turn in &turns {
            let rotation = turn.fixed_view::<3, 3>(0, 0).into_owned();
            assert!((rotation.determinant() - 1.0).abs() < 1e-12);
            assert!((rotation.trace() + 1.0).abs() < 1e-12, "a half turn has trace −1");
            for corner in &corners {
                let moved = transform_point(turn, corner);
                let nearest = corners
                    .iter()
                    .map(|c| (0..3).map(|k| (c[k] - moved[k]).powi(2)).sum::<f64>())
                    .fold(f64::INFINITY, f64::min);
                assert!(nearest < 1e-20, "{corner:?} turned to {moved:?}");
            }
        }
    }
}
