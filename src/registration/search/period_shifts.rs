//! Poses a repeating scene explains nearly as well as the result (project issue 29). A row of
//! pillars or boxes on a floor lies on itself shifted by one period: ICP from a guess near such
//! a shift stays there, every element matched to its neighbour, and a single start has nothing
//! to compare that with. The shifts are found in the result's own surface sample (its inliers
//! with their targets' normals): along each principal axis of the sample, pairs of points on
//! surfaces facing that axis, with parallel normals and side by side across it, vote for the
//! distance between them. Pairs on one face vote for zero; a period collects as many votes or
//! more (every element's faces but the last have partners one period on). Surfaces running along the
//! axis (the floor, the walls beside the row) slide onto themselves under any shift and do not
//! vote. Each shift is then screened and refined like a half turn (`half_turns`).

use std::collections::HashMap;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::registration::degeneracy::SurfaceRow;

/// A surface faces an axis when its normal is within about 45° of it.
const FACING_COSINE: f64 = 0.7;
/// Two points of a pair lie on parallel surfaces when their normals are within about 25°.
const SAME_NORMAL_COSINE: f64 = 0.9;
/// A shift is a period when it collects at least this share of the votes for zero (pairs on
/// one face): with k repeated elements in view, one period pairs the faces of k − 1 of them
/// with the next one's …
const PERIOD_VOTE_SHARE: f64 = 0.6;
/// … and twice the shift at least this share, the faces of k − 2 (k ≥ 3). One box's two
/// opposite faces vote for its width as strongly as a period (normals are sign-free here),
/// but nothing votes for twice its width.
const SECOND_PERIOD_VOTE_SHARE: f64 = 0.3;
/// At most this many periods per axis (the strongest), each tried in both directions.
const PERIODS_PER_AXIS: usize = 2;
/// Facing points used per axis (evenly strided beyond): the votes are over all their pairs.
const MAX_FACING: usize = 600;
/// Fewer facing points than this show no repeated structure worth voting on.
const MIN_FACING: usize = 20;
/// More bins than this (a sample spread over a million spacings) are not voted on.
const MAX_BINS: f64 = 100_000.0;
/// The vote bins are this many times the median distance between neighbouring facing points:
/// wide enough that a face one period on has partners side by side with most points.
const BIN_SPACINGS: f64 = 2.0;

/// Translations (in the target frame) that move the result's inliers by one period of
/// structure they repeat, in both directions; empty when they repeat nothing.
pub(crate) fn period_shifts(rows: &[SurfaceRow]) -> Vec<Vector3<f64>> {
    if rows.len() < MIN_FACING {
        return Vec::new();
    }
    let points: Vec<Vector3<f64>> = rows.iter().map(|row| Vector3::from(row.moved)).collect();
    let normals: Vec<Vector3<f64>> = rows.iter().map(|row| Vector3::from(row.normal)).collect();
    let mut shifts = Vec::new();
    for axis in principal_axes(&points) {
        let facing: Vec<usize> = (0..rows.len())
            .filter(|&i| normals[i].dot(&axis).abs() >= FACING_COSINE)
            .collect();
        if facing.len() < MIN_FACING {
            continue;
        }
        let stride = facing.len().div_ceil(MAX_FACING);
        let chosen: Vec<usize> = facing.into_iter().step_by(stride).collect();
        let pts: Vec<Vector3<f64>> = chosen.iter().map(|&i| points[i]).collect();
        let nrm: Vec<Vector3<f64>> = chosen.iter().map(|&i| normals[i]).collect();
        let Some(bin) = neighbour_spacing(&pts).map(|s| BIN_SPACINGS * s) else {
            continue;
        };
        for period in periods_along(&pts, &nrm, &axis, bin) {
            shifts.push(period * axis);
            shifts.push(-period * axis);
        }
    }
    shifts
}

