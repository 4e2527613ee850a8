//! How a registration runs: the metric, where SIE starts, and every setting of
//! [`RegistrationConfig`].

use crate::cost::CostFunction;
use crate::error::Error;
use crate::noise::NoiseModel;
use crate::point::NonFinite;
use crate::sie::{SieOptions, WarmStart};

/// Residual used by ICP.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Metric {
    /// r = T·a − b (3 columns).
    PointToPoint,
    /// r = n_bᵀ(T·a − b) with the target normal n_b (1 column).
    PointToPlane,
}

/// Where SIE starts from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Starts {
    /// Correspondences: besides the initial guess, the poses of a threshold-free hypothesis
    /// search (`search::hypotheses`). ICP: the initial guess with the paper's β₀, with a narrow
    /// β₀, and after a scale-free lead (`search::cloud_starts`). SIE runs from each and the result with
    /// the most significant inlier cluster is returned; the search ends after the paper's start
    /// when its result is GOOD on its own evidence and either moved little (10 fitted σ),
    /// corrected the guess locally (within half the target's spread, every direction fixed by
    /// its surfaces) or the paper's run from it stays there. Each start may make up to
    /// `max_iterations` updates.
    #[default]
    Automatic,
    /// Only the initial guess (the paper's method as published). A run that ends more than 10
    /// fitted σ from the guess, and further than a local correction (half the target's spread,
    /// every direction fixed by its surfaces), is run once more from its result and the more
    /// significant of the two is kept: a pose the method does not return to is no answer (a flipped
    /// low-overlap scan that one run stopped at is left by the second for a better fit). When
    /// that far result is still not GOOD, a narrow β₀ (1/256 of the RMS residual) runs from the
    /// guess too: a small overlap near the guess, which the wide first levels left for the rest.
    InitialGuess,
    /// ICP from any pose, no guess needed: FPFH descriptors of both clouds at a scale chosen
    /// from the data (a voxel that leaves each a few thousand keypoints, never finer than its
    /// point spacing; normals from 2 voxels, descriptors from 5), mutual matches between them,
    /// the threshold-free hypothesis search on those matches, then SIE from the initial guess
    /// and from each of the 4 most significant poses found, the most significant result kept
    /// (its rivals challenge it as with `Automatic`); starts ending elsewhere lower its margin.
    /// Costs the descriptors (about 0.1–0.5 s at a few thousand keypoints on 2 cores) and up
    /// to 5 SIE runs besides the rivals. Clouds too small or too plain to describe (under 50
    /// keypoints with a normal, or every normal one way: a plane) are refused with
    /// `Error::TooFewPoints` saying why. SIE with the automatic β₀ only; a baseline cost or a
    /// fixed β₀ runs once from the initial guess. Correspondence registration treats it as
    /// `Automatic` (its pairs are matches already).
    Global,
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
    /// (`Starts::Automatic` runs several, a single start that travelled is run again, half and
    /// quarter turns and period shifts are run as starts; `RegistrationResult::iterations`
    /// counts them all).
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
    /// peak, σ more than doubled, the inlier fraction halved, or it travelled beyond the
    /// model's reach: the guess was bad) or with a verdict that is not GOOD, the registration
    /// runs as without it (`starts`). Ignored when `initial_beta` is set. `WarmStart::of` gives
    /// none for a result that is not GOOD: the next frame runs cold.
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
    /// sensors and LiDAR drivers mark invalid returns so. They are not measurements. Kept, they
    /// are one location, which ICP counts as one point (as every exact duplicate), but with
    /// both clouds from the same sensor it still matches the other's (at residual 0 at the
    /// identity). Off by default: 0 0 0 can be a real point.
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
        require_normal_neighbours(self.normal_neighbours)?;
        if self.threads > 1024 {
            return bad(format!("threads must be <= 1024, got {}", self.threads));
        }
        Ok(())
    }
}

/// The neighbour counts PCA normals may use: three points span a plane, and a thousand is
/// far beyond any scan's need (each normal costs a k-NN query).
const NORMAL_NEIGHBOURS: std::ops::RangeInclusive<usize> = 3..=1000;

/// `normal_neighbours` (of a config or a prepared target) is in 3..=1000.
pub(crate) fn require_normal_neighbours(neighbours: usize) -> Result<(), Error> {
    if NORMAL_NEIGHBOURS.contains(&neighbours) {
        Ok(())
    } else {
        Err(Error::InvalidArgument(format!(
            "normal_neighbours must be in {}..={}, got {neighbours}",
            NORMAL_NEIGHBOURS.start(),
            NORMAL_NEIGHBOURS.end()
        )))
    }
}
