//! The point every API takes, and the one policy for points that are not measurements.

/// A 3-D point (or vector), in the caller's units.
pub type Point = [f64; 3];

/// What to do with input points that have a NaN or infinite coordinate: the one policy of
/// every entry point (file readers, the registrations, prepared targets, the C ABI).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NonFinite {
    /// Fail, naming the first such point.
    #[default]
    Reject,
    /// Drop them: depth images and PCL clouds with `is_dense = false` mark invalid points with
    /// NaN. A registration reports a dropped source point with probability 0 and no match, and
    /// a non-finite target normal counts as "no normal".
    Skip,
}
