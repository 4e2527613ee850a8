//! The choice between the results of several starts on one problem: each is judged on every
//! row at the scale its own fit claims (`significance::at_scale`), the most significant one is
//! kept, and how the others relate to it (the same pose or another) goes into its report.
//!
//! A result whose inliers leave some direction of the pose loose (conditioning below
//! `MIN_CONDITIONING`) is no pose but a family of them: two LiDAR sweeps of a street 10 cm
//! apart fit at zero motion on the ground and the fronts alone, and tighter there than at the
//! right pose, since each beam meets its own ray's return; only the cars and poles, outliers
//! there, fix the motion along the street. When two results differ by a move along the loose
//! direction of one of them, that one must be clearly more significant (`MIN_MARGIN` times) to
//! replace the other, is replaced by it when it is nearly as significant, and is no rival to
//! it. Results apart in any other way (a half turn, another place) compete as before.

use nalgebra::{Matrix4, Rotation3, Vector3};

use crate::geometry::{LooseDirection, rotation_part, translation_part};

use crate::registration::degeneracy::SurfaceRow;
use crate::registration::irls::{FinalModel, PendingPerPoint};
use crate::registration::problem::{Problem, moved_apart};
use crate::registration::result::{
    Quality, RegistrationResult, ScaledSource, StartKind, StopReason, TraceEntry, Verdict,
};
use crate::registration::verdict::{Evidence, MIN_CONDITIONING, MIN_MARGIN, verdict, verdict_with};

/// The most significant result of SIE from several starts on one problem, each judged on
/// every row at the scale its own fit claims (`significance::at_scale`).
pub(crate) struct BestOfStarts {
    pub(crate) evidence: Evidence,
    best: Option<Best>,
    /// Where every start ended.
    ends: Vec<End>,
    /// Number of the next update (the runs are numbered on).
    pub(crate) next_iteration: u32,
    /// The median row scale at the last offer (the units `moved_apart` compares poses in).
    typical_scale: f64,
    pub(crate) starts_run: u32,
    /// Every start's trace entries, in the order they ran (the result reports all updates).
    pub(crate) trace: Vec<TraceEntry>,
    /// A scaled source that explains the data better than the best (`scaled_source`).
    pub(crate) scaled_source: Option<ScaledSource>,
    /// The highest significance among the starts that are not rivals built from a result:
    /// what a rival must beat by [`RIVAL_TIE`].
    unrivalled_significance: f64,
}

/// Where a start ended, and how precisely its data place it there (both as row
/// displacements, the units `moved_apart` compares poses in).
struct End {
    transform: Matrix4<f64>,
    significance: f64,
    /// The pose's standard error: σ·√(6 / inliers).
    precision: f64,
    /// The fitted inlier σ (RMS over the histograms).
    sigma: f64,
    /// The direction its inliers leave loose, if any (see the module's description).
    loose: Looseness,
}

impl End {
    /// How far from `best` a start may end and still be at the same pose: a few standard
    /// errors, and never less than the best's noise width. ICP's discrete matching stops
    /// starts within the noise of each other (0.1° and 1.4 cm apart at σ 3.9 cm on real scans)
    /// where √N makes the standard error tiny; the best's inlier model cannot tell such poses
    /// apart. (Not the other's σ: a start that fitted wide noise elsewhere is a rival.)
    fn same_pose_within(&self, best: &End) -> f64 {
        (SAME_POSE_ERRORS * self.precision.max(best.precision)).max(SAME_POSE_WIDTHS * best.sigma)
    }
}

/// Which of two starts that end at the same pose is kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SamePose {
    /// The earlier (unless the later is clearly more significant): near-ties are rounding.
    KeepEarlier,
    /// The later: a run from the earlier one's pose that stayed.
    TakeLater,
}

/// The best start so far.
struct Best {
    significance: f64,
    result: RegistrationResult,
    /// What its per-point results are rebuilt from (ICP starts).
    model: Option<FinalModel>,
    /// Its per-point results were dropped while later starts ran (see `BestOfStarts::park`).
    parked: bool,
    /// The surface sample at its pose (`Problem::surface_rows`), where its repeats are sought.
    surfaces: Vec<SurfaceRow>,
}

impl BestOfStarts {
    pub(crate) fn new(evidence: Evidence) -> Self {
        BestOfStarts {
            evidence,
            best: None,
            ends: Vec::new(),
            next_iteration: 1,
            typical_scale: 1.0,
            starts_run: 0,
            trace: Vec::new(),
            scaled_source: None,
            unrivalled_significance: 0.0,
        }
    }

