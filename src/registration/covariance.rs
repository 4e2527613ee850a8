//! The uncertainty of the final pose. With the pose perturbed on the left, T = Exp(δ)·T̂ and
//! δ = (ω, v) (rotation vector first, then translation, both in the target frame), a row's
//! residual r_i moves by J_i·δ: point-to-point J_i = [−[p_i]×  I], point-to-plane
//! J_i = [(p_i × n_i)ᵀ  n_iᵀ], with p_i the moved source point. The final inlier probabilities
//! P_i weight the rows, as they weight SIE's last least-squares step:
//!
//!   H = Σ P_i J_iᵀ J_i / F_i²,   σ̂² = Σ P_i ‖r_i / F_i‖² / (m·Σ P_i − 6),   Cov(δ) = σ̂² H⁻¹,
//!
//! the weighted least-squares covariance with the inliers' variance measured from their
//! residuals (so it holds whatever the fitted shape p). Directions the inliers leave free
//! (a plane, a corridor) have an eigenvalue of H near 0; they get the variance of an
//! eigenvalue [`FREE_EIGENVALUE_RATIO`] times the largest, far above every constrained one, and
//! the information matrix H/σ̂² keeps them near 0.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};

use crate::point::Point;

/// Fewer cells than this cannot estimate the sandwich's B (6 × 6) with any stability.
const MIN_CELLS: usize = 30;

/// An eigenvalue of H below this fraction of the largest is a direction the data leave free.
pub(crate) const FREE_EIGENVALUE_RATIO: f64 = 1e-12;

/// The pose's covariance and information (rotation first), in the target frame's units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseUncertainty {
    /// Cov(δ), 6 × 6: rad², rad·length, length².
    pub covariance: Matrix6<f64>,
    /// H / σ̂², the inverse of `covariance` where the data constrain the pose (near 0 in the
    /// directions they leave free).
    pub information: Matrix6<f64>,
}

impl PoseUncertainty {
    /// No uncertainty known (no rows, or a baseline run without inliers): zero matrices.
    pub const UNKNOWN: PoseUncertainty = PoseUncertainty {
        covariance: Matrix6::new(
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ),
        information: Matrix6::new(
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ),
    };

    /// The same uncertainty for points p' = length·p + centre (a change of units back to the
    /// caller's): ω is unchanged, v' = length·v + [centre]×·ω.
    pub(crate) fn in_frame(&self, length: f64, centre: &Vector3<f64>) -> PoseUncertainty {
        let map = perturbation_map(length, centre);
        PoseUncertainty {
            covariance: map * self.covariance * map.transpose(),
            information: match map.try_inverse() {
                Some(inverse) => inverse.transpose() * self.information * inverse,
                None => self.information,
            },
        }
    }
}

/// δ' = A·δ for p' = length·p + centre: rows (ω; length·v + centre × ω).
fn perturbation_map(length: f64, centre: &Vector3<f64>) -> Matrix6<f64> {
    let mut map = Matrix6::identity();
    map.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(Matrix3::identity() * length));
    map.fixed_view_mut::<3, 3>(3, 0).copy_from(&centre.cross_matrix());
    map
}

/// Σ P_i J_iᵀ J_i / F_i² and the weighted squared residuals, about `centre` (a point near the
/// moved source points, so the sums do not cancel far from the origin).
pub(crate) struct InformationSum {
    centre: Vector3<f64>,
    hessian: Matrix6<f64>,
    squared_residuals: f64,
    weight: f64,
    residuals: usize,
    /// Side of the cells whose rows' errors are taken as correlated (0: each point alone).
    cell: f64,
    /// Σ P_i J_iᵀ r_i / F_i² per cell (the score of the cell's rows); ordered, so that the
    /// sum over cells is the same bits in every run (a hash map's order is random).
    scores: BTreeMap<[i64; 3], Vector6<f64>>,
    /// The score of the point being added (point-to-point adds three rows).
    point_score: Vector6<f64>,
}

