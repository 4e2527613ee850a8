//! Statistical Inlier Estimation (SIE), §4 of Ekekrantz, Folkesson, Jensfelt,
//! "Adaptive Cost Function for Pointcloud Registration": the estimator alone, on any residual
//! matrix. The registration that uses it (starts, search, verdict) is `crate::registration`.
//!
//! Input: a residual matrix R with n rows (correspondences) and m columns (residual
//! dimensions), already divided by the per-row noise scale F(i) of §4.4.
//!
//! Where each part of §4 lives:
//! * `options`: the settings (histogram mode, noise shape p, bins per sample, ε, k₀, γ rule).
//! * `shape`: the inlier model G of §4.1 and the appendix (generalised Gaussian, shape p)
//!   and the asymmetric penalty of eq. (fitParams) with its minimiser.
//! * `histogram`: one histogram H_j (§4.5: range where G > ε, bins linear in the samples,
//!   smoothing ∝ width), the fit of μ, α, σ (and p) to it, and the per-bin table of
//!   P(I|r) = G_{σ+β}/H capped at 0.99 (eqs. InlierRatio, InlierRatioReg).
//! * `estimator`: the models of every histogram across fits, the adaptive k = P(I|H)^-3
//!   (§4.5), and each row's P(I|R_i), columns combined with γ = (P(I)/P(O))^(m-1) (§4.2).
//! * `schedule`: the estimator inside IRLS (§3, §4.3, §4.5): β annealed until β ≪ σ, the
//!   final round with adaptive k, the IRLS weight of eqs. (regprob3) / (regprob3GGD).
//! * `estimate`: §4 on its own, for callers that do their own estimation.

pub(crate) mod estimate;
pub(crate) mod estimator;
pub(crate) mod histogram;
pub(crate) mod options;
pub(crate) mod schedule;
pub(crate) mod shape;

pub use estimate::{InlierEstimate, MIN_ESTIMATE_ROWS, estimate_inliers};
pub use estimator::SieEstimator;
pub use histogram::{HistogramModel, ModelWidth};
pub use options::{GammaRule, HistogramMode, NoiseShape, SieOptions};
pub use schedule::WarmStart;
pub use shape::GeneralisedGaussian;
