//! Fixed correspondences: source[i] ↔ target[i], residual T·a_i − b_i (the paper's
//! simulation, §6). The rows are built once and refilled at each transform.

use nalgebra::Matrix4;

use super::{
    Problem, RowScales, Rows, StepPoints, noise_scale, probe_points_of, rms_displacement, typical_magnitude,
};
use crate::geometry::{Solve, transform_point, weighted_rigid_fit};
use crate::point::Point;
use crate::registration::covariance::{InformationSum, PoseUncertainty, RowWeight};

/// Matched pairs: source[i] ↔ target[i], residual T·a_i − b_i (the paper's simulation, §6).
pub(crate) struct CorrespondenceProblem<'a> {
    source: &'a [Point],
    probe: Vec<Point>,
    pairs: Vec<(Point, Point)>,
    rows: Rows,
}

impl<'a> CorrespondenceProblem<'a> {
    pub(crate) fn new(
        source: &'a [Point],
        target: &'a [Point],
        source_sigma: Option<Vec<f64>>,
        target_sigma: Option<Vec<f64>>,
    ) -> Self {
        let n = source.len();
        let rows = Rows {
            count: n,
            source: (0..n as u32).collect(),
            target: (0..n as u32).collect(),
            residual: vec![0.0; 3 * n],
            scale: RowScales::PerRow(
                (0..n)
                    .map(|i| noise_scale(&source_sigma, &target_sigma, i, i))
                    .collect(),
            ),
            considered: n,
        };
        CorrespondenceProblem {
            source,
            probe: probe_points_of(source),
            pairs: source.iter().copied().zip(target.iter().copied()).collect(),
            rows,
        }
    }
}

impl Problem for CorrespondenceProblem<'_> {
    fn rematches(&self) -> bool {
        false
    }

    fn steps_on_subset(&self, _points: StepPoints) -> bool {
        false
    }

    fn cols(&self) -> usize {
        3
    }

    fn source_count(&self) -> usize {
        self.source.len()
    }

    fn probe_points(&self) -> &[Point] {
        &self.probe
    }

    fn coordinate_magnitude(&self) -> f64 {
        typical_magnitude(self.source)
    }

    fn source_anchor(&self) -> Point {
        crate::geometry::median_point(self.source)
    }

    fn linearise(&mut self, transform: &Matrix4<f64>, _points: StepPoints) -> &Rows {
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
        rms_displacement(self.source.len(), |i| self.source[i], &self.rows.scale, old, new)
    }

    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.linearise(transform, StepPoints::Sample)
    }

    /// Fixed correspondences: each row alone (no cells), its residual follows its point (N = I,
    /// s = 1).
    fn pose_uncertainty(
        &self,
        transform: &Matrix4<f64>,
        probabilities: &[f64],
        weight: &RowWeight,
    ) -> PoseUncertainty {
        let mut sum = InformationSum::about(transform_point(transform, &self.source_anchor()), 0.0);
        for (i, ((a, _), residual)) in self
            .pairs
            .iter()
            .zip(self.rows.residual.chunks_exact(3))
            .enumerate()
        {
            let p = transform_point(transform, a);
            sum.add_point(
                &p,
                None,
                residual,
                self.rows.scale.get(i),
                probabilities[i],
                Some(weight),
            );
        }
        sum.finish(1.0)
    }
}
