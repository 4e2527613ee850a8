//! Rigid registration with IRLS (§3) weighted by SIE (§4) or a baseline cost (§5): from given
//! correspondences (the paper's simulation, §6) or ICP on two clouds.
//!
//! Transforms are 4×4 homogeneous `T_target_source`: p_target = T · p_source.
//!
//! * `correspondences`, `clouds`: the entry points (`register_correspondences`,
//!   `register_clouds`, `register_clouds_to`): checks, units, the flow of one registration.
//! * `config`, `result`, `hooks`: what a caller gives and gets back.
//! * `target`: a target cloud prepared once for many registrations.
//! * `problem`: the residual rows a transform gives and the weighted step they solve (given
//!   pairs, or ICP's nearest-neighbour matches).
//! * `irls`: one run of the IRLS loop by its own plan (β₀, matched subset, stopping rule).
//! * `search`: where SIE starts and which start's result is kept.
//! * `warm`: a sequence's warm start and whether its model held.
//! * `odometry`: a sensor's frames one after another, bad frames set aside.
//! * `significance`, `verdict`, `degeneracy`: how far to trust a result (`degeneracy`: how
//!   well the surfaces under a point-to-point result fix its pose).
//! * `input`, `units`: the input rules, and computing in safe units.

mod clouds;
mod config;
mod correspondences;
mod covariance;
mod degeneracy;
mod hooks;
mod input;
mod irls;
mod odometry;
mod problem;
mod result;
mod search;
pub(crate) mod significance;
mod target;
mod thinning;
mod units;
mod verdict;
mod warm;

pub use clouds::{register_clouds, register_clouds_to};
pub(crate) use clouds::{register_owned_clouds, register_owned_to};
pub use config::{Metric, RegistrationConfig, Starts};
pub use correspondences::register_correspondences;
pub use covariance::PoseUncertainty;
pub use hooks::{Hooks, Observer};
pub use input::NORMAL_LENGTH_TOLERANCE;
pub use odometry::{FrameOutcome, FrameStatus, Odometry};
pub use result::{
    Quality, RegistrationResult, ScaledSource, SearchReport, StageTimes, StartKind, StopReason, TraceEntry,
    Verdict,
};
pub use target::{PrepareOptions, PreparedTarget};
pub use verdict::{MIN_CONDITIONING, MIN_MARGIN, MIN_SCALED_RATIO};
