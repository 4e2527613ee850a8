//! What `sie register` reports: the transform as text, the one-screen summary and the JSON
//! document for scripts.
use std::fmt::Write as _;

use nalgebra::{Matrix4, Matrix6};
use serde::Serialize;
use sie::geometry::{rotation_angle, rotation_part, translation_part};
use sie::{LooseDirection, RegistrationResult, StartKind, StopReason, TraceEntry, Verdict};

pub use super::numbers::significant;

/// Rotation (degrees) and translation distance between an estimate and the ground truth:
/// the size of truth⁻¹ · estimate.
pub fn pose_error(estimate: &Matrix4<f64>, truth: &Matrix4<f64>) -> (f64, f64) {
    let difference = truth.try_inverse().unwrap_or_else(Matrix4::identity) * estimate;
    (
        rotation_angle(&rotation_part(&difference)).to_degrees(),
        translation_part(&difference).norm(),
    )
}

/// Short name of a stop reason (the demo's table, the summary, the JSON report).
pub fn stop_label(reason: StopReason) -> &'static str {
    match reason {
        StopReason::Converged => "converged",
        StopReason::IterationLimit => "iter-limit",
        StopReason::Degenerate => "degenerate",
        StopReason::Cancelled => "cancelled",
    }
}

/// Four lines of four numbers, readable back by `--init` / `--ground-truth`. Nine decimals keep
/// rotation entries to 1e-9.
pub fn format_transform(t: &Matrix4<f64>, indent: &str) -> String {
    let mut text = String::new();
    for r in 0..4 {
        let row = t.row(r);
        let _ = writeln!(
            text,
            "{indent}{:>13.9} {:>13.9} {:>13.9} {:>13.9}",
            row[0], row[1], row[2], row[3]
        );
    }
    text
}

/// One cloud as read.
#[derive(Serialize)]
pub struct CloudReport {
    pub path: String,
    pub points: usize,
    /// Points dropped for a non-finite coordinate (`--skip-invalid`).
    pub skipped_non_finite: usize,
    /// Points at exactly 0 0 0 dropped by the registration (`--skip-origin`).
    pub skipped_origin: usize,
    /// Kept points that repeat another kept point exactly: the registration counts each
    /// location once (every copy gets its location's results).
    pub repeated: usize,
    /// What the reader noticed but read past (also printed on stderr, `-q` or not), e.g. a PCD
    /// file holding more points than its header declares.
    pub warnings: Vec<String>,
}

/// Error of the result against `--ground-truth`.
#[derive(Clone, Copy, Serialize)]
pub struct GroundTruthError {
    pub rotation_error_deg: f64,
    /// Input units.
    pub translation_error: f64,
}

#[derive(Serialize)]
pub struct TraceRow {
    pub iteration: u32,
    pub annealing: bool,
    pub sigma: f64,
    pub beta: f64,
    pub penalty: f64,
    pub inlier_fraction: f64,
    pub rmse: f64,
    pub translation_change: f64,
    pub rotation_change: f64,
    pub correspondences: usize,
    /// T_target_source reached by this update, row-major like `transform` of the report.
    pub transform: [[f64; 4]; 4],
}

impl From<&TraceEntry> for TraceRow {
    fn from(e: &TraceEntry) -> Self {
        TraceRow {
            iteration: e.iteration,
            annealing: e.annealing,
            sigma: e.sigma,
            beta: e.beta,
            penalty: e.penalty,
            inlier_fraction: e.inlier_fraction,
            rmse: e.rmse,
            translation_change: e.translation_change,
            rotation_change: e.rotation_change,
            correspondences: e.correspondences,
            transform: transform_rows(&e.transform),
        }
    }
}

