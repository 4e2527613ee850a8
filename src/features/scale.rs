//! The scale descriptors are computed at, from the data alone: a voxel size that leaves each
//! cloud a few thousand keypoints (Open3D's usual recipe then takes normals from 2 voxels and
//! FPFH from 5), never finer than the points' own spacing.

use std::collections::HashMap;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::geometry::{bounding_box, dot};
use crate::nn::NearestNeighbours;
use crate::parallel::Workers;
use crate::point::Point;
use crate::voxel;

/// Keypoints a cloud is aimed to keep: enough for a few hundred mutual matches, few enough that
/// brute-force matching of 33-bin descriptors stays a fraction of a second.
const TARGET_KEYPOINTS: usize = 2500;
/// The normal radius and the FPFH radius, in voxels (Open3D's recipe).
pub const NORMAL_RADIUS_VOXELS: f64 = 2.0;
/// See [`NORMAL_RADIUS_VOXELS`].
pub const FEATURE_RADIUS_VOXELS: f64 = 5.0;
/// Neighbours a normal and a descriptor may use (Open3D's recipe: 30 and 100).
pub const NORMAL_NEIGHBOURS: usize = 30;
/// See [`NORMAL_NEIGHBOURS`].
pub const FEATURE_NEIGHBOURS: usize = 100;
/// Points sampled for a cloud's spacing (the median nearest-neighbour distance).
const SPACING_SAMPLE: usize = 2000;

/// The voxel size both clouds' keypoints are taken at (one size, so that their descriptors
/// describe the same neighbourhoods).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DescriptorScale {
    /// Voxel edge (input units): the larger of the two clouds' own.
    pub voxel: f64,
    /// The voxel the source alone would take.
    pub source_voxel: f64,
    /// The voxel the target alone would take.
    pub target_voxel: f64,
}

impl DescriptorScale {
    /// The larger of the two clouds' voxel sizes: each cloud's is the size that leaves it about
    /// [`TARGET_KEYPOINTS`] voxels, never less than its spacing, and never more than
    /// `max_keypoints`. `None` when a cloud has no extent (all points at one place).
    pub fn choose(
        source: &[Point],
        source_index: &NearestNeighbours,
        target: &[Point],
        target_index: &NearestNeighbours,
        max_keypoints: usize,
    ) -> Option<Self> {
        let source_voxel = voxel_for(source, source_index, max_keypoints)?;
        let target_voxel = voxel_for(target, target_index, max_keypoints)?;
        Some(DescriptorScale {
            voxel: source_voxel.max(target_voxel),
            source_voxel,
            target_voxel,
        })
    }

    /// Radius of the normals' neighbourhoods.
    pub fn normal_radius(&self) -> f64 {
        NORMAL_RADIUS_VOXELS * self.voxel
    }

    /// Radius of the descriptors' neighbourhoods.
    pub fn feature_radius(&self) -> f64 {
        FEATURE_RADIUS_VOXELS * self.voxel
    }
}

/// The voxel size leaving `points` about `TARGET_KEYPOINTS` occupied voxels (at most
/// `max_keypoints`): a surface's count falls as 1/size², so a few corrections from the extent's
/// guess reach it.
fn voxel_for(points: &[Point], index: &NearestNeighbours, max_keypoints: usize) -> Option<f64> {
    let spacing = spacing(points, index);
    let (lo, hi) = bounding_box(points);
    let diagonal = (hi - lo).norm();
    if !(diagonal.is_finite() && diagonal > 0.0) {
        return None;
    }
    let floor = if spacing > 0.0 { spacing } else { diagonal * 1e-6 };
    let mut voxel = (diagonal / (TARGET_KEYPOINTS as f64).sqrt()).max(floor);
    for _ in 0..6 {
        let Some(next) = voxel::next_edge(voxel, occupied_voxels(points, voxel), TARGET_KEYPOINTS) else {
            break;
        };
        let next = next.max(floor);
        if next == voxel {
            break;
        }
        voxel = next;
    }
    // Scattered points (no surface) fall slower than 1/size²: grow until the cap holds.
    while occupied_voxels(points, voxel) > max_keypoints {
        voxel *= 1.25;
    }
    Some(voxel)
}

/// Median distance from a point to its nearest other point, over a sample (0 when most sampled
/// points have an exact duplicate).
fn spacing(points: &[Point], index: &NearestNeighbours) -> f64 {
    let step = points.len().div_ceil(SPACING_SAMPLE).max(1);
    let mut nearest = Vec::new();
    let mut distances: Vec<f64> = points
        .iter()
        .step_by(step)
        .filter_map(|p| {
            index.nearest_k(p, 2, &mut nearest);
            let other = nearest.iter().find(|&&j| points[j] != *p)?;
            let q = points[*other];
            Some(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt())
        })
        .collect();
    if distances.is_empty() {
        return 0.0;
    }
    let middle = distances.len() / 2;
    *distances.select_nth_unstable_by(middle, f64::total_cmp).1
}

fn occupied_voxels(points: &[Point], voxel: f64) -> usize {
    let mut seen = std::collections::HashSet::with_capacity(4 * TARGET_KEYPOINTS);
    for p in points {
        seen.insert(voxel::key(p, voxel));
    }
    seen.len()
}

/// A cloud reduced to one point per occupied voxel: the centroid of its points (Open3D's
/// `voxel_down_sample`).
pub struct Keypoints {
    /// The centroids, in the order their voxels were first met.
    pub points: Vec<Point>,
}

