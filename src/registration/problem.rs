//! The two registration problems the IRLS driver solves: fixed correspondences and ICP.
//! Each produces residual rows at a transform and solves the weighted step; buffers are reused
//! across iterations (no per-correspondence allocation per iteration).
use nalgebra::Matrix4;
use rand::SeedableRng;

use super::{Metric, Point, RegistrationConfig};
use crate::geometry::{Solve, point_to_plane_step, transform_point, weighted_rigid_fit};
use crate::nn::NearestNeighbours;
use crate::noise::combine;
use crate::normals::estimate_normals;
use crate::parallel::Workers;

/// Residual rows of one iteration.
#[derive(Default)]
pub struct Rows {
    /// Source point of each row.
    pub source: Vec<u32>,
    /// Matched target point of each row.
    pub target: Vec<u32>,
    /// Residuals, rows × cols, input units.
    pub residual: Vec<f64>,
    /// Noise scale F of each row (§4.4); 1 with constant noise.
    pub scale: Vec<f64>,
}

impl Rows {
    pub fn len(&self) -> usize {
        self.source.len()
    }

    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }

    fn clear(&mut self) {
        self.source.clear();
        self.target.clear();
        self.residual.clear();
        self.scale.clear();
    }
}

pub trait Problem {
    /// Residual dimensions m.
    fn cols(&self) -> usize;
    fn source_count(&self) -> usize;
    /// Centroid of the source points (where update sizes are measured).
    fn source_centroid(&self) -> Point;
    /// (Re)matches at `transform` and fills the rows used for fitting.
    fn linearise(&mut self, transform: &Matrix4<f64>) -> &Rows;
    /// The rows of the last `linearise`.
    fn rows(&self) -> &Rows;
    /// Weighted least-squares step from `transform` with one weight per row.
    fn solve(&mut self, transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve>;
    /// RMS over the rows of ‖(new − old)·a_i‖ / F_i: how far the update moved the data,
    /// in the normalised units σ is measured in.
    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64;
    /// Rows for every source point (no sampling) at `transform`, for the reported results.
    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows;
}

fn noise_scale(source_sigma: &Option<Vec<f64>>, target_sigma: &Option<Vec<f64>>, s: usize, t: usize) -> f64 {
    match (source_sigma, target_sigma) {
        (Some(a), Some(b)) => combine(a[s], b[t]),
        _ => 1.0,
    }
}

fn rms_displacement(rows: &Rows, source: &[Point], old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64 {
    if rows.is_empty() {
        return 0.0;
    }
    let difference = new - old;
    let sum: f64 = rows
        .source
        .iter()
        .zip(&rows.scale)
        .map(|(&s, f)| {
            let d = transform_point(&difference, &source[s as usize]);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) / (f * f)
        })
        .sum();
    (sum / rows.len() as f64).sqrt()
}

/// Matched pairs: source[i] ↔ target[i], residual T·a_i − b_i (the paper's simulation, §6).
pub struct CorrespondenceProblem<'a> {
    source: &'a [Point],
    pairs: Vec<(Point, Point)>,
    rows: Rows,
}

impl<'a> CorrespondenceProblem<'a> {
    pub fn new(
        source: &'a [Point],
        target: &'a [Point],
        source_sigma: Option<Vec<f64>>,
        target_sigma: Option<Vec<f64>>,
    ) -> Self {
        let n = source.len();
        let rows = Rows {
            source: (0..n as u32).collect(),
            target: (0..n as u32).collect(),
            residual: vec![0.0; 3 * n],
            scale: (0..n)
                .map(|i| noise_scale(&source_sigma, &target_sigma, i, i))
                .collect(),
        };
        CorrespondenceProblem {
            source,
            pairs: source.iter().copied().zip(target.iter().copied()).collect(),
            rows,
        }
    }
}

impl Problem for CorrespondenceProblem<'_> {
    fn cols(&self) -> usize {
        3
    }

    fn source_count(&self) -> usize {
        self.source.len()
    }

    fn source_centroid(&self) -> Point {
        crate::geometry::centroid(self.source)
    }

    fn linearise(&mut self, transform: &Matrix4<f64>) -> &Rows {
        for ((a, b), r) in self.pairs.iter().zip(self.rows.residual.chunks_exact_mut(3)) {
            let p = transform_point(transform, a);
            r.copy_from_slice(&[p[0] - b[0], p[1] - b[1], p[2] - b[2]]);
        }
        &self.rows
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn solve(&mut self, _transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve> {
        weighted_rigid_fit(&self.pairs, weights)
    }

    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64 {
        rms_displacement(&self.rows, self.source, old, new)
    }

    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.linearise(transform)
    }
}

/// A nearest-neighbour match of one source point: target index (u32::MAX = none) and the
/// transformed source point.
#[derive(Clone, Copy)]
struct Match {
    target: u32,
    point: Point,
}

const NO_MATCH: u32 = u32::MAX;

/// ICP: nearest-neighbour correspondences from a kd-tree built once per target.
pub struct CloudProblem<'a> {
    source: &'a [Point],
    target: &'a [Point],
    normals: Vec<Point>,
    metric: Metric,
    index: NearestNeighbours,
    /// Source points matched in each iteration (all, or a fixed random subset).
    sample: Vec<u32>,
    source_sigma: Option<Vec<f64>>,
    target_sigma: Option<Vec<f64>>,
    workers: Workers,
    matches: Vec<Match>,
    rows: Rows,
    /// Transformed source point of each row (point-to-plane linearisation).
    row_points: Vec<Point>,
    pairs: Vec<(Point, Point)>,
    plane_terms: Vec<(Point, Point, Point)>,
}