    /// Scores a run's result (its rows, at its transform, are the problem's last rows) and
    /// keeps it if it is the best so far; pending per-point results are spread only when it
    /// is kept (after the result it replaces is freed). False when the run was cancelled: no
    /// more starts.
    pub(crate) fn offer(
        &mut self,
        problem: &mut dyn Problem,
        result: RegistrationResult,
        pending: Option<PendingPerPoint>,
        start: StartKind,
    ) -> bool {
        self.offer_with(problem, result, pending, start, SamePose::KeepEarlier)
    }

    /// As `offer`, for a run of the paper's method from the best result's own pose: it
    /// replaces the best when it ends at the same pose (the later run is the one that stayed).
    /// Whether it ended at that pose; `None` when it was cancelled (or no start ran before).
    pub(crate) fn offer_rerun(
        &mut self,
        problem: &mut dyn Problem,
        result: RegistrationResult,
        pending: PendingPerPoint,
    ) -> Option<bool> {
        let from = self.best.as_ref().map(|best| best.result.transform)?;
        let offered = self.offer_with(
            problem,
            result,
            Some(pending),
            StartKind::InitialGuess,
            SamePose::TakeLater,
        );
        offered.then(|| self.last_end_at(&*problem, &from))
    }

    fn offer_with(
        &mut self,
        problem: &mut dyn Problem,
        mut result: RegistrationResult,
        pending: Option<PendingPerPoint>,
        start: StartKind,
        same_pose: SamePose,
    ) -> bool {
        self.starts_run += 1;
        self.next_iteration = result.iterations + 1;
        self.trace.append(&mut result.trace);
        let cluster = self.evidence.assess(problem, &mut result);
        // Before the rows may be taken below; `finish` compares poses in these units.
        self.typical_scale = problem.rows().scale.median();
        let significance = cluster.significance;
        let precision = result.sigma_rms() * (6.0 / (cluster.count.max(1) as f64)).sqrt();
        let loose = Looseness::of(&result);
        self.ends.push(End {
            transform: result.transform,
            significance,
            precision,
            sigma: result.sigma_rms(),
            loose,
        });
        result.search.start = start;
        result.search.significance = significance;
        let cancelled = result.stop_reason == StopReason::Cancelled;
        // A cancelled run's transform is the one the caller stopped at: report it. A start that
        // ends at the best pose so far (within its precision) replaces it only when clearly more
        // significant (a better noise model there): near-ties between equal poses are rounding,
        // and the earlier start (the paper's) is kept.
        let replaces = match &self.best {
            None => true,
            Some(Best { result: best, .. })
                if same_pose == SamePose::TakeLater && self.last_end_at(&*problem, &best.transform) =>
            {
                true
            }
            Some(Best {
                significance: best_significance,
                result: best,
                ..
            }) if loose.slides_between(&result.transform, &best.transform) => {
                significance > MIN_MARGIN * *best_significance
            }
            Some(Best {
                significance: best_significance,
                result: best,
                ..
            }) if Looseness::of(best).slides_between(&best.transform, &result.transform) => {
                significance * MIN_MARGIN >= *best_significance
            }
            Some(Best {
                significance: best_significance,
                result: best,
                ..
            }) => {
                let to_beat = if start.is_rival() {
                    best_significance.max(RIVAL_TIE * self.unrivalled_significance)
                } else {
                    *best_significance
                };
                significance > to_beat
                    && (significance > SAME_POSE_TIE * *best_significance || {
                        let best_precision = self
                            .ends
                            .iter()
                            .find(|end| end.transform == best.transform)
                            .map_or(precision, |end| end.precision);
                        let apart = moved_apart(problem.probe_points(), &best.transform, &result.transform)
                            / self.typical_scale;
                        apart > SAME_POSE_ERRORS * precision.max(best_precision)
                    })
            }
        };
        if !start.is_rival() {
            self.unrivalled_significance = self.unrivalled_significance.max(significance);
        }
        if cancelled || replaces {
            self.best = None;
            let surfaces = problem.surface_rows().to_vec();
            let model = pending.map(|pending| pending.spread_last(problem, &mut result));
            self.best = Some(Best {
                significance,
                result,
                model,
                parked: false,
                surfaces,
            });
        }
        !cancelled
    }

    /// Whether the last start ended at `pose` (an earlier start's end), as `finish` counts
    /// agreeing starts.
    fn last_end_at(&self, problem: &dyn Problem, pose: &Matrix4<f64>) -> bool {
        let Some(last) = self.ends.last() else {
            return false;
        };
        let earlier = self
            .ends
            .iter()
            .find(|end| end.transform == *pose)
            .unwrap_or(last);
        moved_apart(problem.probe_points(), pose, &last.transform) / self.typical_scale
            <= last.same_pose_within(earlier)
    }

    /// The surface sample at the best result's pose (empty if no start ran).
    pub(crate) fn best_surfaces(&self) -> &[SurfaceRow] {
        self.best.as_ref().map_or(&[], |best| &best.surfaces)
    }

