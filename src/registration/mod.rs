//! Rigid registration with IRLS (§3) weighted by SIE (§4) or a baseline cost (§5):
//! from given correspondences (the paper's simulation, §6) or ICP on two clouds.
//!
//! Transforms are 4×4 homogeneous `T_target_source`: p_target = T · p_source.

mod driver;
mod input;
mod pipeline;
mod problem;
mod target;
mod units;

use std::ops::ControlFlow;

use nalgebra::Matrix4;

use crate::cost::CostFunction;
use crate::noise::{NoiseModel, NoiseScales};
pub use crate::sie::estimate::{InlierEstimate, MIN_ESTIMATE_ROWS, estimate_inliers};
use crate::sie::{HistogramModel, SieOptions};

pub use crate::error::Error;
pub use crate::geometry::{NonFinite, Point};
pub use crate::sie::schedule::WarmStart;

/// Residual used by ICP.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// r = T·a − b (3 columns).
    PointToPoint,
    /// r = n_bᵀ(T·a − b) with the target normal n_b (1 column).
    PointToPlane,
}

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

/// Where SIE starts from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Starts {
    /// Correspondences: besides the initial guess, the poses of a threshold-free hypothesis
    /// search (`sie::hypotheses`). ICP: the initial guess with the paper's β₀, with a narrow
    /// β₀, and after a scale-free lead (`sie::starts`). SIE runs from each and the result with
    /// the most significant inlier cluster is returned. Each start may make up to
    /// `max_iterations` updates.
    #[default]
    Automatic,
    /// Only the initial guess (the paper's method as published).
    InitialGuess,
}

/// Which start the returned transform came from (`sie::starts`, `sie::hypotheses`).
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
}

/// How a registration runs. `Default` is SIE, point-to-plane, no parameter to tune.
#[derive(Clone, Debug, PartialEq)]
pub struct RegistrationConfig {
    /// The robust cost that weights correspondences (SIE by default).
    pub cost: CostFunction,
    /// SIE's estimator settings (used when `cost` is [`CostFunction::Sie`]).
    pub sie: SieOptions,
    /// ICP only; correspondence registration always uses point-to-point.
    pub metric: Metric,
    /// Where SIE starts (SIE only; baselines start from the initial guess).
    pub starts: Starts,
    /// Cap on IRLS updates (each is one match + weight + solve step) of each start
    /// (`Starts::Automatic` runs several; `RegistrationResult::iterations` counts them all).
    pub max_iterations: u32,
    /// Converged when the update moves the source centroid by less than this (input units) …
    pub translation_tolerance: f64,
    /// … and rotates by less than this (radians).
    pub rotation_tolerance: f64,
    /// Built-in noise normalisation (§4.4); a `NoiseScales` callback passed to the registration
    /// overrides it.
    pub noise: NoiseModel,
    /// β₀ in normalised units; `None` = RMS of the initial residuals (§4.3).
    pub initial_beta: Option<f64>,
    /// SIE: start from a previous registration's noise model (`WarmStart::of`), for a
    /// sequence registered from good guesses. One run from the initial guess with β₀ = 2σ and
    /// no levels far below σ (none after the first when that one moved the rows by less than
    /// the model's width); when it ends without the model holding (not converged, no inlier
    /// peak, σ more than doubled or the inlier fraction halved: the guess was bad), the
    /// registration runs as without it (`starts`). Ignored when `initial_beta` is set.
    pub warm_start: Option<WarmStart>,
    /// β ← shrink·β after each convergence (§4.3: 0.5).
    pub beta_shrink: f64,
    /// Annealing ends when β < ratio·σ ("β ≪ σ").
    pub beta_stop_ratio: f64,
    /// ICP: use at most this many randomly chosen source points per iteration (0 = all).
    pub max_correspondences: usize,
    /// ICP point-to-plane: neighbours for PCA normals when the caller gives none.
    pub normal_neighbours: usize,
    /// Worker threads for matching and normals (0 = all cores, 1 = the caller's thread only).
    pub threads: usize,
    /// Seed of the correspondence sampling.
    pub seed: u64,
    /// Record one `TraceEntry` per iteration.
    pub record_trace: bool,
    /// Points (or pairs) with a NaN or infinite coordinate: rejected (the default), or dropped
    /// (depth images and PCL clouds with `is_dense = false` carry them). Dropped source points
    /// report probability 0 and no match; a non-finite target normal counts as "no normal".
    pub non_finite: NonFinite,
    /// Drop points (or pairs) at exactly (0, 0, 0) the same way: organised clouds from depth
    /// sensors mark invalid pixels so. They are not measurements, and with both clouds from the
    /// same sensor point-to-point matches them to each other (at residual 0 at the identity).
    /// Off by default: 0 0 0 can be a real point.
    pub skip_origin: bool,
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        RegistrationConfig {
            cost: CostFunction::Sie,
            sie: SieOptions::default(),
            metric: Metric::PointToPlane,
            starts: Starts::Automatic,
            max_iterations: 200,
            translation_tolerance: 1e-6,
            rotation_tolerance: 1e-6,
            noise: NoiseModel::Constant,
            initial_beta: None,
            warm_start: None,
            beta_shrink: 0.5,
            beta_stop_ratio: 0.01,
            max_correspondences: 0,
            normal_neighbours: 10,
            threads: 0,
            seed: 0x5EED,
            record_trace: false,
            non_finite: NonFinite::Reject,
            skip_origin: false,
        }
    }
}