/// The `--json` document. Field names are part of the tool's interface.
#[derive(Serialize)]
pub struct JsonReport<'a> {
    pub source: &'a CloudReport,
    pub target: &'a CloudReport,
    /// "sie", "cauchy", … as given to `--cost`, and its parameter (null for sie and l2).
    pub cost: String,
    pub cost_parameter: Option<f64>,
    pub metric: &'static str,
    /// T_target_source, row-major: `transform[row][col]`.
    pub transform: [[f64; 4]; 4],
    /// "converged", "iteration_limit", "degenerate" or "cancelled".
    pub stop_reason: &'static str,
    pub converged: bool,
    pub iterations: u32,
    /// Fitted σ per histogram (residual units: input units with the constant noise model).
    pub sigma: Vec<f64>,
    pub beta: Vec<f64>,
    /// Final k of the asymmetric penalty.
    pub penalty: f64,
    pub noise_shape: f64,
    pub inlier_fraction: f64,
    /// Inlier-weighted RMS residual, input units.
    pub rmse: f64,
    /// Registration time (reading the files excluded).
    pub seconds: f64,
    pub read_seconds: f64,
    pub ground_truth: Option<GroundTruthError>,
    /// Largest change made to a rotation entry of `--init` / `--ground-truth` to make it
    /// exactly rigid (null without the option; above 1e-6 the file was visibly rounded).
    pub init_correction: Option<f64>,
    pub ground_truth_correction: Option<f64>,
    /// How far to trust the pose, and the evidence.
    pub quality: QualityReport,
    /// Where the pose came from (`--starts automatic` runs several starts).
    pub search: SearchRow,
    /// The pose's 6 × 6 covariance (`covariance[row][col]`) in the order and frame that
    /// `pose_perturbation` states; all zeros when too few residuals were weighted.
    pub covariance: [[f64; 6]; 6],
    /// Its inverse where the data constrain the pose (near 0 in directions they leave free).
    pub information: [[f64; 6]; 6],
    /// [`POSE_PERTURBATION`].
    pub pose_perturbation: &'static str,
    /// One row per update of every start with `--trace`, else empty.
    pub trace: Vec<TraceRow>,
}

/// The verdict and its evidence (`RegistrationResult::quality`).
#[derive(Serialize)]
pub struct QualityReport {
    /// "good", "doubtful" or "unsupported".
    pub verdict: &'static str,
    /// Of the inlier cluster against chance, nats (0: nothing stands out).
    pub significance: f64,
    /// How well the inliers constrain the pose, 0–1.
    pub conditioning: f64,
    /// Fitted σ over the target points' typical spacing (null when that spacing is 0).
    pub sigma_to_spacing: Option<f64>,
    /// significance / search.runner_up_significance (null when no start ended elsewhere).
    pub margin: Option<f64>,
    /// The direction the inliers' surfaces constrain least, when their measure set
    /// `conditioning` (null otherwise).
    pub loose_direction: Option<LooseDirectionRow>,
    /// A fit that scales the source and explains the data better (null when none did).
    pub scaled_source: Option<ScaledSourceRow>,
}

/// `Quality::scaled_source`.
#[derive(Serialize)]
pub struct ScaledSourceRow {
    /// The source's scale against the target that the fit found.
    pub scale: f64,
    /// Its inliers' significance over the result's.
    pub significance_ratio: f64,
}

/// `Quality::loose_direction`: "translation" along `axis`, or "rotation" about `axis` through
/// the inliers' centroid (a unit vector in the target frame).
#[derive(Serialize)]
pub struct LooseDirectionRow {
    pub kind: &'static str,
    pub axis: [f64; 3],
}

impl LooseDirectionRow {
    fn of(direction: LooseDirection) -> Self {
        match direction {
            LooseDirection::Translation(axis) => LooseDirectionRow {
                kind: "translation",
                axis,
            },
            LooseDirection::Rotation(axis) => LooseDirectionRow {
                kind: "rotation",
                axis,
            },
        }
    }

    /// "translation along x", "rotation about (0.71, 0.71, 0.00)".
    fn describe(&self) -> String {
        let axis = match self.axis.iter().position(|c| c.abs() > AXIS_NAMED) {
            Some(k) => {
                let sign = if self.axis[k] < 0.0 { "-" } else { "" };
                format!("{sign}{}", ["x", "y", "z"][k])
            }
            None => format!("({:.2}, {:.2}, {:.2})", self.axis[0], self.axis[1], self.axis[2]),
        };
        match self.kind {
            "translation" => format!("translation along {axis}"),
            _ => format!("rotation about {axis}"),
        }
    }
}

/// A unit axis within about 2.6° of a coordinate axis is named by it.
const AXIS_NAMED: f64 = 0.999;

/// The search over starts (`RegistrationResult::search`).
#[derive(Serialize)]
pub struct SearchRow {
    /// "initial_guess", "narrow_beta", "scale_free_lead" or "hypothesis".
    pub start: &'static str,
    pub starts_run: u32,
    pub hypotheses: u32,
    pub agreeing_starts: u32,
    /// Largest significance of a start that ended at another pose (0: none did).
    pub runner_up_significance: f64,
}

