//! What a registration reports: the transform, why it stopped, the fitted noise model, the
//! per-point results, the trace, the stage times, the search and the verdict.

use nalgebra::Matrix4;

use super::covariance::PoseUncertainty;
use crate::error::Error;
use crate::geometry::LooseDirection;

use crate::sie::HistogramModel;

/// Why the iteration stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// The last update was below both tolerances in the final round (for SIE: after β ≪ σ).
    Converged,
    /// `max_iterations` updates were made without converging.
    IterationLimit,
    /// The problem has no unique solution: no correspondence with weight > 0, or the weighted
    /// system is rank deficient (e.g. collinear points, one plane for point-to-plane). The
    /// transform is the best constrained estimate reached.
    Degenerate,
    /// The observer asked to stop; the transform is the one reached so far.
    Cancelled,
}

/// Which start the returned transform came from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StartKind {
    /// The caller's initial guess (the identity when none was given) with the paper's β₀.
    #[default]
    InitialGuess,
    /// The initial guess with β₀ far below the RMS of the initial residuals (ICP).
    NarrowBeta,
    /// A scale-free (L1) IRLS run from the initial guess, then SIE (ICP).
    ScaleFreeLead,
    /// A pose found by the hypothesis search (correspondences).
    Hypothesis,
    /// The initial guess with the caller's warm start (`RegistrationConfig::warm_start`): the
    /// previous fit's noise model, β₀ = 2σ.
    WarmStart,
    /// The result of another start turned half a turn about one of its inliers' principal axes
    /// (a near-symmetric scene's rival pose, `search::half_turns`), then SIE (ICP).
    HalfTurn,
    /// The result of another start shifted by one period of structure its inliers repeat
    /// (a row of pillars, `search::period_shifts`), then SIE (ICP).
    PeriodShift,
    /// A pose proposed by matching FPFH descriptors of the two clouds (`Starts::Global`), then
    /// SIE (ICP).
    FeatureMatch,
    /// The result of another start turned a quarter turn about one of its inliers' principal
    /// axes, re-centred on the target (a room's rival pose, `search::quarter_turns`), then SIE
    /// (ICP).
    QuarterTurn,
}

impl StartKind {
    /// Whether the start is a rival built from another start's result (a half or quarter turn,
    /// a period shift) rather than a start of the search.
    pub(crate) fn is_rival(self) -> bool {
        matches!(
            self,
            StartKind::HalfTurn | StartKind::QuarterTurn | StartKind::PeriodShift
        )
    }
}

/// One IRLS iteration, for plotting convergence.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceEntry {
    /// 1-based update count.
    pub iteration: u32,
    /// True while β is being annealed; false in the final round (and for baselines).
    pub annealing: bool,
    /// σ of the first histogram (normalised units); the baseline's scale for other costs.
    pub sigma: f64,
    /// β of the first histogram at this iteration (normalised units; 0 for baselines).
    pub beta: f64,
    /// Penalty k of the first histogram at this iteration (0 for baselines).
    pub penalty: f64,
    /// Σ P(I|r) / source points, as `RegistrationResult::inlier_fraction` (unmatched points
    /// count 0), over the source points this iteration matched (all, or the sample), with the
    /// weights of this update.
    pub inlier_fraction: f64,
    /// Weighted RMS residual of this iteration (input units).
    pub rmse: f64,
    /// Size of this update: how far it moved the source centroid, and its rotation angle.
    pub translation_change: f64,
    /// Rotation angle of this update (radians).
    pub rotation_change: f64,
    /// Correspondences (matched rows) this iteration used.
    pub correspondences: usize,
    /// T_target_source after this update (p_target = T · p_source): what a viewer animates.
    pub transform: Matrix4<f64>,
}