/// The strongest periods (distances along `axis`, positive) that pairs side by side across it
/// vote for, with `bin` the width of a vote bin and of "side by side".
fn periods_along(
    points: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    axis: &Vector3<f64>,
    bin: f64,
) -> Vec<f64> {
    let along: Vec<f64> = points.iter().map(|p| p.dot(axis)).collect();
    let extent = along.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - along.iter().copied().fold(f64::INFINITY, f64::min);
    let bins = (extent / bin).ceil() + 2.0;
    if !(bins.is_finite() && bins <= MAX_BINS) {
        return Vec::new();
    }
    let bins = bins as usize;
    // votes[k]: pairs k·bin apart along the axis (rounded); sums[k]: their distances. Each
    // point's partners come from the cells around it across the axis, in index order, so the
    // sums add up as over all pairs.
    let mut votes = vec![0usize; bins];
    let mut sums = vec![0.0f64; bins];
    let cells = AcrossCells::new(points, axis, bin);
    let mut partners = Vec::new();
    for i in 0..points.len() {
        cells.partners_after(i, &mut partners);
        for &j in &partners {
            if normals[i].dot(&normals[j]).abs() < SAME_NORMAL_COSINE {
                continue;
            }
            let apart = points[j] - points[i];
            let distance = (along[j] - along[i]).abs();
            let across = (apart - (along[j] - along[i]) * axis).norm();
            if across > bin {
                continue;
            }
            let k = (distance / bin).round() as usize;
            if k < bins {
                votes[k] += 1;
                sums[k] += distance;
            }
        }
    }
    let at_zero = votes[0];
    if at_zero == 0 {
        return Vec::new();
    }
    let share = |k: usize| votes[k] as f64 / at_zero as f64;
    // Near two periods (within a bin): a third element repeats the first two.
    let twice = |k: usize| {
        (2 * k - 1..=2 * k + 1)
            .filter(|&m| m < bins)
            .map(share)
            .fold(0.0, f64::max)
    };
    // Local maxima beyond the faces' own thickness, with enough votes there and at twice the
    // distance (one box's two opposite faces vote for its width, but not for twice that).
    let mut peaks: Vec<(usize, usize)> = (2..bins)
        .filter(|&k| {
            share(k) >= PERIOD_VOTE_SHARE
                && twice(k) >= SECOND_PERIOD_VOTE_SHARE
                && votes[k] >= votes[k - 1]
                && votes.get(k + 1).is_none_or(|&next| votes[k] > next)
        })
        .map(|k| (votes[k], k))
        .collect();
    peaks.sort_unstable_by(|a, b| b.cmp(a));
    peaks
        .into_iter()
        .take(PERIODS_PER_AXIS)
        .map(|(count, k)| sums[k] / count as f64)
        .collect()
}

/// A grid over the plane across an axis whose cells are a little wider than `bin`: two points
/// less than `bin` apart across the axis lie in the same or neighbouring cells.
struct AcrossCells {
    /// Each point's cell.
    cell_of: Vec<(i64, i64)>,
    /// Each cell's points, ascending.
    members: HashMap<(i64, i64), Vec<usize>>,
}

impl AcrossCells {
    fn new(points: &[Vector3<f64>], axis: &Vector3<f64>, bin: f64) -> Self {
        // Two directions across the axis; the margin covers the rounding of the across
        // distance the votes compute their own way.
        let u = axis
            .cross(&Vector3::x())
            .try_normalize(1e-6)
            .unwrap_or_else(|| axis.cross(&Vector3::y()).normalize());
        let v = axis.cross(&u);
        let width = bin * (1.0 + 1e-6);
        let cell = |p: &Vector3<f64>| {
            (
                (p.dot(&u) / width).floor() as i64,
                (p.dot(&v) / width).floor() as i64,
            )
        };
        let cell_of: Vec<(i64, i64)> = points.iter().map(cell).collect();
        let mut members: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
        for (i, c) in cell_of.iter().enumerate() {
            members.entry(*c).or_default().push(i);
        }
        AcrossCells { cell_of, members }
    }

    /// The points after `i` (by index, ascending) in its cell and the eight around it.
    fn partners_after(&self, i: usize, out: &mut Vec<usize>) {
        out.clear();
        let (a, b) = self.cell_of[i];
        for da in -1..=1 {
            for db in -1..=1 {
                if let Some(cell) = self.members.get(&(a.saturating_add(da), b.saturating_add(db))) {
                    let after = cell.partition_point(|&j| j <= i);
                    out.extend_from_slice(&cell[after..]);
                }
            }
        }
        out.sort_unstable();
    }
}

