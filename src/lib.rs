//! sie — point-cloud registration with a self-tuning robust cost function: Statistical Inlier
//! Estimation (Ekekrantz, Folkesson, Jensfelt, "Adaptive Cost Function for Pointcloud
//! Registration").
//!
//! * Registration: [`register_clouds`] (ICP of two clouds), [`register_clouds_to`] (onto a
//!   [`PreparedTarget`] that serves many registrations), [`register_correspondences`] (given
//!   pairs), each configured by a [`RegistrationConfig`] and reporting a [`RegistrationResult`]
//!   with its verdict ([`Quality`]).
//! * The estimator alone: [`estimate_inliers`] on any residual matrix, or [`SieEstimator`].
//! * [`ffi`]: the C ABI (the only module that touches raw pointers).
//!
//! ```
//! use sie::synthetic::room_scene;
//! use sie::{Hooks, RegistrationConfig, StopReason, register_clouds};
//!
//! // Two noisy, partially overlapping scans of a room, 7° and 0.2 m apart.
//! let scene = room_scene(5_000, 0.01, 1);
//! let result = register_clouds(&scene.source, &scene.target, None, None, &RegistrationConfig::default(), Hooks::default())?;
//! assert_eq!(result.stop_reason, StopReason::Converged);
//! // p_target = T · p_source; compare with the known transform.
//! let error = (result.transform - scene.t_target_source).abs().max();
//! assert!(error < 0.01, "{error}");
//! # Ok::<(), sie::Error>(())
//! ```
// Raw pointers live in `ffi` only (its own `allow` lifts this there); the compiler keeps it so,
// and every block there states why it is sound.
#![deny(unsafe_code)]
#![warn(clippy::undocumented_unsafe_blocks)]
// Every public item says what it is for (units, ranges) where a user reads it, and the docs
// build without a broken or private link (scripts/test-all.sh denies rustdoc's warnings).
#![warn(missing_docs)]
#![warn(
    rustdoc::broken_intra_doc_links,
    rustdoc::private_intra_doc_links,
    rustdoc::missing_crate_level_docs,
    rustdoc::invalid_codeblock_attributes,
    rustdoc::invalid_html_tags,
    rustdoc::invalid_rust_codeblocks,
    rustdoc::bare_urls,
    rustdoc::redundant_explicit_links,
    rustdoc::unescaped_backticks
)]

// One path per public item: the registration and the estimator are reached through the
// re-exports below (their modules are private); `geometry`, `io` and `synthetic` are toolboxes
// of their own; `ffi` is the C ABI. The modules the tests and benchmarks reach into for
// measurements are public but hidden from the documentation.
mod cost;
mod error;
#[doc(hidden)]
pub mod features;
pub mod ffi;
pub mod geometry;
#[cfg(feature = "io")]
pub mod io;
mod median;
#[doc(hidden)]
pub mod memory;
#[doc(hidden)]
pub mod nn;
mod noise;
#[doc(hidden)]
pub mod normals;
#[doc(hidden)]
pub mod parallel;
mod point;
mod registration;
mod sie;
pub mod synthetic;
mod voxel;

pub use cost::CostFunction;
pub use error::Error;
pub use geometry::LooseDirection;
pub use noise::{CloudRole, NoiseModel, NoiseScales};
pub use point::{NonFinite, Point};
pub use registration::{
    FrameOutcome, FrameStatus, Hooks, MIN_CONDITIONING, MIN_MARGIN, MIN_SCALED_RATIO, Metric,
    NORMAL_LENGTH_TOLERANCE, Observer, Odometry, PoseUncertainty, PrepareOptions, PreparedTarget, Quality,
    RegistrationConfig, RegistrationResult, ScaledSource, SearchReport, StageTimes, StartKind, Starts,
    StopReason, TraceEntry, Verdict, register_clouds, register_clouds_to, register_correspondences,
};
pub use sie::{
    GammaRule, GeneralisedGaussian, HistogramMode, HistogramModel, InlierEstimate, MIN_ESTIMATE_ROWS,
    ModelWidth, NoiseShape, SieEstimator, SieOptions, WarmStart, estimate_inliers,
};
