//! Voxel grids: the cell a point falls in, and the edge that leaves about a wanted number of
//! occupied cells (the global stage's keypoints, the odometry's thinned frames).

use crate::point::Point;

/// Occupied cells within this factor of the wanted count are close enough.
pub(crate) const COUNT_TOLERANCE: f64 = 1.25;

/// The cell of edge `voxel` that `p` falls in.
pub(crate) fn key(p: &Point, voxel: f64) -> [i64; 3] {
    p.map(|c| (c / voxel).floor() as i64)
}

/// The edge to try after `count` cells of edge `voxel` were occupied where `wanted` are;
/// `None` when the count is within [`COUNT_TOLERANCE`]. A surface's count falls as 1/edge², so
/// the edge scales by √(count / wanted), at most 2× either way.
pub(crate) fn next_edge(voxel: f64, count: usize, wanted: usize) -> Option<f64> {
    let ratio = count as f64 / wanted as f64;
    if (1.0 / COUNT_TOLERANCE..=COUNT_TOLERANCE).contains(&ratio) {
        return None;
    }
    Some(voxel * ratio.sqrt().clamp(0.5, 2.0))
}