/// The median distance from each point to its nearest other point (None below two points).
fn neighbour_spacing(points: &[Vector3<f64>]) -> Option<f64> {
    if points.len() < 2 {
        return None;
    }
    // Swept in x order: a point further along x than the nearest found so far is no nearer.
    let mut by_x: Vec<usize> = (0..points.len()).collect();
    by_x.sort_unstable_by(|&a, &b| points[a].x.total_cmp(&points[b].x));
    let mut nearest: Vec<f64> = (0..by_x.len())
        .map(|rank| {
            let p = &points[by_x[rank]];
            let mut best = f64::INFINITY;
            let mut look = |other: usize| {
                let q = &points[other];
                let dx = q.x - p.x;
                if dx * dx > best {
                    return false;
                }
                best = best.min((q - p).norm_squared());
                true
            };
            for &other in &by_x[rank + 1..] {
                if !look(other) {
                    break;
                }
            }
            for &other in by_x[..rank].iter().rev() {
                if !look(other) {
                    break;
                }
            }
            best
        })
        .collect();
    nearest.sort_unstable_by(f64::total_cmp);
    let median = nearest[nearest.len() / 2].sqrt();
    (median.is_finite() && median > 0.0).then_some(median)
}

/// The eigenvectors of the points' scatter about their centroid.
fn principal_axes(points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let centroid = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let scatter = points.iter().fold(Matrix3::zeros(), |sum, p| {
        let d = p - centroid;
        sum + d * d.transpose()
    });
    if !scatter.iter().all(|v| v.is_finite()) {
        return Vec::new();
    }
    SymmetricEigen::new(scatter)
        .eigenvectors
        .column_iter()
        .map(|axis| axis.into_owned())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The four side faces of 0.4 m square boxes (1 m high) at x = 0, 1, …, count − 1, on a
    /// 2 m wide floor: points on a 5 cm grid with their outward normals.
    fn row_of_boxes(count: usize) -> Vec<SurfaceRow> {
        let mut rows = Vec::new();
        let mut push = |moved: [f64; 3], normal: [f64; 3]| {
            rows.push(SurfaceRow {
                moved,
                target: 0,
                normal,
                weight: 1.0,
                row: rows.len(),
            })
        };
        let steps = |from: f64, to: f64| {
            let n = ((to - from) / 0.05).round() as usize;
            (0..=n).map(move |k| from + k as f64 * 0.05)
        };
        for x in steps(-0.5, count as f64 - 0.5) {
            for y in steps(-1.0, 1.0) {
                push([x, y, 0.0], [0.0, 0.0, 1.0]);
            }
        }
        for b in 0..count {
            let c = b as f64;
            for t in steps(-0.2, 0.2) {
                for z in steps(0.0, 1.0) {
                    push([c - 0.2, t, z], [-1.0, 0.0, 0.0]);
                    push([c + 0.2, t, z], [1.0, 0.0, 0.0]);
                    push([c + t, -0.2, z], [0.0, -1.0, 0.0]);
                    push([c + t, 0.2, z], [0.0, 1.0, 0.0]);
                }
            }
        }
        rows
    }

    /// Five boxes 1 m apart: the shifts found are ±1 m along the row (and possibly ±2 m), none
    /// across it; one box alone repeats nothing, nor do two.
    #[test]
    fn a_row_of_boxes_repeats_by_its_spacing_and_one_or_two_boxes_by_nothing() {
        let shifts = period_shifts(&row_of_boxes(5));
        assert!(!shifts.is_empty(), "no period found");
        for shift in &shifts {
            assert!(
                shift.y.abs() < 0.05 && shift.z.abs() < 0.05,
                "{shift:?} is not along the row"
            );
        }
        let one_period = shifts.iter().filter(|s| (s.x.abs() - 1.0).abs() < 0.05).count();
        assert_eq!(one_period, 2, "{shifts:?}");
        let one = period_shifts(&row_of_boxes(1));
        assert!(one.is_empty(), "{one:?}");
        let two = period_shifts(&row_of_boxes(2));
        assert!(two.is_empty(), "{two:?}");
    }
}