/// Wall time of one registration's stages, in seconds (what a profile of the call would show,
/// without a profiler). `total` also covers validation and noise scales.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Building the target's kd-tree, including sorting the target along a space-filling
    /// curve (ICP only).
    pub index: f64,
    /// Estimating target normals: choosing their scale up front; point-to-plane without given
    /// normals, each normal when matching first reaches its point (not counted in `matching`
    /// or `evaluation`); in either metric, the surface normals of a few thousand inliers'
    /// targets at each run's result, for its conditioning.
    pub normals: f64,
    /// Nearest-neighbour matching and residual rows, every iteration.
    pub matching: f64,
    /// Fitting the cost (SIE: histogram, σ, k, P(I|r)) and computing the IRLS weights.
    pub weighting: f64,
    /// The weighted least-squares step.
    pub solve: f64,
    /// Matching every source point at the returned transform for the reported results.
    pub evaluation: f64,
    /// The whole call, from validation to the returned result.
    pub total: f64,
}

/// Everything a registration reports.
#[derive(Clone, Debug, PartialEq)]
pub struct RegistrationResult {
    /// T_target_source: p_target = T · p_source.
    pub transform: Matrix4<f64>,
    /// Why the iteration stopped.
    pub stop_reason: StopReason,
    /// Whether it stopped because it converged (`stop_reason == StopReason::Converged`);
    /// whether the pose is supported is `quality.verdict`.
    pub converged: bool,
    /// Number of updates made.
    pub iterations: u32,
    /// Fitted σ_j per histogram (normalised units; input units with the constant noise model).
    pub sigma: Vec<f64>,
    /// Final β_j per histogram (empty for baselines).
    pub beta: Vec<f64>,
    /// Final k (the first histogram's).
    pub penalty: f64,
    /// Final noise shape p (2 unless estimated).
    pub noise_shape: f64,
    /// Σ_i P(I|r_i) / n_source at the returned transform (unmatched and dropped points count
    /// 0). ICP counts each distinct source location once (copies of a point are one point).
    pub inlier_fraction: f64,
    /// sqrt(Σ P_i‖r_i‖² / Σ P_i) at the returned transform, input units (‖r‖ is the plane
    /// distance for point-to-plane).
    pub rmse: f64,
    /// Per source point, P(I|r) at the returned transform (0 if unmatched). For baseline costs:
    /// the IRLS weight divided by the largest weight. Copies of a point share its value.
    pub probabilities: Vec<f64>,
    /// Per source point, the matched target index (-1 if unmatched); a target location the
    /// caller gave several times is named by its first index.
    pub correspondences: Vec<i64>,
    /// Last fitted histograms (SIE only), for the paper's Fig. 1.
    pub histograms: Vec<HistogramModel>,
    /// Per-iteration trace when `record_trace` is set.
    pub trace: Vec<TraceEntry>,
    /// Wall time of the registration's stages (seconds).
    pub times: StageTimes,
    /// Which start decided the result, and what the search found.
    pub search: SearchReport,
    /// How far to trust the result.
    pub quality: Quality,
    /// The pose's covariance and information from the final inliers (rotation first, the
    /// target frame; see [`PoseUncertainty`]).
    pub uncertainty: PoseUncertainty,
}

/// A verdict on a registration from the evidence SIE has. `converged` only says the iteration
/// settled; this says whether the pose it settled at is supported by the data.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Verdict {
    /// Every test passed: a significant inlier cluster, a pose the inliers constrain in every
    /// direction, no other start ending elsewhere nearly as significant, (ICP) inlier
    /// residuals no wider than the points' spacing, and a run that stopped by itself (never
    /// at the iteration cap).
    Good,
    /// The pose is supported but some evidence speaks against it (see `Quality`): check it.
    #[default]
    Doubtful,
    /// No inlier cluster stands out from chance at the fitted scale: the data do not support
    /// this pose.
    Unsupported,
}

