//! sie — point-cloud registration with a self-tuning robust cost function: Statistical Inlier
//! Estimation (Ekekrantz, Folkesson, Jensfelt, "Adaptive Cost Function for Pointcloud
//! Registration").
//!
//! * [`sie`]: the estimator on any residual matrix.
//! * [`registration`]: rigid registration from correspondences or ICP on two clouds.
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
// Every public item says what it is for (units, ranges) where a user reads it.
#![warn(missing_docs)]

// `cost` and `noise` are reached through the re-exports below only. `parallel` and `normals`
// stay public: the tests and examples (bench_icp, memory_limits, prepared_target) use them.
pub(crate) mod cost;
pub mod error;
pub mod ffi;
pub mod geometry;
#[cfg(feature = "io")]
pub mod io;
pub mod memory;
mod median;
pub mod nn;
pub(crate) mod noise;
pub mod normals;
pub mod parallel;
pub mod registration;
pub mod sie;
pub mod synthetic;

pub use cost::CostFunction;
pub use noise::{CloudRole, NoiseModel, NoiseScales};
pub use registration::{
    Error, Hooks, InlierEstimate, MIN_ESTIMATE_ROWS, Metric, NonFinite, Observer, Point, PrepareOptions,
    PreparedTarget, Quality, RegistrationConfig, RegistrationResult, SearchReport, StageTimes, StartKind,
    Starts, StopReason, TraceEntry, Verdict, WarmStart, estimate_inliers, register_clouds,
    register_clouds_to, register_correspondences,
};
pub use sie::{GammaRule, HistogramMode, HistogramModel, ModelWidth, NoiseShape, SieEstimator, SieOptions};