impl Keypoints {
    /// The voxel centroids of `points` at `scale`.
    pub fn of(points: &[Point], scale: &DescriptorScale) -> Self {
        let mut slots: HashMap<[i64; 3], usize> = HashMap::new();
        let mut sums: Vec<(Vector3<f64>, usize)> = Vec::new();
        for p in points {
            let slot = *slots.entry(voxel::key(p, scale.voxel)).or_insert_with(|| {
                sums.push((Vector3::zeros(), 0));
                sums.len() - 1
            });
            sums[slot].0 += Vector3::from(*p);
            sums[slot].1 += 1;
        }
        Keypoints {
            points: sums
                .into_iter()
                .map(|(sum, count)| (sum / count as f64).into())
                .collect(),
        }
    }
}

/// Unit normal of each point from the PCA of its neighbours within `radius` (at most
/// [`NORMAL_NEIGHBOURS`], the point included), turned towards the origin (the sensor, as
/// `normals::estimate_normals` does). Fewer than 3 neighbours, or neighbours on a line: zero.
pub fn keypoint_normals(
    points: &[Point],
    index: &NearestNeighbours,
    radius: f64,
    workers: &Workers,
) -> Vec<Point> {
    let squared_radius = radius * radius;
    let mut normals = vec![[0.0; 3]; points.len()];
    workers.for_each_chunk_of(256, &mut normals, |first, piece| {
        let mut nearest = Vec::new();
        for (offset, normal) in piece.iter_mut().enumerate() {
            let p = &points[first + offset];
            index.nearest_k(p, NORMAL_NEIGHBOURS, &mut nearest);
            let near: Vec<Vector3<f64>> = nearest
                .iter()
                .map(|&j| Vector3::from(points[j]))
                .filter(|q| (q - Vector3::from(*p)).norm_squared() <= squared_radius)
                .collect();
            *normal = plane_normal(&near).map_or([0.0; 3], |n| {
                let n: Point = n.into();
                if dot(&n, p) > 0.0 { n.map(|c| -c) } else { n }
            });
        }
    });
    normals
}

/// The smallest principal axis of `near`, when they span a plane.
fn plane_normal(near: &[Vector3<f64>]) -> Option<Vector3<f64>> {
    if near.len() < 3 {
        return None;
    }
    let mean = near.iter().sum::<Vector3<f64>>() / near.len() as f64;
    let covariance = near
        .iter()
        .map(|q| (q - mean) * (q - mean).transpose())
        .sum::<Matrix3<f64>>();
    let eigen = SymmetricEigen::new(covariance);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    // A line (or one place): no plane.
    if eigen.eigenvalues[order[1]] <= 1e-10 * eigen.eigenvalues[order[2]] {
        return None;
    }
    let normal = eigen.eigenvectors.column(order[0]).into_owned();
    let length = normal.norm();
    (length > 0.0).then(|| normal / length)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wavy surface of `n` points on a `side` × `side` grid.
    fn surface(side: usize, step: f64) -> Vec<Point> {
        (0..side * side)
            .map(|k| {
                let (x, y) = ((k % side) as f64 * step, (k / side) as f64 * step);
                [x, y, 0.2 * (x * 4.0).sin() * (y * 3.0).cos()]
            })
            .collect()
    }

    #[test]
    fn the_voxel_leaves_a_few_thousand_keypoints_and_never_splits_the_spacing() {
        // 90 000 points: the voxel grows until about 2500 keypoints remain.
        let dense = surface(300, 0.01);
        let index = NearestNeighbours::new(&dense).unwrap();
        let scale = DescriptorScale::choose(&dense, &index, &dense, &index, 4000).unwrap();
        let kept = Keypoints::of(&dense, &scale).points.len();
        assert!(
            (1500..=4000).contains(&kept),
            "{kept} keypoints at voxel {}",
            scale.voxel
        );
        // 400 points: no voxel finer than their spacing (0.01), so at most one keypoint each.
        let sparse = surface(20, 0.01);
        let index = NearestNeighbours::new(&sparse).unwrap();
        let scale = DescriptorScale::choose(&sparse, &index, &sparse, &index, 4000).unwrap();
        assert!(scale.voxel >= 0.01 * (1.0 - 1e-9), "{}", scale.voxel);
        // One place: no extent, no scale.
        let point = vec![[1.0, 2.0, 3.0]; 10];
        let index = NearestNeighbours::new(&point).unwrap();
        assert_eq!(
            DescriptorScale::choose(&point, &index, &point, &index, 4000),
            None
        );
    }

    #[test]
    fn keypoints_are_voxel_centroids_and_normals_face_the_origin() {
        let points = vec![[0.1, 0.1, 5.0], [0.3, 0.3, 5.0], [1.5, 0.5, 5.0]];
        let unit = DescriptorScale {
            voxel: 1.0,
            source_voxel: 1.0,
            target_voxel: 1.0,
        };
        let keypoints = Keypoints::of(&points, &unit).points;
        assert_eq!(keypoints, vec![[0.2, 0.2, 5.0], [1.5, 0.5, 5.0]]);
        let plane: Vec<Point> = (0..100)
            .map(|k| [(k % 10) as f64, (k / 10) as f64, 5.0])
            .collect();
        let index = NearestNeighbours::new(&plane).unwrap();
        let normals = keypoint_normals(&plane, &index, 2.5, &Workers::new(2).unwrap());
        for n in normals {
            assert!((n[2] + 1.0).abs() < 1e-9, "{n:?}");
        }
    }
}
