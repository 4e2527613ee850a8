//! Fast Point Feature Histograms (Rusu, Blodow, Beetz, "Fast Point Feature Histograms (FPFH)
//! for 3D Registration", ICRA 2009), with Open3D's conventions so that the values can be checked
//! against `open3d.pipelines.registration.compute_fpfh_feature` (tests/fpfh_open3d.rs):
//!
//! * a pair (p, n), (q, m) gives three angles in the Darboux frame of the point whose normal is
//!   closer to the line between them: α = atan2(w·m', u·m') … (here f0), φ = v·m' (f1) and
//!   θ = u·(q − p)/|q − p| (f2), each binned into 11 equal bins of its range;
//! * a point's SPFH adds 100 / (neighbours) per neighbour to each of the three 11-bin parts;
//! * its FPFH is its neighbours' SPFH weighted by 1 / squared distance, each part normalised to
//!   100, plus its own SPFH (Open3D's weighting; the paper weighs by the distance).
//!
//! Neighbourhoods are Open3D's hybrid search: the `max_neighbours` nearest points (the point
//! itself counted) within `radius`.

use crate::geometry::{cross, dot, length};
use crate::nn::NearestNeighbours;
use crate::parallel::Workers;
use crate::point::Point;

/// Bins of one FPFH: three angles × 11 bins.
pub const FPFH_BINS: usize = 33;
/// Bins per angle.
const ANGLE_BINS: usize = 11;
/// One point's descriptor.
pub type Fpfh = [f64; FPFH_BINS];

/// Points per parallel chunk: each costs up to ~100 neighbour pairs.
const CHUNK: usize = 64;

/// The FPFH of every point of `points` (with unit `normals`, one per point), from the
/// neighbours `index` (built on `points`) finds within `radius`, at most `max_neighbours` of
/// them counting the point itself. A point without neighbours gets all zeros.
pub fn fpfh(
    points: &[Point],
    normals: &[Point],
    index: &NearestNeighbours,
    radius: f64,
    max_neighbours: usize,
    workers: &Workers,
) -> Vec<Fpfh> {
    let neighbourhoods = Neighbourhoods::find(points, index, radius, max_neighbours, workers);
    let mut simplified = vec![[0.0; FPFH_BINS]; points.len()];
    workers.for_each_chunk_of(CHUNK, &mut simplified, |first, piece| {
        for (offset, histogram) in piece.iter_mut().enumerate() {
            let i = first + offset;
            *histogram = spfh(points, normals, i, neighbourhoods.of(i));
        }
    });
    let mut features = vec![[0.0; FPFH_BINS]; points.len()];
    workers.for_each_chunk_of(CHUNK, &mut features, |first, piece| {
        for (offset, feature) in piece.iter_mut().enumerate() {
            let i = first + offset;
            *feature = weighted_sum(&simplified, i, &neighbourhoods, i);
        }
    });
    features
}

/// Each point's neighbours (the point itself left out) with their squared distances.
struct Neighbourhoods {
    /// Neighbours of point i: `members[offsets[i]..offsets[i + 1]]`.
    offsets: Vec<usize>,
    members: Vec<(u32, f64)>,
}

impl Neighbourhoods {
    fn find(
        points: &[Point],
        index: &NearestNeighbours,
        radius: f64,
        max_neighbours: usize,
        workers: &Workers,
    ) -> Self {
        let squared_radius = radius * radius;
        let mut lists: Vec<Vec<(u32, f64)>> = vec![Vec::new(); points.len()];
        workers.for_each_chunk_of(CHUNK, &mut lists, |first, piece| {
            let mut nearest = Vec::new();
            for (offset, list) in piece.iter_mut().enumerate() {
                let i = first + offset;
                index.nearest_k(&points[i], max_neighbours, &mut nearest);
                list.extend(nearest.iter().filter(|&&j| j != i).filter_map(|&j| {
                    let d = squared_distance(&points[i], &points[j]);
                    (d <= squared_radius).then_some((j as u32, d))
                }));
            }
        });
        let mut offsets = Vec::with_capacity(points.len() + 1);
        offsets.push(0);
        for list in &lists {
            offsets.push(offsets.last().copied().unwrap_or(0) + list.len());
        }
        Neighbourhoods {
            offsets,
            members: lists.into_iter().flatten().collect(),
        }
    }

    fn of(&self, i: usize) -> &[(u32, f64)] {
        &self.members[self.offsets[i]..self.offsets[i + 1]]
    }
}

