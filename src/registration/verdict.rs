//! How far to trust a registration: the evidence at its result (the significance of its inlier
//! cluster against a background of wrong poses, how well the inliers constrain the pose, σ
//! against the target's spacing) and the verdict drawn from it.

use nalgebra::Matrix4;

use super::irls::resolution;
use super::problem::{CloudProblem, Problem, Rows};
use super::result::{Quality, RegistrationResult, StopReason, Verdict};
use super::significance::{self, Background, BinnedSignificance};

/// What a result is judged by: the background of its significance, and (ICP) the typical
/// spacing of the target points as a normalised residual.
pub(crate) struct Evidence {
    background: Background,
    spacing: Option<f64>,
    /// The initial guess already fits every row to rounding: no other start is needed.
    pub(crate) exact_start: bool,
}

impl Evidence {
    /// Fixed correspondences: this background, no spacing (pairs have none).
    pub(crate) fn of_pairs(background: Background) -> Self {
        Evidence {
            background,
            spacing: None,
            exact_start: false,
        }
    }

    /// ICP: the background is the spread of the residuals at the initial guess (over the
    /// evidence subset, see [`CloudProblem::evaluate_evidence`]), the spacing the median
    /// distance between neighbouring target points.
    pub(crate) fn of_clouds(problem: &mut CloudProblem<'_>, init: &Matrix4<f64>) -> Self {
        let cols = problem.cols();
        let magnitude = problem.coordinate_magnitude();
        // Residuals at the rounding level already: the guess is exact, and the spread of the
        // target itself is the background a wrong pose would show.
        let exact = |rows: &Rows, spread: f64| spread <= resolution(magnitude, &rows.scale).powi(2);
        let spread = mean_squared_norm(problem.evaluate_evidence(init), cols);
        let typical_scale = problem.rows().scale.median();
        // The subset says so only when every point does.
        let exact_start = exact(problem.rows(), spread) && {
            let rows = problem.evaluate_all(init);
            exact(rows, mean_squared_norm(rows, cols))
        };
        let spread = if exact_start {
            (problem.target_spread() / typical_scale).powi(2)
        } else {
            spread
        };
        Evidence {
            background: Background {
                spread_squared: spread.max(f64::MIN_POSITIVE),
                dims: cols,
            },
            spacing: Some(problem.target_spacing() / typical_scale),
            exact_start,
        }
    }

    /// ICP near a right pose (a warm start's kept run, or the first start's result when the
    /// guess was close): the residuals at the initial guess are mostly inliers there, not the
    /// background a wrong pose would show. This background is the spread of the residuals at
    /// the result displaced by `DISPLACED_WIDTHS` fitted σ along each axis in turn: what a pose
    /// that wrong shows. On unrelated clouds (noise onto noise) that spread is the result's own, and
    /// nothing stands out. Leaves the problem's rows at the result.
    pub(crate) fn around(problem: &mut CloudProblem<'_>, result: &RegistrationResult) -> Self {
        let cols = problem.cols();
        let typical_scale = problem.rows().scale.median();
        let step = (DISPLACED_WIDTHS * result.sigma_rms() * typical_scale)
            .min(DISPLACED_SCENE_FRACTION * problem.target_spread());
        let mut spread = 0.0;
        for axis in 0..3 {
            let mut displaced = result.transform;
            displaced[(axis, 3)] += step;
            spread += mean_squared_norm(problem.evaluate_evidence(&displaced), cols) / 3.0;
        }
        problem.evaluate_all(&result.transform);
        Evidence {
            background: Background {
                spread_squared: spread.max(f64::MIN_POSITIVE),
                dims: cols,
            },
            spacing: Some(problem.target_spacing() / typical_scale),
            exact_start: false,
        }
    }

    /// Takes the wider of this background and `around`'s at `result` (a guess near the right
    /// pose has mostly inliers at it). Leaves the problem's rows at the result.
    pub(crate) fn widen_around(&mut self, problem: &mut CloudProblem<'_>, result: &RegistrationResult) {
        let around = Evidence::around(problem, result).background.spread_squared;
        self.background.spread_squared = self.background.spread_squared.max(around);
    }

    /// The background a result is judged against.
    pub(crate) fn background(&self) -> Background {
        self.background
    }

    /// The scale-free significance of these rows (`BinnedSignificance`) against this
    /// background: how much a pose's residuals stand out, with no fitted scale to judge at
    /// (a pose no run has refined yet).
    pub(crate) fn screen(&self, rows: &Rows, cols: usize) -> f64 {
        BinnedSignificance::new(self.background)
            .evaluate(squared_norms(rows, cols))
            .significance
    }