    /// The best result's transform and fitted σ (RMS over the histograms), if a start ran.
    pub(crate) fn best_pose(&self) -> Option<(Matrix4<f64>, f64)> {
        self.best
            .as_ref()
            .map(|best| (best.result.transform, best.result.sigma_rms()))
    }

    /// How far the best result lies from `pose`, in its fitted σ (the RMS over the probe
    /// points, as `cloud_starts::moved_in_widths`); 0 if no start ran.
    pub(crate) fn best_apart_in_sigmas(&self, problem: &dyn Problem, pose: &Matrix4<f64>) -> f64 {
        self.best.as_ref().map_or(0.0, |best| {
            moved_apart(problem.probe_points(), pose, &best.result.transform)
                / (self.typical_scale * best.result.sigma_rms())
        })
    }

    /// The best result's inlier fraction (0 if no start ran).
    pub(crate) fn best_inlier_fraction(&self) -> f64 {
        self.best.as_ref().map_or(0.0, |best| best.result.inlier_fraction)
    }

    /// Whether the best result's surfaces fix every direction of its pose (its conditioning
    /// reaches the verdict's minimum).
    pub(crate) fn best_is_constrained(&self) -> bool {
        self.best
            .as_ref()
            .is_some_and(|best| best.result.quality.conditioning >= MIN_CONDITIONING)
    }

    /// Whether the best result so far is GOOD on its own evidence, with no other start to
    /// compare it with.
    pub(crate) fn best_is_good_alone(&self) -> bool {
        self.best_is_good_alone_with(|_| {})
    }

    /// As [`BestOfStarts::best_is_good_alone`], or would be but for a direction its surfaces
    /// leave loose: right in every direction the data fix.
    pub(crate) fn best_is_good_alone_but_for_conditioning(&self) -> bool {
        self.best_is_good_alone_with(|quality| {
            quality.conditioning = quality.conditioning.max(MIN_CONDITIONING);
        })
    }

    fn best_is_good_alone_with(&self, overlook: impl Fn(&mut Quality)) -> bool {
        self.best.as_ref().is_some_and(|best| {
            let mut quality = best.result.quality;
            quality.margin = f64::INFINITY;
            overlook(&mut quality);
            verdict_with(&best.result, &quality) == Verdict::Good
        })
    }

    /// Counts a start that is no rival to the best (`half_turns`): its updates are numbered
    /// and traced, its pose is not compared.
    pub(crate) fn pass_over(&mut self, result: RegistrationResult) {
        self.pass_over_unfinished(result.iterations, result.trace);
    }

    /// As `pass_over`, for a run stopped before its report: its last update's number and its
    /// trace.
    pub(crate) fn pass_over_unfinished(&mut self, iterations: u32, mut trace: Vec<TraceEntry>) {
        self.starts_run += 1;
        self.next_iteration = iterations + 1;
        self.trace.append(&mut trace);
    }

    /// Drops the best result's per-point results before another start runs (`finish`
    /// rebuilds them): at 10 M points they are 153 MiB of the registration's peak, and
    /// rebuilding costs one pass over the source points.
    pub(crate) fn park(&mut self) {
        if let Some(best) = self.best.as_mut().filter(|best| best.model.is_some()) {
            best.result.probabilities = Vec::new();
            best.result.correspondences = Vec::new();
            best.parked = true;
        }
    }

    /// The best result, with how the other starts' results relate to it: how many ended at
    /// the same pose (within a few standard errors of either, or the noise width), and the significance of the best
    /// one that did not.
    pub(crate) fn finish(self, problem: &mut dyn Problem) -> RegistrationResult {
        let typical_scale = self.typical_scale;
        let Best {
            mut result,
            model,
            parked,
            ..
        } = self.best.expect("at least one start ran");
        result.iterations = self.next_iteration - 1;
        result.trace = self.trace;
        result.search.starts_run = self.starts_run;
        let (mut agreeing, mut runner_up) = (0, 0.0f64);
        let best_end = self.ends.iter().find(|end| end.transform == result.transform);
        for end in &self.ends {
            let apart =
                moved_apart(problem.probe_points(), &result.transform, &end.transform) / typical_scale;
            if apart <= end.same_pose_within(best_end.unwrap_or(end)) {
                agreeing += 1;
            } else if !end.loose.slides_between(&end.transform, &result.transform) {
                runner_up = runner_up.max(end.significance);
            }
        }
        result.search.agreeing_starts = agreeing;
        result.search.runner_up_significance = runner_up;
        result.quality.margin = if runner_up > 0.0 {
            result.quality.significance / runner_up
        } else {
            f64::INFINITY
        };
        result.quality.scaled_source = self.scaled_source;
        result.quality.verdict = verdict(&result);
        // Last: the rows the agreement above was measured with are the last start's.
        if let Some(model) = model.filter(|_| parked) {
            model.evaluate_again(problem).spread_last(problem, &mut result);
        }
        result
    }
}

