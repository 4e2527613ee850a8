//! A sensor frame thinned to one point per voxel before it is registered, for frames much
//! larger than a registration needs (a LiDAR sweep of 100 k points and more). The voxel is
//! chosen from the frame so that about [`THINNED_POINTS`] stay; the points left out take the
//! probability and correspondence of the point kept in their voxel, so a result still speaks
//! for every point of the frame.

use std::collections::HashMap;

use crate::geometry::{bounding_box_diagonal, is_finite};
use crate::point::Point;
use crate::registration::result::RegistrationResult;
use crate::voxel;

/// Frames are thinned to about this many points …
pub(crate) const THINNED_POINTS: usize = 16_384;
/// … when they hold more than this many valid points: a depth camera's 160 × 120 frame (19 k)
/// is registered whole, its far walls and near floor each fixing part of the pose; a LiDAR
/// sweep (60–130 k) is thinned.
const THIN_ABOVE: usize = 2 * THINNED_POINTS;
/// Voxel sizes tried at most per frame (each a pass over the frame).
const MAX_VOXEL_TRIES: usize = 6;
/// A frame point not registered at all (a missing return the config skips).
const NOT_KEPT: u32 = u32::MAX;

/// A frame thinned to one point per voxel: the first point met in each.
pub(crate) struct ThinnedFrame {
    pub(crate) points: Vec<Point>,
    /// For each frame point, the index in `points` of the point kept for its voxel.
    kept_for: Vec<u32>,
    /// The voxel edge used.
    pub(crate) voxel: f64,
}

impl ThinnedFrame {
    /// `frame` thinned, its valid points (finite, and not 0 0 0 when `skip_origin`) only;
    /// `None` when it has no more than [`THIN_ABOVE`] of them, or none with an extent.
    /// `previous_voxel` (the last frame's) is tried first.
    pub(crate) fn of(frame: &[Point], skip_origin: bool, previous_voxel: Option<f64>) -> Option<Self> {
        let valid = |p: &Point| is_finite(p) && !(skip_origin && *p == [0.0; 3]);
        let count = frame.iter().filter(|p| valid(p)).count();
        if count <= THIN_ABOVE {
            return None;
        }
        let diagonal = bounding_box_diagonal(frame.iter().filter(|p| valid(p)));
        if !(diagonal.is_finite() && diagonal > 0.0) {
            return None;
        }
        // A surface keeps a count that falls as 1/voxel²: a few corrections from a guess.
        let voxel = previous_voxel
            .filter(|v| v.is_finite() && *v > 0.0)
            .unwrap_or(diagonal / (THINNED_POINTS as f64).sqrt());
        let mut thinned = Self::at(frame, &valid, voxel);
        for _ in 1..MAX_VOXEL_TRIES {
            let Some(next) = voxel::next_edge(thinned.voxel, thinned.points.len(), THINNED_POINTS) else {
                break;
            };
            thinned = Self::at(frame, &valid, next);
        }
        Some(thinned)
    }

    fn at(frame: &[Point], valid: &impl Fn(&Point) -> bool, voxel: f64) -> Self {
        let mut slots: HashMap<[i64; 3], u32> = HashMap::with_capacity(2 * THINNED_POINTS);
        let mut points = Vec::with_capacity(2 * THINNED_POINTS);
        let kept_for = frame
            .iter()
            .map(|p| {
                if !valid(p) {
                    return NOT_KEPT;
                }
                *slots.entry(voxel::key(p, voxel)).or_insert_with(|| {
                    points.push(*p);
                    (points.len() - 1) as u32
                })
            })
            .collect();
        ThinnedFrame {
            points,
            kept_for,
            voxel,
        }
    }

    /// `result` (of the thinned points) for every frame point: each takes the probability and
    /// correspondence of the point kept for its voxel; points not registered at all, 0 and -1.
    pub(crate) fn spread_to_frame(&self, result: &mut RegistrationResult) {
        let spread = |kept: u32| (kept != NOT_KEPT).then_some(kept as usize);
        result.probabilities = self
            .kept_for
            .iter()
            .map(|&k| spread(k).map_or(0.0, |k| result.probabilities[k]))
            .collect();
        result.correspondences = self
            .kept_for
            .iter()
            .map(|&k| spread(k).map_or(-1, |k| result.correspondences[k]))
            .collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A floor and two walls of `side`² points each, with every 97th point a missing return
    /// (0 0 0) and every 101st NaN.
    fn corner(side: usize) -> Vec<Point> {
        let step = 10.0 / side as f64;
        let mut points = Vec::with_capacity(3 * side * side);
        for i in 0..side {
            for j in 0..side {
                let (u, v) = (i as f64 * step, j as f64 * step);
                points.extend([[u, v, 0.0], [u, 0.0, v], [0.0, u, v]]);
            }
        }
        for (k, p) in points.iter_mut().enumerate() {
            if k % 97 == 0 {
                *p = [0.0; 3];
            } else if k % 101 == 0 {
                *p = [f64::NAN, 1.0, 1.0];
            }
        }
        points
    }

    #[test]
    fn frames_up_to_twice_the_kept_count_are_left_whole() {
        let small = corner(100);
        assert!(small.len() <= THIN_ABOVE);
        assert!(ThinnedFrame::of(&small, true, None).is_none());
    }

    #[test]
    fn a_large_frame_keeps_about_the_count_one_point_per_voxel_and_each_point_knows_its_own() {
        let frame = corner(200);
        let thinned = ThinnedFrame::of(&frame, true, None).expect("120 000 points are thinned");
        let kept = thinned.points.len();
        let tolerance = voxel::COUNT_TOLERANCE;
        let settled = THINNED_POINTS as f64 / tolerance..=THINNED_POINTS as f64 * tolerance;
        assert!(
            settled.contains(&(kept as f64)),
            "{kept} kept at voxel {}",
            thinned.voxel
        );
        let key = |p: &Point| voxel::key(p, thinned.voxel);
        for (p, &k) in frame.iter().zip(&thinned.kept_for) {
            if !is_finite(p) || *p == [0.0; 3] {
                assert_eq!(k, NOT_KEPT, "{p:?}");
            } else {
                assert_eq!(key(p), key(&thinned.points[k as usize]), "{p:?}");
            }
        }
        // The voxel found is the next frame's first try, and settles at once.
        let again = ThinnedFrame::of(&frame, true, Some(thinned.voxel)).unwrap();
        assert_eq!(again.voxel, thinned.voxel);
        // 0 0 0 kept as a point when the config does not skip it.
        let with_origin = ThinnedFrame::of(&frame, false, Some(thinned.voxel)).unwrap();
        assert!(with_origin.points.contains(&[0.0; 3]));
    }

    #[test]
    fn every_frame_point_takes_its_kept_points_probability_and_match() {
        let frame = vec![
            [0.1, 0.1, 0.1],
            [0.2, 0.2, 0.2],
            [0.0; 3],
            [5.1, 0.1, 0.1],
            [5.2, 0.3, 0.0],
        ];
        let valid = |p: &Point| *p != [0.0; 3];
        let thinned = ThinnedFrame::at(&frame, &valid, 1.0);
        assert_eq!(thinned.points, vec![[0.1, 0.1, 0.1], [5.1, 0.1, 0.1]]);
        let mut result = RegistrationResult::with_points(vec![0.9, 0.25], vec![7, 3], 0.5);
        thinned.spread_to_frame(&mut result);
        assert_eq!(result.probabilities, vec![0.9, 0.9, 0.0, 0.25, 0.25]);
        assert_eq!(result.correspondences, vec![7, 7, -1, 3, 3]);
    }
}
