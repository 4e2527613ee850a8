//! Candidate poses with no initial guess: FPFH descriptors of both clouds' keypoints at a scale
//! chosen from the data (`features::DescriptorScale`), mutual matches between them, and the
//! threshold-free hypothesis search (`hypotheses`) on those matches.

use nalgebra::{Matrix3, Matrix4, SymmetricEigen};

use super::hypotheses::{self, Pairs};
use crate::error::Error;
use crate::features::{DescriptorScale, Fpfh, Keypoints, fpfh, keypoint_normals, mutual_matches};
use crate::memory;
use crate::nn::NearestNeighbours;
use crate::parallel::Workers;
use crate::point::Point;

/// Keypoints with a normal each cloud needs: fewer describe too little of it to match (a cloud
/// of 20 points, a line).
const MIN_KEYPOINTS: usize = 50;
/// The keypoints' normals must not all point one way: the middle eigenvalue of their scatter
/// (mean n·nᵀ) at least this (normals within about 6° of one direction are one plane, whose
/// descriptors are all alike; real scenes keep 0.05 and more).
const MIN_NORMAL_SPREAD: f64 = 0.01;
/// When a cloud has too few keypoints at the voxel both share and the other cloud's own voxel
/// is this many times its own, the message names the scales: partial views of one scene in one
/// unit take voxels within a few times of each other (their extents), while millimetres
/// against metres differ 1000x, centimetres 100x.
const MIN_SCALE_RATIO: f64 = 20.0;
/// Most keypoints a cloud may keep (`DescriptorScale` aims at 2500), which bounds the
/// descriptors' memory and the matching's time.
pub(crate) const MAX_KEYPOINTS: usize = 4000;
/// Heap per keypoint while describing: the point, its normal, two 33-bin histograms, up to 100
/// neighbours (index and squared distance) and its share of the kd-tree, with margin.
const BYTES_PER_KEYPOINT: usize = 2 * 24 + 2 * 264 + 100 * 16 + 64;

/// The poses the global stage proposes, most significant first (the initial guess among them).
pub(crate) struct FeaturePoses {
    pub(crate) poses: Vec<Matrix4<f64>>,
    /// Minimal samples the hypothesis search drew.
    pub(crate) samples: usize,
}

/// Candidate poses of `source` onto `target` from descriptor matches. Errors: a cloud too
/// small or too plain to describe ([`Error::TooFewPoints`], the message says which and why), or
/// no memory for the descriptors.
pub(crate) fn feature_poses(
    source: &[Point],
    target: &[Point],
    init: &Matrix4<f64>,
    seed: u64,
    workers: &Workers,
) -> Result<FeaturePoses, Error> {
    // Before anything is built: the descriptors are bounded by MAX_KEYPOINTS per cloud.
    memory::ensure_available(
        memory::global_stage_bytes(
            source.len() + target.len(),
            2 * MAX_KEYPOINTS * BYTES_PER_KEYPOINT,
        ),
        "the global stage's descriptors",
    )?;
    let source_index = NearestNeighbours::new(source)?;
    let target_index = NearestNeighbours::new(target)?;
    let scale = DescriptorScale::choose(source, &source_index, target, &target_index, MAX_KEYPOINTS)
        .ok_or_else(|| {
            Error::TooFewPoints(
                "the global stage needs clouds with an extent: every point of a cloud is at one place"
                    .to_string(),
            )
        })?;
    drop((source_index, target_index));
    let source = Described::of(Role::Source, source, &scale, workers)?;
    let target = Described::of(Role::Target, target, &scale, workers)?;
    let matches = mutual_matches(&source.features, &target.features, workers);
    let pair_source: Vec<Point> = matches.iter().map(|&(i, _)| source.points[i]).collect();
    let pair_target: Vec<Point> = matches.iter().map(|&(_, j)| target.points[j]).collect();
    let scales = vec![1.0; matches.len()];
    let pairs = Pairs {
        source: &pair_source,
        target: &pair_target,
        scales: &scales,
    };
    let search = hypotheses::search(&pairs, init, seed);
    Ok(FeaturePoses {
        poses: search.candidates.iter().map(|h| h.transform).collect(),
        samples: search.samples,
    })
}