impl<'a> CloudProblem<'a> {
    pub fn new(
        source: &'a [Point],
        target: &'a [Point],
        target_normals: Option<&[Point]>,
        source_sigma: Option<Vec<f64>>,
        target_sigma: Option<Vec<f64>>,
        config: &RegistrationConfig,
        workers: Workers,
    ) -> Result<Self, String> {
        if source.len() >= NO_MATCH as usize {
            return Err(format!(
                "source has {} points; at most {} are supported",
                source.len(),
                NO_MATCH - 1
            ));
        }
        let index = NearestNeighbours::new(target)?;
        let normals = match (config.metric, target_normals) {
            (Metric::PointToPoint, _) => Vec::new(),
            (Metric::PointToPlane, Some(given)) => given.to_vec(),
            (Metric::PointToPlane, None) => estimate_normals(
                target,
                &index,
                config.normal_neighbours.min(target.len()),
                &workers,
            ),
        };
        let sample = sample_indices(source.len(), config.max_correspondences, config.seed);
        Ok(CloudProblem {
            source,
            target,
            normals,
            metric: config.metric,
            index,
            sample,
            source_sigma,
            target_sigma,
            workers,
            matches: Vec::new(),
            rows: Rows::default(),
            row_points: Vec::new(),
            pairs: Vec::new(),
            plane_terms: Vec::new(),
        })
    }

    /// Matches `indices` (or every source point) at `transform` and fills the rows.
    fn match_and_fill(&mut self, transform: &Matrix4<f64>, all: bool) {
        let count = if all { self.source.len() } else { self.sample.len() };
        self.matches.resize(
            count,
            Match {
                target: NO_MATCH,
                point: [0.0; 3],
            },
        );
        let (source, sample, index, normals) = (self.source, &self.sample, &self.index, &self.normals);
        let plane = self.metric == Metric::PointToPlane;
        self.workers
            .for_each_chunk_mut(&mut self.matches, |start, chunk| {
                for (k, slot) in chunk.iter_mut().enumerate() {
                    let s = if all {
                        start + k
                    } else {
                        sample[start + k] as usize
                    };
                    let point = transform_point(transform, &source[s]);
                    let (t, _) = index.nearest_one(&point);
                    // A target point without a normal (degenerate neighbourhood) gives no plane.
                    let usable = !plane || normals[t] != [0.0; 3];
                    *slot = Match {
                        target: if usable { t as u32 } else { NO_MATCH },
                        point,
                    };
                }
            });
        let rows = &mut self.rows;
        rows.clear();
        self.row_points.clear();
        for (k, m) in self.matches.iter().enumerate() {
            if m.target == NO_MATCH {
                continue;
            }
            let s = if all { k } else { sample[k] as usize };
            let t = m.target as usize;
            let q = self.target[t];
            let d = [m.point[0] - q[0], m.point[1] - q[1], m.point[2] - q[2]];
            rows.source.push(s as u32);
            rows.target.push(m.target);
            if plane {
                let n = normals[t];
                rows.residual.push(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]);
            } else {
                rows.residual.extend_from_slice(&d);
            }
            rows.scale
                .push(noise_scale(&self.source_sigma, &self.target_sigma, s, t));
            self.row_points.push(m.point);
        }
    }
}

/// A fixed, sorted random subset of `limit` source indices (all when `limit` is 0 or ≥ n), so
/// every iteration sees the same correspondences' sources.
fn sample_indices(n: usize, limit: usize, seed: u64) -> Vec<u32> {
    if limit == 0 || limit >= n {
        return (0..n as u32).collect();
    }
    let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut chosen: Vec<u32> = rand::seq::index::sample(&mut rng, n, limit)
        .into_iter()
        .map(|i| i as u32)
        .collect();
    chosen.sort_unstable();
    chosen
}

impl Problem for CloudProblem<'_> {
    fn cols(&self) -> usize {
        match self.metric {
            Metric::PointToPoint => 3,
            Metric::PointToPlane => 1,
        }
    }

    fn source_count(&self) -> usize {
        self.source.len()
    }

    fn source_centroid(&self) -> Point {
        crate::geometry::centroid(self.source)
    }

    fn linearise(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.match_and_fill(transform, false);
        &self.rows
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn solve(&mut self, transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve> {
        let rows = &self.rows;
        match self.metric {
            Metric::PointToPoint => {
                self.pairs.clear();
                self.pairs.extend(
                    rows.source
                        .iter()
                        .zip(&rows.target)
                        .map(|(&s, &t)| (self.source[s as usize], self.target[t as usize])),
                );
                weighted_rigid_fit(&self.pairs, weights)
            }
            Metric::PointToPlane => {
                self.plane_terms.clear();
                self.plane_terms.extend(
                    rows.target
                        .iter()
                        .zip(&self.row_points)
                        .map(|(&t, p)| (*p, self.target[t as usize], self.normals[t as usize])),
                );
                point_to_plane_step(transform, &self.plane_terms, weights)
            }
        }
    }

    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64 {
        rms_displacement(&self.rows, self.source, old, new)
    }

    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.match_and_fill(transform, true);
        &self.rows
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampling_is_deterministic_sorted_and_bounded() {
        let a = sample_indices(1000, 100, 42);
        assert_eq!(a, sample_indices(1000, 100, 42));
        assert_eq!(a.len(), 100);
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(sample_indices(10, 0, 1).len(), 10);
        assert_eq!(sample_indices(10, 50, 1).len(), 10);
    }
}