/// Whether a result's inliers fix its pose, and if not, in which direction they leave it loose.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Looseness {
    Fixed,
    /// Conditioning below `MIN_CONDITIONING`; the direction when the surfaces named it.
    Loose(Option<LooseDirection>),
}

/// A move lies along a loose translation when its direction is within about 25° of it
/// (|cos| ≥ this) and it turns by less than [`SLIDE_ROTATION`]; about a loose rotation axis,
/// when its own rotation axis is that close to it.
const SLIDE_ALIGNMENT: f64 = 0.9;
/// See [`SLIDE_ALIGNMENT`] (radians, 1°).
const SLIDE_ROTATION: f64 = 0.0175;

impl Looseness {
    fn of(result: &RegistrationResult) -> Self {
        if result.quality.conditioning < MIN_CONDITIONING {
            Looseness::Loose(result.quality.loose_direction)
        } else {
            Looseness::Fixed
        }
    }

    /// Whether the move from the pose `from` (whose looseness this is) to `to` slides along the
    /// loose direction: the data of `from` cannot tell the two apart in that direction, so
    /// `to` is not another explanation but the same one, fixed further.
    fn slides_between(&self, from: &Matrix4<f64>, to: &Matrix4<f64>) -> bool {
        let Looseness::Loose(Some(direction)) = self else {
            return false;
        };
        // The move of the points already placed by `from`, in the target frame.
        let Some(inverse) = from.try_inverse() else {
            return false;
        };
        let step = to * inverse;
        // nalgebra's `from_matrix` iterates until it converges, which a non-finite matrix (a
        // start that left f64's range) never does: such a move slides nowhere.
        if !step.iter().all(|v| v.is_finite()) {
            return false;
        }
        let rotation = Rotation3::from_matrix_eps(&rotation_part(&step), 1e-12, 100, Rotation3::identity());
        let aligned = |a: &Vector3<f64>, axis: &[f64; 3]| {
            let norm = a.norm();
            norm > 0.0 && (a.dot(&Vector3::from(*axis)) / norm).abs() >= SLIDE_ALIGNMENT
        };
        match direction {
            LooseDirection::Translation(axis) => {
                rotation.angle() < SLIDE_ROTATION && aligned(&translation_part(&step), axis)
            }
            LooseDirection::Rotation(axis) => rotation.axis().is_some_and(|a| aligned(&a, axis)),
        }
    }
}

/// Between two results at the same pose, the later must be this many times as significant to
/// replace the earlier.
const SAME_POSE_TIE: f64 = 1.05;

/// A rival built from the best result (its half or quarter turn, its period shift) must be this
/// many times as significant as every start that is not such a rival to replace the best: a
/// near-tie is a symmetry the data cannot break (a bare corner of three equal planes turned
/// onto itself), and the pose the caller's guess led to is kept, its margin saying how close
/// the call was. (Against those starts, not the best so far: among many tied rivals, as a
/// plane has, the most significant still wins.)
const RIVAL_TIE: f64 = 1.05;

/// Two starts' results are the same pose when they are this many standard errors apart or
/// closer (as row displacements) …
const SAME_POSE_ERRORS: f64 = 3.0;
/// … or, when judging rivals, this many noise widths.
const SAME_POSE_WIDTHS: f64 = 1.0;

#[cfg(test)]
mod tests {
    use super::*;

    /// A move with a non-finite entry (a start whose transform left f64's range) slides along
    /// no direction, and deciding so ends: nalgebra's iteration to the nearest rotation never
    /// converged on it (an odometry fuzz input ran for more than 10 minutes).
    #[test]
    fn a_non_finite_move_slides_nowhere_and_returns() {
        let loose = Looseness::Loose(Some(LooseDirection::Translation([1.0, 0.0, 0.0])));
        let from = Matrix4::identity();
        let mut sliding = Matrix4::identity();
        sliding[(0, 3)] = 0.5;
        assert!(
            loose.slides_between(&from, &sliding),
            "a move along the loose axis slides"
        );
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut to = Matrix4::identity();
            to[(0, 0)] = bad;
            assert!(!loose.slides_between(&from, &to), "{bad}");
            let mut far = sliding;
            far[(1, 3)] = bad;
            assert!(!loose.slides_between(&from, &far), "{bad} in the translation");
        }
        let spin = Looseness::Loose(Some(LooseDirection::Rotation([0.0, 0.0, 1.0])));
        let mut to = Matrix4::identity();
        to[(1, 1)] = f64::NAN;
        assert!(!spin.slides_between(&from, &to));
    }
}