    /// Fills `result.quality` but for the verdict and the margin (which need every start) and
    /// returns the cluster at the result's fitted scale. The problem's rows must be the result's.
    pub(crate) fn assess(
        &self,
        problem: &dyn Problem,
        result: &mut RegistrationResult,
    ) -> significance::Cluster {
        let sigma = result.sigma_rms();
        let cluster = significance::at_scale(
            squared_norms(problem.rows(), problem.cols()),
            &self.background,
            sigma,
        );
        result.quality.significance = cluster.significance;
        result.quality.sigma_to_spacing = self.spacing.map_or(0.0, |spacing| {
            if spacing > 0.0 {
                sigma / spacing
            } else {
                f64::INFINITY
            }
        });
        cluster
    }
}

/// Mean of the rows' squared residual norms (0 without rows). A row whose square leaves f64's
/// range (a garbage point far out) is left out: one of them made the mean infinite, and with
/// it every pose significant.
pub(crate) fn mean_squared_norm(rows: &Rows, cols: usize) -> f64 {
    let (sum, count) = squared_norms(rows, cols)
        .filter(|v| v.is_finite())
        .fold((0.0, 0usize), |(sum, count), v| (sum + v, count + 1));
    sum / count.max(1) as f64
}

/// ‖r_i‖² / F_i² of every row.
fn squared_norms(rows: &Rows, cols: usize) -> impl Iterator<Item = f64> + '_ {
    rows.residual.chunks_exact(cols).enumerate().map(|(i, r)| {
        let f = rows.scale.get(i);
        r.iter().map(|v| v * v).sum::<f64>() / (f * f)
    })
}

/// [`Quality::conditioning`](crate::Quality::conditioning) below this makes the verdict
/// DOUBTFUL: some direction of the pose rests on under a fiftieth of the constraint of the
/// best-constrained one (inliers on one plane or one line, or only the ground and the fronts of
/// a street, which run along the motion: a LiDAR pair held at zero motion 0.4 m off keeps 0.002,
/// Kinect frames 0.64 m off from one start 0.015; right runs on the real-scan
/// table keep 0.036 or more, from one start or several).
pub const MIN_CONDITIONING: f64 = 0.02;
/// [`Quality::margin`](crate::Quality::margin) below this makes the verdict DOUBTFUL: a start
/// that ended elsewhere with more than half the significance makes the result a close call.
pub const MIN_MARGIN: f64 = 2.0;

/// [`Quality::scaled_source`](crate::Quality::scaled_source): a fit that scales the source makes
/// the verdict DOUBTFUL when its inliers stand out this many times as much as the rigid
/// result's refitted alike. Right runs on the real-scan table reach 1.04 (1.12 point-to-point: a
/// scaled fit absorbs some noise and the scanners' own scale differences of 0.1–1 %); the
/// synthetic room scaled by 0.95–1.1 gives 1.8–14 (docs/results.md, "A scaled source").
pub const MIN_SCALED_RATIO: f64 = 1.2;

/// The verdict from the evidence in `result.quality` and the fitted histograms.
pub(crate) fn verdict(result: &RegistrationResult) -> Verdict {
    verdict_with(result, &result.quality)
}

/// The verdict `result` would get with this quality evidence.
pub(crate) fn verdict_with(result: &RegistrationResult, quality: &Quality) -> Verdict {
    // A run stopped by its cap has not shown that it reached the pose the data hold.
    match verdict_if_settled(result, quality) {
        Verdict::Good if result.stop_reason == StopReason::IterationLimit => Verdict::Doubtful,
        verdict => verdict,
    }
}

/// The verdict `result` would get with this quality evidence had its run settled.
pub(crate) fn verdict_if_settled(result: &RegistrationResult, quality: &Quality) -> Verdict {
    // NaN counts as no support.
    if quality.significance.is_nan() || quality.significance <= 0.0 {
        return Verdict::Unsupported;
    }
    // A histogram without spread (exact data) has every sample at its peak.
    let peak = result
        .histograms
        .iter()
        .all(|h| h.peak_found || h.inlier.sigma == 0.0);
    let good = peak
        && quality.conditioning >= MIN_CONDITIONING
        && quality.margin >= MIN_MARGIN
        && quality.sigma_to_spacing <= 1.0
        && quality.scaled_source.is_none();
    if good { Verdict::Good } else { Verdict::Doubtful }
}

/// The quality of a result that had no other start to compare with.
pub(crate) fn judged_alone(evidence: &Evidence, problem: &dyn Problem, result: &mut RegistrationResult) {
    evidence.assess(problem, result);
    result.search.significance = result.quality.significance;
    result.quality.margin = f64::INFINITY;
    result.quality.verdict = verdict(result);
}

/// See [`Evidence::around`]: ten σ is far outside the inlier peak (99 % of Gaussian inliers lie
/// within 2.6σ per component) and still a near miss next to a poor initial guess.
const DISPLACED_WIDTHS: f64 = 10.0;
/// … and at most this fraction of the target's spread: a shift that moves a good part of the
/// source off the target would widen any residuals, a fitted σ that large (noise onto noise)
/// has no room to be told from chance.
const DISPLACED_SCENE_FRACTION: f64 = 0.05;