fn squared_distance(a: &Point, b: &Point) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// The simplified histogram of point i over its neighbours.
fn spfh(points: &[Point], normals: &[Point], i: usize, neighbours: &[(u32, f64)]) -> Fpfh {
    let mut histogram = [0.0; FPFH_BINS];
    if neighbours.is_empty() {
        return histogram;
    }
    let increment = 100.0 / neighbours.len() as f64;
    for &(j, _) in neighbours {
        let j = j as usize;
        let [f0, f1, f2] = pair_angles(&points[i], &normals[i], &points[j], &normals[j]);
        histogram[bin(f0, -std::f64::consts::PI, std::f64::consts::PI)] += increment;
        histogram[ANGLE_BINS + bin(f1, -1.0, 1.0)] += increment;
        histogram[2 * ANGLE_BINS + bin(f2, -1.0, 1.0)] += increment;
    }
    histogram
}

/// The bin of `value` among 11 equal bins of [lo, hi], values outside clamped to the ends.
fn bin(value: f64, lo: f64, hi: f64) -> usize {
    let position = (ANGLE_BINS as f64 * (value - lo) / (hi - lo)).floor();
    position.clamp(0.0, (ANGLE_BINS - 1) as f64) as usize
}

/// The three angles of a pair of oriented points, in the Darboux frame (u, v, w) of the one
/// whose normal makes the smaller angle with the line joining them. Coincident points, or a
/// normal along the line, give zeros.
fn pair_angles(p: &Point, n: &Point, q: &Point, m: &Point) -> [f64; 3] {
    let mut d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
    let distance = length(&d);
    if distance == 0.0 {
        return [0.0; 3];
    }
    let cos_p = dot(n, &d) / distance;
    let cos_q = dot(m, &d) / distance;
    // The frame sits on the point whose normal is closer to the joining line.
    let (u, other, theta) = if cos_p.abs().acos() > cos_q.abs().acos() {
        d = d.map(|c| -c);
        (*m, *n, -cos_q)
    } else {
        (*n, *m, cos_p)
    };
    let v = cross(&d, &u);
    let v_length = length(&v);
    if v_length == 0.0 {
        return [0.0; 3];
    }
    let v = v.map(|c| c / v_length);
    let w = cross(&u, &v);
    let phi = dot(&v, &other);
    let alpha = dot(&w, &other).atan2(dot(&u, &other));
    [alpha, phi, theta]
}

/// Point i's FPFH: its neighbours' SPFH weighted by 1 / squared distance, each angle's part
/// normalised to 100, plus its own SPFH.
fn weighted_sum(simplified: &[Fpfh], i: usize, neighbourhoods: &Neighbourhoods, own: usize) -> Fpfh {
    let mut feature = [0.0; FPFH_BINS];
    let neighbours = neighbourhoods.of(i);
    if neighbours.is_empty() {
        return feature;
    }
    let mut sums = [0.0; 3];
    for &(j, squared) in neighbours {
        // Open3D leaves out a neighbour at the point's own place.
        if squared == 0.0 {
            continue;
        }
        for (b, value) in simplified[j as usize].iter().enumerate() {
            let weighted = value / squared;
            sums[b / ANGLE_BINS] += weighted;
            feature[b] += weighted;
        }
    }
    for (b, value) in feature.iter_mut().enumerate() {
        let sum = sums[b / ANGLE_BINS];
        if sum != 0.0 {
            *value *= 100.0 / sum;
        }
        *value += simplified[own][b];
    }
    feature
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_clamp_and_split_evenly() {
        assert_eq!(bin(-1.0, -1.0, 1.0), 0);
        assert_eq!(bin(1.0, -1.0, 1.0), 10);
        assert_eq!(bin(0.0, -1.0, 1.0), 5);
        assert_eq!(bin(7.0, -1.0, 1.0), 10);
    }

    #[test]
    fn pair_angles_are_those_of_the_darboux_frame() {
        // Two points on the x axis, normals along z and turned 90° about x towards -y.
        let angles = pair_angles(&[0.0; 3], &[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0], &[0.0, -1.0, 0.0]);
        // u = z, v = x × z = -y, w = u × v = x: φ = v·m = 1, α = atan2(w·m, u·m) = 0, θ = 0.
        assert_eq!(angles, [0.0, 1.0, 0.0]);
        assert_eq!(
            pair_angles(&[1.0; 3], &[0.0, 0.0, 1.0], &[1.0; 3], &[0.0, 0.0, 1.0]),
            [0.0; 3]
        );
    }

    #[test]
    fn every_part_sums_to_two_hundred_with_neighbours() {
        let points: Vec<Point> = (0..200)
            .map(|k| {
                let (x, y) = ((k % 20) as f64 * 0.1, (k / 20) as f64 * 0.1);
                [x, y, (x * 3.0).sin() * 0.2 + y * y * 0.1]
            })
            .collect();
        let normals = vec![[0.0, 0.0, 1.0]; points.len()];
        let index = NearestNeighbours::new(&points).unwrap();
        let workers = Workers::new(2).unwrap();
        for feature in fpfh(&points, &normals, &index, 0.35, 100, &workers) {
            for part in feature.chunks(ANGLE_BINS) {
                let sum: f64 = part.iter().sum();
                assert!((sum - 200.0).abs() < 1e-9, "{sum}");
            }
        }
    }
}