pub fn quality_report(result: &RegistrationResult) -> QualityReport {
    let quality = &result.quality;
    QualityReport {
        verdict: verdict_label(quality.verdict),
        significance: quality.significance,
        conditioning: quality.conditioning,
        sigma_to_spacing: quality
            .sigma_to_spacing
            .is_finite()
            .then_some(quality.sigma_to_spacing),
        margin: quality.margin.is_finite().then_some(quality.margin),
        loose_direction: quality.loose_direction.map(LooseDirectionRow::of),
        scaled_source: quality.scaled_source.map(|scaled| ScaledSourceRow {
            scale: scaled.scale,
            significance_ratio: scaled.significance_ratio,
        }),
    }
}

pub fn search_row(result: &RegistrationResult) -> SearchRow {
    let search = &result.search;
    SearchRow {
        start: match search.start {
            StartKind::InitialGuess => "initial_guess",
            StartKind::NarrowBeta => "narrow_beta",
            StartKind::ScaleFreeLead => "scale_free_lead",
            StartKind::Hypothesis => "hypothesis",
            StartKind::WarmStart => "warm_start",
            StartKind::HalfTurn => "half_turn",
            StartKind::PeriodShift => "period_shift",
            StartKind::FeatureMatch => "feature_match",
            StartKind::QuarterTurn => "quarter_turn",
        },
        starts_run: search.starts_run,
        hypotheses: search.hypotheses,
        agreeing_starts: search.agreeing_starts,
        runner_up_significance: search.runner_up_significance,
    }
}

pub fn verdict_label(verdict: Verdict) -> &'static str {
    match verdict {
        Verdict::Good => "good",
        Verdict::Doubtful => "doubtful",
        Verdict::Unsupported => "unsupported",
    }
}

/// The summary's verdict line: the verdict, what to do, and for DOUBTFUL which evidence is
/// weak. The thresholds are the core's (`registration::pipeline::verdict`, documented in
/// include/sie.h's `sie_summary`).
pub fn verdict_line(result: &RegistrationResult) -> String {
    let q = &result.quality;
    match q.verdict {
        Verdict::Good => {
            let starts = &result.search;
            let agreement = if starts.starts_run > 1 {
                format!(
                    ", {} of {} starts agree",
                    starts.agreeing_starts, starts.starts_run
                )
            } else {
                String::new()
            };
            format!(
                "good (significance {:.0}, conditioning {}{agreement})",
                q.significance,
                significant(q.conditioning)
            )
        }
        Verdict::Unsupported => {
            "UNSUPPORTED: no inlier cluster stands out from chance; do not use this pose".to_string()
        }
        Verdict::Doubtful => {
            let mut weak = Vec::new();
            // A histogram without spread (exact data) has every sample at its peak.
            if result
                .histograms
                .iter()
                .any(|h| !h.peak_found && h.inlier.sigma != 0.0)
            {
                weak.push("no inlier peak in the residual histogram".to_string());
            }
            if result.stop_reason == StopReason::IterationLimit {
                weak.push("stopped at the iteration limit before converging".to_string());
            }
            if q.conditioning < sie::MIN_CONDITIONING {
                let loose = q
                    .loose_direction
                    .map_or("some direction of the pose".to_string(), |d| {
                        LooseDirectionRow::of(d).describe()
                    });
                weak.push(format!(
                    "conditioning {} (the inliers leave {loose} loose)",
                    significant(q.conditioning)
                ));
            }
            if q.margin < sie::MIN_MARGIN {
                weak.push(format!(
                    "another start ended elsewhere nearly as significant (margin {})",
                    significant(q.margin)
                ));
            }
            if let Some(scaled) = q.scaled_source {
                weak.push(format!(
                    "the source scaled by {} fits {} x as significantly (clouds of different \
                     scale, or a wrong pose)",
                    significant(scaled.scale),
                    significant(scaled.significance_ratio)
                ));
            }
            if q.sigma_to_spacing > 1.0 {
                weak.push(format!(
                    "inlier sigma {} x the point spacing",
                    significant(q.sigma_to_spacing)
                ));
            }
            if weak.is_empty() {
                weak.push("weak evidence".to_string());
            }
            format!(
                "DOUBTFUL: {}; check the pose or retry from another guess",
                weak.join(", ")
            )
        }
    }
}

pub fn json_stop_reason(reason: StopReason) -> &'static str {
    match reason {
        StopReason::Converged => "converged",
        StopReason::IterationLimit => "iteration_limit",
        StopReason::Degenerate => "degenerate",
        StopReason::Cancelled => "cancelled",
    }
}

/// What `covariance` and `information` of the JSON report describe.
pub const POSE_PERTURBATION: &str = "left: T = Exp(d) * transform with d = (rotation vector [rad], translation \
     [input units]), rotation first, both in the target frame";

