//! Where SIE starts on two clouds, and which start's result is kept.
//!
//! §4.3 leaves β₀ open ("prior knowledge about the uncertainty of T or … the standard
//! deviation of the initial set of residuals"). The RMS of the initial residuals (the paper's
//! choice) is right when the initial guess is poor, but on partially overlapping scans it also
//! counts the points with no counterpart: the first levels then weigh almost everything and
//! follow the all-points optimum away from a good initial guess. A β₀ far below the RMS keeps a
//! good guess but cannot travel far from a poor one; and when the initial residuals have no
//! peak at all, a scale-free IRLS (L1) finds the basin better than either. None of the three
//! wins everywhere, so ICP runs all of them from the initial guess and keeps the result whose
//! inlier cluster is most significant at its own fitted scale (`significance::at_scale`).
//!
//! Measured on the real-scan table's 132 registrations (docs/results.md, "Real scans"): the
//! paper's β₀ alone succeeds on 50 of the 92 Stanford runs, β₀ = RMS/256 alone on 68, both with
//! the selection on 69–70; the L1 lead turns the two Kinect frame pairs that fail from the
//! identity with quadratic noise scaling into successes.

/// Before SIE: nothing, or a scale-free IRLS run whose result SIE starts from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lead {
    None,
    /// IRLS with the L1 weight 1/max(‖r‖, δ) (no scale to tune) until its updates are small
    /// against the initial residuals.
    ScaleFree,
}

/// One start of SIE on two clouds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CloudStart {
    pub lead: Lead,
    /// β₀ as a fraction of the RMS residual at SIE's start (1: the paper's β₀).
    pub beta_fraction: f64,
}

/// The starts ICP runs from one initial guess, in order: the paper's, a narrow one, and a
/// scale-free lead followed by the paper's.
pub const CLOUD_STARTS: [CloudStart; 3] = [
    CloudStart {
        lead: Lead::None,
        beta_fraction: 1.0,
    },
    CloudStart {
        lead: Lead::None,
        beta_fraction: 1.0 / 256.0,
    },
    CloudStart {
        lead: Lead::ScaleFree,
        beta_fraction: 1.0,
    },
];

/// The scale-free lead stops when an update moves the source centroid by less than this
/// fraction of the initial RMS residual and rotates it by less than LEAD_ROTATION_TOLERANCE:
/// it only has to reach the basin, SIE does the rest.
pub const LEAD_TRANSLATION_FRACTION: f64 = 1e-3;
pub const LEAD_ROTATION_TOLERANCE: f64 = 1e-4;