/// Which cloud is described (for the messages).
#[derive(Clone, Copy)]
enum Role {
    Source,
    Target,
}

impl Role {
    fn name(self) -> &'static str {
        match self {
            Role::Source => "source",
            Role::Target => "target",
        }
    }

    /// The voxel this cloud alone would take, and the other cloud's.
    fn own_and_other_voxels(self, scale: &DescriptorScale) -> (f64, f64) {
        match self {
            Role::Source => (scale.source_voxel, scale.target_voxel),
            Role::Target => (scale.target_voxel, scale.source_voxel),
        }
    }

    fn other(self) -> Role {
        match self {
            Role::Source => Role::Target,
            Role::Target => Role::Source,
        }
    }
}

/// A cloud's keypoints with a normal, and their descriptors.
struct Described {
    points: Vec<Point>,
    features: Vec<Fpfh>,
}

impl Described {
    fn of(role: Role, cloud: &[Point], scale: &DescriptorScale, workers: &Workers) -> Result<Self, Error> {
        let name = role.name();
        let keypoints = Keypoints::of(cloud, scale).points;
        let index = NearestNeighbours::new(&keypoints)?;
        let normals = keypoint_normals(&keypoints, &index, scale.normal_radius(), workers);
        let (points, normals): (Vec<Point>, Vec<Point>) = keypoints
            .iter()
            .zip(&normals)
            .filter(|(_, n)| **n != [0.0; 3])
            .map(|(p, n)| (*p, *n))
            .unzip();
        if points.len() < MIN_KEYPOINTS {
            let (own, other) = role.own_and_other_voxels(scale);
            let why = if other >= MIN_SCALE_RATIO * own {
                format!(
                    "both clouds are described at one scale, and the {}'s own is {:.0}x the {name}'s \
                     (voxel {other:.4e} against {own:.4e}): clouds in different units (centimetres \
                     against metres), or a small object against a whole scene; bring them to the same \
                     units, or register from an initial guess",
                    role.other().name(),
                    other / own
                )
            } else {
                "too few points, or a line, to describe; register from an initial guess instead".to_string()
            };
            return Err(Error::TooFewPoints(format!(
                "the global stage needs at least {MIN_KEYPOINTS} keypoints with a surface normal in each \
                 cloud; the {name} gives {} ({} points, voxel {:.4e}): {why}",
                points.len(),
                cloud.len(),
                scale.voxel
            )));
        }
        let spread = normal_spread(&normals);
        if spread < MIN_NORMAL_SPREAD {
            return Err(Error::TooFewPoints(format!(
                "the global stage found no structure to describe in the {name}: its surface normals all \
                 point one way (spread {spread:.1e}, a plane), so every descriptor is alike and no pose \
                 can be told from another; register from an initial guess instead"
            )));
        }
        let index = NearestNeighbours::new(&points)?;
        let features = fpfh(
            &points,
            &normals,
            &index,
            scale.feature_radius(),
            crate::features::FEATURE_NEIGHBOURS,
            workers,
        );
        Ok(Described { points, features })
    }
}

/// The middle eigenvalue of the normals' mean n·nᵀ: 0 when they all lie along one line (one
/// plane's, either sign), up to 1/2.
fn normal_spread(normals: &[Point]) -> f64 {
    let scatter = normals
        .iter()
        .map(|n| {
            let v = nalgebra::Vector3::from(*n);
            v * v.transpose()
        })
        .sum::<Matrix3<f64>>()
        / normals.len().max(1) as f64;
    let mut eigenvalues: Vec<f64> = SymmetricEigen::new(scatter).eigenvalues.iter().copied().collect();
    eigenvalues.sort_by(f64::total_cmp);
    eigenvalues[1]
}