/// A 6 × 6 matrix as rows.
pub fn matrix6_rows(m: &Matrix6<f64>) -> [[f64; 6]; 6] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

pub fn transform_rows(t: &Matrix4<f64>) -> [[f64; 4]; 4] {
    std::array::from_fn(|r| std::array::from_fn(|c| t[(r, c)]))
}

/// Everything the summary shows besides the result itself.
pub struct SummaryContext<'a> {
    pub source: &'a CloudReport,
    pub target: &'a CloudReport,
    /// e.g. "SIE, point-to-plane, constant noise".
    pub method: String,
    /// e.g. "normals estimated from 10 neighbours".
    pub target_note: String,
    pub units: &'a str,
    pub seconds: f64,
    pub read_seconds: f64,
    pub ground_truth: Option<GroundTruthError>,
    /// False for baseline costs: their verdict rests on no fitted noise model.
    pub judged: bool,
    pub written: Vec<String>,
}

/// The one-screen summary printed on stderr.
pub fn summary(result: &RegistrationResult, context: &SummaryContext) -> String {
    let mut text = String::new();
    let cloud = |c: &CloudReport| {
        let skipped = match (c.skipped_non_finite, c.skipped_origin) {
            (0, 0) => None,
            (n, 0) => Some(format!("{n} non-finite skipped")),
            (0, o) => Some(format!("{o} at 0 0 0 skipped")),
            (n, o) => Some(format!("{n} non-finite and {o} at 0 0 0 skipped")),
        };
        let repeated = (c.repeated > 0).then(|| {
            format!(
                "{} exact repeats of other points, each location counted once",
                c.repeated
            )
        });
        let notes: Vec<String> = skipped.into_iter().chain(repeated).collect();
        let notes = if notes.is_empty() {
            String::new()
        } else {
            format!(" ({})", notes.join("; "))
        };
        format!("{}: {} points{notes}", c.path, c.points)
    };
    let _ = writeln!(text, "source   {}", cloud(context.source));
    let _ = writeln!(
        text,
        "target   {}, {}",
        cloud(context.target),
        context.target_note
    );
    let _ = writeln!(text, "method   {}", context.method);
    let stop = match result.stop_reason {
        StopReason::Converged => "converged",
        StopReason::IterationLimit => "NOT converged: iteration limit reached",
        StopReason::Degenerate => "NOT converged: degenerate problem (too few or collinear/planar matches)",
        StopReason::Cancelled => "cancelled (Ctrl-C)",
    };
    let _ = writeln!(
        text,
        "result   {stop} after {} iterations in {:.3} s (reading {:.3} s)",
        result.iterations, context.seconds, context.read_seconds
    );
    if !result.sigma.is_empty() {
        let join = |values: &[f64]| {
            values
                .iter()
                .map(|&v| significant(v))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let beta = if result.beta.is_empty() {
            String::new()
        } else {
            format!(", beta {}", join(&result.beta))
        };
        let _ = writeln!(
            text,
            "         sigma {} ({}){beta}, k {:.2}, noise shape p {:.2}",
            join(&result.sigma),
            context.units,
            result.penalty,
            result.noise_shape
        );
    }
    let _ = writeln!(
        text,
        "         inlier fraction {:.3}, inlier-weighted RMSE {} (input units)",
        result.inlier_fraction,
        significant(result.rmse)
    );
    if context.judged {
        let _ = writeln!(text, "verdict  {}", verdict_line(result));
    } else {
        let _ = writeln!(
            text,
            "verdict  {} (a baseline cost fits no noise model to judge by; use --cost sie for a verdict)",
            verdict_label(result.quality.verdict)
        );
    }
    if let Some(error) = context.ground_truth {
        let _ = writeln!(
            text,
            "truth    rotation error {:.4} deg, translation error {} (input units)",
            error.rotation_error_deg,
            significant(error.translation_error)
        );
    }
    if !context.written.is_empty() {
        let _ = writeln!(text, "wrote    {}", context.written.join(", "));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transform_text_reads_back() {
        let t = Matrix4::new(
            0.5, -0.25, 0.0, 1.5, 0.25, 0.5, 0.0, -2.0, 0.0, 0.0, 1.0, 1e-9, 0.0, 0.0, 0.0, 1.0,
        );
        let text = format_transform(&t, "");
        let numbers: Vec<f64> = text.split_whitespace().map(|v| v.parse().unwrap()).collect();
        assert_eq!(numbers, t.transpose().as_slice());
        assert_eq!(transform_rows(&t)[1][3], -2.0);
    }
}