impl InformationSum {
    /// Sums about `centre`; rows whose moved source points share a cube of side `cell` are
    /// taken as correlated (they lean on the same target points and normals), 0 for none.
    pub(crate) fn about(centre: Point, cell: f64) -> Self {
        InformationSum {
            centre: Vector3::from(centre),
            hessian: Matrix6::zeros(),
            squared_residuals: 0.0,
            weight: 0.0,
            residuals: 0,
            cell,
            scores: BTreeMap::new(),
            point_score: Vector6::zeros(),
        }
    }

    fn cell_of(&self, p: &Point, serial: usize) -> [i64; 3] {
        if self.cell > 0.0 && self.cell.is_finite() {
            p.map(|c| (c / self.cell).floor() as i64)
        } else {
            [serial as i64, 0, 0]
        }
    }

    fn close_point(&mut self, p: &Point) {
        let key = self.cell_of(p, self.scores.len() + self.residuals);
        *self.scores.entry(key).or_insert_with(Vector6::zeros) += self.point_score;
        self.point_score = Vector6::zeros();
    }

    /// A point-to-point row: moved source point `p`, residual p − q, noise scale `scale`.
    pub(crate) fn add_point(&mut self, p: &Point, residual: &[f64], scale: f64, probability: f64) {
        let arm = Vector3::from(*p) - self.centre;
        let skew = -arm.cross_matrix();
        for axis in 0..3 {
            let mut jac = [0.0; 6];
            for c in 0..3 {
                jac[c] = skew[(axis, c)];
            }
            jac[3 + axis] = 1.0;
            self.add_row(&jac, residual[axis], scale, probability);
        }
        self.close_point(p);
    }

    /// A point-to-plane row: moved source point `p`, normal `n`, residual nᵀ(p − q).
    pub(crate) fn add_plane(&mut self, p: &Point, n: &Point, residual: f64, scale: f64, probability: f64) {
        let normal = Vector3::from(*n);
        let rot = (Vector3::from(*p) - self.centre).cross(&normal);
        let jac = [rot.x, rot.y, rot.z, normal.x, normal.y, normal.z];
        self.add_row(&jac, residual, scale, probability);
        self.close_point(p);
    }

    fn add_row(&mut self, jac: &[f64; 6], residual: f64, scale: f64, probability: f64) {
        let normalised = residual / scale;
        if !(probability > 0.0 && normalised.is_finite() && jac.iter().all(|v| v.is_finite())) {
            return;
        }
        let w = probability / (scale * scale);
        for r in 0..6 {
            for c in 0..6 {
                self.hessian[(r, c)] += w * jac[r] * jac[c];
            }
        }
        self.point_score += Vector6::from(*jac) * (w * residual);
        self.squared_residuals += probability * normalised * normalised;
        self.weight += probability;
        self.residuals += 1;
    }

