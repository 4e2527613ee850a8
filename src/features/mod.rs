//! Rotation-invariant local descriptors for a global stage that needs no initial guess: the
//! scale they are computed at (chosen from the data), FPFH histograms, and matching them.
//!
//! * `scale`: the voxel size from the clouds' spacing and extent, keypoints (voxel centroids)
//!   and their normals.
//! * `fpfh`: Fast Point Feature Histograms (Rusu, Blodow, Beetz 2009) as Open3D computes them.
//! * `matching`: mutual nearest neighbours in descriptor space.

mod fpfh;
mod matching;
mod scale;

pub use fpfh::{FPFH_BINS, Fpfh, fpfh};
pub use matching::mutual_matches;
pub use scale::{
    DescriptorScale, FEATURE_NEIGHBOURS, FEATURE_RADIUS_VOXELS, Keypoints, NORMAL_NEIGHBOURS,
    NORMAL_RADIUS_VOXELS, keypoint_normals,
};
