//! Where SIE starts, and which start's result is kept. SIE's IRLS is local; its robustness to
//! a poor initial guess comes from starting it more than once and keeping the result whose
//! inlier cluster is most significant at its own scale (`registration::significance`).
//!
//! * `cloud_starts`: ICP's starts from one guess (the paper's β₀, a narrow β₀, a scale-free lead).
//! * `hypotheses`: a threshold-free hypothesis search over minimal samples of given pairs.
//! * `pair_starts`: correspondence registration from the guess, or from that search's best
//!   poses.
//! * `half_turns`, `quarter_turns`, `period_shifts`: the rivals a near-symmetric, box-like or
//!   repeating scene allows a result, run as further starts; `scaled_source`: a fit that also
//!   scales the source.
//! * `choice`: the choice between the starts' results, and how the others relate to it.
//! * `feature_poses`, `global_starts`: with no guess to trust, poses from descriptor matches
//!   (FPFH, mutual matching, the hypothesis search) and SIE from each.

mod choice;
mod cloud_starts;
mod feature_poses;
mod global_starts;
mod half_turns;
mod hypotheses;
mod pair_starts;
mod period_shifts;
mod quarter_turns;
mod scaled_source;

pub(crate) use choice::BestOfStarts;
pub(crate) use cloud_starts::{
    challenge_with_rivals, register_from_starts, register_one_start, run_on_clouds,
};
pub(crate) use feature_poses::{FeaturePoses, feature_poses};
pub(crate) use global_starts::register_from_feature_poses;
pub(crate) use pair_starts::{register_from_guess, register_from_hypotheses};