    /// The uncertainty about the frame's origin; [`PoseUncertainty::UNKNOWN`] without enough
    /// weighted residuals to measure a variance (fewer than seven).
    pub(crate) fn finish(&self) -> PoseUncertainty {
        let dof = self.weight - 6.0;
        if dof.is_nan() || dof <= 0.0 || self.residuals < 7 || !self.hessian.iter().all(|v| v.is_finite()) {
            return PoseUncertainty::UNKNOWN;
        }
        let variance = self.squared_residuals / dof;
        let eigen = SymmetricEigen::new(self.hessian);
        let largest = eigen.eigenvalues.max();
        if !(largest > 0.0 && largest.is_finite() && variance.is_finite()) {
            return PoseUncertainty::UNKNOWN;
        }
        let floor = FREE_EIGENVALUE_RATIO * largest;
        // Cov = H⁺·B·H⁺ with B = Σ_cells s_c·s_cᵀ (the cluster-robust sandwich: correlated rows
        // in a cell add their errors before squaring), and σ̂²/floor in the free directions.
        let mut scores = Matrix6::zeros();
        if self.scores.len() >= MIN_CELLS {
            for s in self.scores.values() {
                scores += s * s.transpose();
            }
        } else {
            // Too few cells to estimate B: the model's σ̂²·H.
            scores = self.hessian * variance;
        }
        let mut pseudo_inverse = Matrix6::zeros();
        let mut free = Matrix6::zeros();
        for k in 0..6 {
            let direction = eigen.eigenvectors.column(k);
            let outer = direction * direction.transpose();
            let lambda = eigen.eigenvalues[k];
            if lambda > floor {
                pseudo_inverse += outer / lambda;
            } else {
                free += outer * (variance / floor);
            }
        }
        let covariance = pseudo_inverse * scores * pseudo_inverse + free;
        let information = match covariance.try_inverse() {
            Some(inverse) if inverse.iter().all(|v| v.is_finite()) => (inverse + inverse.transpose()) * 0.5,
            _ => return PoseUncertainty::UNKNOWN,
        };
        let about_centre = PoseUncertainty {
            covariance,
            information,
        };
        about_centre.in_frame(1.0, &self.centre)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Changing frames and back gives the same matrices.
    #[test]
    fn frames_round_trip() {
        let mut sum = InformationSum::about([1.0, 2.0, 3.0], 0.0);
        for k in 0..40 {
            let x = k as f64;
            let p = [
                1.0 + (x * 0.37).sin(),
                2.0 + (x * 0.91).cos(),
                3.0 + (x * 0.13).sin(),
            ];
            let r = [
                0.01 * (x * 1.7).sin(),
                -0.02 * (x * 0.3).cos(),
                0.005 * (x * 2.9).sin(),
            ];
            sum.add_point(&p, &r, 1.0, 1.0);
        }
        let u = sum.finish();
        let centre = Vector3::new(-4.0, 7.0, 0.5);
        let back = u.in_frame(3.0, &centre).in_frame(1.0 / 3.0, &(-centre / 3.0));
        assert!((back.covariance - u.covariance).abs().max() <= 1e-9 * u.covariance.abs().max());
        // Information is the inverse of covariance where everything is constrained.
        let product = u.covariance * u.information;
        assert!((product - Matrix6::identity()).abs().max() < 1e-6, "{product}");
    }

    /// Points on one plane, point-to-plane: translation within the plane and rotation about
    /// its normal are free, and get variances far above the constrained directions'.
    #[test]
    fn a_plane_leaves_three_directions_free() {
        let mut sum = InformationSum::about([0.0; 3], 0.0);
        for i in 0..20 {
            for j in 0..20 {
                let p = [i as f64 * 0.1, j as f64 * 0.1, 0.0];
                let r = 0.01 * (((i * 7 + j * 3) % 5) as f64 - 2.0);
                sum.add_plane(&p, &[0.0, 0.0, 1.0], r, 1.0, 1.0);
            }
        }
        let u = sum.finish();
        let variance = |k: usize| u.covariance[(k, k)];
        // Constrained: rotation about x and y, translation along z. Free: the rest.
        let constrained = variance(0).max(variance(1)).max(variance(5));
        for free in [2, 3, 4] {
            assert!(variance(free) > 1e6 * constrained, "{free}: {}", variance(free));
        }
        assert!(u.information[(3, 3)].abs() < 1e-9 * u.information[(5, 5)]);
    }

    /// Too few residuals to measure a variance: unknown, never NaN.
    #[test]
    fn too_few_rows_are_unknown() {
        let mut sum = InformationSum::about([0.0; 3], 0.0);
        sum.add_point(&[1.0, 0.0, 0.0], &[0.1, 0.0, 0.0], 1.0, 1.0);
        sum.add_plane(&[0.0, 1.0, 0.0], &[f64::NAN, 0.0, 1.0], 0.1, 1.0, 1.0);
        assert_eq!(sum.finish(), PoseUncertainty::UNKNOWN);
    }
}