/// The evidence behind the verdict.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Quality {
    /// Good, doubtful or unsupported, from the evidence below.
    pub verdict: Verdict,
    /// Significance of the inlier cluster at the fitted scale (nats; the scale-free score of `registration::significance`).
    pub significance: f64,
    /// How well the weighted inliers constrain the pose, 0–1: at the last update
    /// (`geometry::Solve::conditioning`); ICP, the smaller of that and point-to-plane's measure
    /// taken at the result from the inliers' surface normals (wide neighbourhoods, edges left
    /// out), which sees sliding along a plane or a corridor where the solves do not.
    pub conditioning: f64,
    /// Fitted σ over the typical distance between neighbouring target points (ICP; 0 for
    /// correspondences, which have no spacing).
    pub sigma_to_spacing: f64,
    /// Significance of the result over that of the best start that ended elsewhere (∞ when
    /// none did).
    pub margin: f64,
    /// ICP: the direction the inliers' surfaces constrain least, when their measure set
    /// `conditioning` (it names what a low conditioning leaves free: "translation along x");
    /// `None` when the solve's own conditioning was the smaller, or for correspondences.
    pub loose_direction: Option<LooseDirection>,
    /// ICP: a fit that also scales the source, started from the result, whose inliers stand out
    /// [`MIN_SCALED_RATIO`](crate::MIN_SCALED_RATIO) times as much as the result's: no rigid
    /// pose explains the data as well (the clouds differ in scale, or the pose is wrong), and the
    /// verdict is DOUBTFUL. `None` when no such fit was found (or none was tried: the result was
    /// not GOOD otherwise, or correspondences).
    pub scaled_source: Option<ScaledSource>,
}

/// See [`Quality::scaled_source`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaledSource {
    /// The scale of the source against the target that the fit found.
    pub scale: f64,
    /// The significance of that fit's inliers over the result's (both scale-free, on the same
    /// subset of the source).
    pub significance_ratio: f64,
}

/// Where the returned transform came from.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SearchReport {
    /// Which start the transform came from.
    pub start: StartKind,
    /// Minimal samples drawn by the hypothesis search (0 when none ran): on the given pairs, or
    /// on the descriptor matches of `Starts::Global`.
    pub hypotheses: u32,
    /// Starts SIE was run from (1 without a search).
    pub starts_run: u32,
    /// Significance of the inlier cluster at the returned transform, at the scale of its
    /// fitted σ (`registration::significance::at_scale`; nats, 0 when nothing stands out from chance).
    /// 0 when only one start ran.
    pub significance: f64,
    /// Starts whose result is the returned pose (within 3 standard errors), itself included.
    pub agreeing_starts: u32,
    /// The largest significance among starts that ended elsewhere (0: none did).
    pub runner_up_significance: f64,
}

impl RegistrationResult {
    /// The last guard of "no NaN success": a result whose transform or noise model left
    /// f64's range (coordinates spanning more orders of magnitude than the arithmetic holds)
    /// is an error, not an OK with NaN.
    pub(crate) fn ensure_finite(self) -> Result<RegistrationResult, Error> {
        let finite = self.transform.iter().all(|v| v.is_finite())
            && self.sigma.iter().chain(&self.beta).all(|v| v.is_finite())
            && self.rmse.is_finite();
        if finite {
            Ok(self)
        } else {
            Err(Error::InvalidArgument(
                "the registration left double precision's range: the coordinates (or the initial \
                 guess's translation) span more orders of magnitude than its arithmetic holds; \
                 rescale the clouds or drop the points far from the rest"
                    .to_string(),
            ))
        }
    }

    /// σ of the result: the RMS over its histograms.
    pub(crate) fn sigma_rms(&self) -> f64 {
        (self.sigma.iter().map(|s| s * s).sum::<f64>() / self.sigma.len().max(1) as f64).sqrt()
    }
}

#[cfg(test)]
impl RegistrationResult {
    /// A converged result of one update with these per-point values (the rest plain), for
    /// tests of what is done to a result's per-point arrays.
    pub(crate) fn with_points(
        probabilities: Vec<f64>,
        correspondences: Vec<i64>,
        inlier_fraction: f64,
    ) -> Self {
        RegistrationResult {
            transform: Matrix4::identity(),
            stop_reason: StopReason::Converged,
            converged: true,
            iterations: 1,
            sigma: vec![0.01],
            beta: vec![0.0001],
            penalty: 1.0,
            noise_shape: 2.0,
            inlier_fraction,
            rmse: 0.01,
            probabilities,
            correspondences,
            histograms: Vec::new(),
            trace: Vec::new(),
            times: StageTimes::default(),
            search: SearchReport::default(),
            quality: Quality::default(),
            uncertainty: PoseUncertainty::UNKNOWN,
        }
    }
}