impl RegistrationConfig {
    /// Checks every setting; the message names the first bad one.
    pub fn validate(&self) -> Result<(), Error> {
        let bad = |m: String| Err(Error::InvalidArgument(m));
        self.cost.validate().or_else(bad)?;
        self.sie.validate().or_else(bad)?;
        if self.max_iterations == 0 {
            return bad("max_iterations must be >= 1".into());
        }
        for (name, v) in [
            ("translation_tolerance", self.translation_tolerance),
            ("rotation_tolerance", self.rotation_tolerance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{name} must be finite and >= 0, got {v}"));
            }
        }
        if let Some(b) = self.initial_beta {
            if !(b.is_finite() && b >= 0.0) {
                return bad(format!("initial_beta must be finite and >= 0, got {b}"));
            }
        }
        if let Some(warm) = &self.warm_start {
            warm.validate().or_else(bad)?;
        }
        if !(self.beta_shrink > 0.0 && self.beta_shrink < 1.0) {
            return bad(format!("beta_shrink must be in (0, 1), got {}", self.beta_shrink));
        }
        if !(self.beta_stop_ratio > 0.0 && self.beta_stop_ratio.is_finite()) {
            return bad(format!(
                "beta_stop_ratio must be finite and > 0, got {}",
                self.beta_stop_ratio
            ));
        }
        input::require_normal_neighbours(self.normal_neighbours)?;
        if self.threads > 1024 {
            return bad(format!("threads must be <= 1024, got {}", self.threads));
        }
        Ok(())
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
    /// Estimating target normals (point-to-plane without given normals): choosing the scale up
    /// front, then each normal when matching first reaches its point (not counted in
    /// `matching` or `evaluation`).
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
    /// Σ_i P(I|r_i) / n_source at the returned transform (unmatched points count 0).
    pub inlier_fraction: f64,
    /// sqrt(Σ P_i‖r_i‖² / Σ P_i) at the returned transform, input units (‖r‖ is the plane
    /// distance for point-to-plane).
    pub rmse: f64,
    /// Per source point, P(I|r) at the returned transform (0 if unmatched). For baseline costs:
    /// the IRLS weight divided by the largest weight.
    pub probabilities: Vec<f64>,
    /// Per source point, the matched target index (-1 if unmatched).
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
}

/// A verdict on a registration from the evidence SIE has (issue: "converged" must mean right).
/// `converged` only says the iteration settled; this says whether the pose it settled at is
/// supported by the data.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Verdict {
    /// Every test passed: a significant inlier cluster, a pose the inliers constrain in every
    /// direction, no other start ending elsewhere nearly as significant, and (ICP) inlier
    /// residuals no wider than the points' spacing.
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
    /// Significance of the inlier cluster at the fitted scale (nats, `sie::significance`).
    pub significance: f64,
    /// How well the weighted inliers constrain the pose at the last update, 0–1
    /// (`geometry::Solve::conditioning`).
    pub conditioning: f64,
    /// Fitted σ over the typical distance between neighbouring target points (ICP; 0 for
    /// correspondences, which have no spacing).
    pub sigma_to_spacing: f64,
    /// Significance of the result over that of the best start that ended elsewhere (∞ when
    /// none did).
    pub margin: f64,
}

/// Where the returned transform came from.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SearchReport {
    /// Which start the transform came from.
    pub start: StartKind,
    /// Minimal samples drawn by the hypothesis search (0 when none ran).
    pub hypotheses: u32,
    /// Starts SIE was run from (1 without a search).
    pub starts_run: u32,
    /// Significance of the inlier cluster at the returned transform, at the scale of its
    /// fitted σ (`sie::significance::at_scale`; nats, 0 when nothing stands out from chance).
    /// 0 when only one start ran.
    pub significance: f64,
    /// Starts whose result is the returned pose (within 3 standard errors), itself included.
    pub agreeing_starts: u32,
    /// The largest significance among starts that ended elsewhere (0: none did).
    pub runner_up_significance: f64,
}

pub use input::{NORMAL_LENGTH_TOLERANCE, require_unit_normals};
impl WarmStart {
    /// The noise model a registration ended with, to start the next one from (`None` for a
    /// baseline cost or a result without a usable σ).
    pub fn of(result: &RegistrationResult) -> Option<WarmStart> {
        if result.beta.is_empty() {
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

pub use pipeline::{register_clouds, register_clouds_to, register_correspondences};
pub(crate) use pipeline::{register_owned_clouds, register_owned_to};
pub use target::{PrepareOptions, PreparedTarget};

/// Caller code a registration calls back into. `Hooks::default()` uses none.
#[derive(Default)]
pub struct Hooks<'a> {
    /// Per-point noise σ of both clouds (§4.4), called once per cloud; overrides
    /// `RegistrationConfig::noise`.
    pub noise: Option<&'a mut dyn NoiseScales>,
    /// Called after every update with that iteration's trace entry (also when `record_trace`
    /// is off). Returning `ControlFlow::Break(())` stops the registration with
    /// `StopReason::Cancelled` and the transform reached so far.
    pub observer: Option<&'a mut Observer<'a>>,
}

/// Per-iteration callback: `ControlFlow::Break(())` cancels the registration.
pub type Observer<'a> = dyn FnMut(&TraceEntry) -> ControlFlow<()> + 'a;

impl<'a> Hooks<'a> {
    /// Only a noise callback.
    pub fn noise(noise: Option<&'a mut dyn NoiseScales>) -> Self {
        Hooks {
            noise,
            observer: None,
        }
    }
}
