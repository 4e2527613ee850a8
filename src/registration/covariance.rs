//! The uncertainty of the final pose (docs/uncertainty.md has its calibration). With the pose
//! perturbed on the left, T = Exp(δ)·T̂ and δ = (ω, v) (rotation vector first, then
//! translation, both in the target frame), a row's residual r_i moves by J_i·δ: point-to-point
//! J_i = [−[p_i]×  I], point-to-plane J_i = [(p_i × n_i)ᵀ  n_iᵀ], with p_i the moved source
//! point.
//!
//! The result solves the weighted score equation Σ J_iᵀ ψ(u_i) / F_i = 0, with u_i = r_i / F_i
//! and ψ(u) = P(u)·u the residual weighted by the final model's inlier probability (as SIE's
//! last least-squares step weights it). To first order its error is δ = −G⁻¹·g, with g the
//! score at the true pose and G its response to the pose, so (the M-estimator's sandwich)
//!
//!   Cov(δ) = G⁻¹ B G⁻¹,   B = Σ_c g_c g_cᵀ,   G = s · Σ_i J_iᵀ W_i N_i J_i / F_i²,
//!
//! * B, the score's spread: g_c = Σ_{i in c} J_iᵀ ψ(u_i) / F_i summed over cells c of rows
//!   whose errors are correlated. ICP: rows whose matched target points share a cube of a few
//!   target spacings. They share those points' noise and their normals' neighbourhoods, and a
//!   part of the source beyond the target's edge is matched, all of it, to the edge's points:
//!   cells of the moved source points would cut those apart. Fixed correspondences: each row
//!   alone.
//! * W = ∂ψ/∂u: the weights change with the residuals. P falls off in the tails, so a
//!   residual that grows there pulls less than P·u would: W = P + u·P' < P, measured by a
//!   central difference of the final model's P ([`RowWeight`]).
//! * N, how a row's residual follows its point. Fixed correspondences: N = I. ICP matches
//!   again. Point-to-plane's residual follows the motion along its normal only (N = 1, the
//!   normal being in J). So does point-to-point's, whose point slides along the surface to a
//!   new nearest target: N = n·nᵀ with n the normal at its target, summed over the surfaces'
//!   weighted sample of rows (`degeneracy`), and W = P: its P depends on the tangential
//!   offsets the matching draws anew, hardly on the normal part the pose moves
//!   (docs/uncertainty.md has what the slope along n does there).
//! * s ≤ 1: a point moved off its surface by h changes its residual by s·h, not h, when the
//!   targets' noise is not small against their spacing: the nearest target is then one whose
//!   noise puts it nearer the point's side (s ≈ 1/(1 + 2πρσ²) for density ρ and noise σ).
//!   Measured by matching the sample again with its points moved along their normals; 1 for
//!   fixed correspondences.
//!
//! Directions the inliers leave free (a plane, a corridor) have an eigenvalue of G near 0;
//! they get the variance σ̂² of an eigenvalue [`FREE_EIGENVALUE_RATIO`] times the largest, far
//! above every constrained one, with σ̂² = Σ P_i ‖u_i‖² / (m·Σ P_i − 6) the inliers' variance,
//! and the information matrix (the covariance's inverse) keeps them near 0.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};

use crate::point::Point;

/// Fewer cells than this cannot estimate the sandwich's B (6 × 6) with any stability: it is
/// then the model's σ̂²·Σ P_i J_iᵀJ_i / F_i².
const MIN_CELLS: usize = 30;

/// An eigenvalue of G below this fraction of the largest is a direction the data leave free.
pub(crate) const FREE_EIGENVALUE_RATIO: f64 = 1e-12;

/// The final model's weighting of a row, and the step that measures its slope.
pub(crate) struct RowWeight<'a> {
    /// P(u) of a normalised residual row u (any values, not only the rows'), as the final
    /// probabilities give it.
    pub(crate) probability: &'a dyn Fn(&[f64]) -> f64,
    /// Half-width of the central differences of ψ(u) = P(u)·u (normalised units): a fraction of
    /// the inliers' spread, so that they span several of the model's histogram bins.
    pub(crate) step: f64,
}

impl RowWeight<'_> {
    /// ψ(u + t·d) = P·(u + t·d) for a row of up to three columns.
    fn weighted(&self, u: &[f64], d: &[f64], t: f64) -> [f64; 3] {
        let mut moved = [0.0; 3];
        for (k, m) in moved.iter_mut().enumerate().take(u.len()) {
            *m = u[k] + t * d[k];
        }
        let p = (self.probability)(&moved[..u.len()]);
        moved.map(|c| p * c)
    }

    /// (∂ψ/∂u)·d, the change of ψ along the unit direction `d`, by a central difference;
    /// P(u)·d when there is no step to take (all residuals 0).
    fn slope_along(&self, u: &[f64], d: &[f64]) -> [f64; 3] {
        let h = self.step;
        if !(h > 0.0 && h.is_finite()) {
            let p = (self.probability)(u);
            let mut along = [0.0; 3];
            for (k, a) in along.iter_mut().enumerate().take(u.len()) {
                *a = p * d[k];
            }
            return along;
        }
        let (plus, minus) = (self.weighted(u, d, h), self.weighted(u, d, -h));
        std::array::from_fn(|k| (plus[k] - minus[k]) / (2.0 * h))
    }

    /// dᵀ(∂ψ/∂u)d.
    fn slope(&self, u: &[f64], d: &[f64]) -> f64 {
        let along = self.slope_along(u, d);
        d.iter().zip(along).map(|(a, b)| a * b).sum()
    }
}

/// The pose's covariance and information (rotation first), in the target frame's units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseUncertainty {
    /// Cov(δ), 6 × 6: rad², rad·length, length².
    pub covariance: Matrix6<f64>,
    /// The inverse of `covariance` (near 0 in the directions the data leave free).
    pub information: Matrix6<f64>,
}

/// The 6 × 6 zero matrix (`Matrix6::zeros` is not a const fn).
const ZERO: Matrix6<f64> = Matrix6::new(
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
);

impl PoseUncertainty {
    /// No uncertainty known (no rows, or a baseline run without inliers): zero matrices.
    pub const UNKNOWN: PoseUncertainty = PoseUncertainty {
        covariance: ZERO,
        information: ZERO,
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

/// The sums of the sandwich (module documentation) about `centre`, a point near the moved source
/// points, so the sums do not cancel far from the origin.
pub(crate) struct InformationSum {
    centre: Vector3<f64>,
    /// Σ P_i J_iᵀJ_i / F_i²: the rows as fixed measurements of weight P_i.
    hessian: Matrix6<f64>,
    /// G before the matching's factor s.
    response: Matrix6<f64>,
    squared_residuals: f64,
    weight: f64,
    residuals: usize,
    /// Side of the cells whose rows' errors are taken as correlated (0: each row alone).
    cell: f64,
    /// g_c per cell; ordered, so that the sum over cells is the same bits in every run (a
    /// hash map's order is random).
    scores: BTreeMap<[i64; 3], Vector6<f64>>,
}

/// The 3 × 6 Jacobian [−[p]×  I] of a point-to-point row about `centre`.
fn point_jacobian(p: &Point, centre: &Vector3<f64>) -> nalgebra::Matrix3x6<f64> {
    let mut jac = nalgebra::Matrix3x6::zeros();
    jac.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&-(Vector3::from(*p) - centre).cross_matrix());
    jac.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
    jac
}

/// The 1 × 6 Jacobian [(p × n)ᵀ  nᵀ] of a point-to-plane row about `centre`.
fn plane_jacobian(p: &Point, n: &Point, centre: &Vector3<f64>) -> Vector6<f64> {
    let normal = Vector3::from(*n);
    let rot = (Vector3::from(*p) - centre).cross(&normal);
    Vector6::new(rot.x, rot.y, rot.z, normal.x, normal.y, normal.z)
}

impl InformationSum {
    /// Sums about `centre`; rows whose keys share a cube of side `cell` are taken as
    /// correlated, 0 for none.
    pub(crate) fn about(centre: Point, cell: f64) -> Self {
        InformationSum {
            centre: Vector3::from(centre),
            hessian: Matrix6::zeros(),
            response: Matrix6::zeros(),
            squared_residuals: 0.0,
            weight: 0.0,
            residuals: 0,
            cell,
            scores: BTreeMap::new(),
        }
    }

    /// The cell of `key` (a row of its own without one, or without cells).
    fn cell_of(&self, key: Option<&Point>) -> [i64; 3] {
        match key {
            Some(k) if self.cell > 0.0 && self.cell.is_finite() => k.map(|c| (c / self.cell).floor() as i64),
            _ => [(self.scores.len() + self.residuals) as i64, i64::MIN, 0],
        }
    }

    /// A point-to-point row: moved source point `p`, residual r = p − q, noise scale F, inlier
    /// probability P; `key` places it in a cell. With `weight`, its response to the pose as a
    /// fixed correspondence (N = I) joins G; ICP's point-to-point adds G from the surfaces
    /// instead ([`InformationSum::add_surface_response`]).
    pub(crate) fn add_point(
        &mut self,
        p: &Point,
        key: Option<&Point>,
        residual: &[f64],
        scale: f64,
        probability: f64,
        weight: Option<&RowWeight>,
    ) {
        let jac = point_jacobian(p, &self.centre);
        let r = Vector3::from_column_slice(residual);
        let u = r / scale;
        if !(probability > 0.0 && u.iter().all(|v| v.is_finite()) && jac.iter().all(|v| v.is_finite())) {
            return;
        }
        let f2 = scale * scale;
        self.hessian += jac.transpose() * jac * (probability / f2);
        if let Some(weight) = weight {
            let columns: [[f64; 3]; 3] = std::array::from_fn(|k| {
                let mut d = [0.0; 3];
                d[k] = 1.0;
                weight.slope_along(u.as_slice(), &d)
            });
            let slope = Matrix3::from_fn(|j, k| columns[k][j]);
            let symmetric = (slope + slope.transpose()) * 0.5;
            let term = jac.transpose() * symmetric * jac / f2;
            if term.iter().all(|v| v.is_finite()) {
                self.response += term;
            }
        }
        let cell = self.cell_of(key);
        *self.scores.entry(cell).or_insert_with(Vector6::zeros) += jac.transpose() * r * (probability / f2);
        self.squared_residuals += probability * u.norm_squared();
        self.weight += 3.0 * probability;
        self.residuals += 3;
    }

    /// A point-to-plane row: moved source point `p`, normal `n`, residual nᵀ(p − q), noise
    /// scale F, inlier probability P; `key` places it in a cell.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn add_plane(
        &mut self,
        p: &Point,
        n: &Point,
        key: Option<&Point>,
        residual: f64,
        scale: f64,
        probability: f64,
        weight: &RowWeight,
    ) {
        let jac = plane_jacobian(p, n, &self.centre);
        let u = residual / scale;
        if !(probability > 0.0 && u.is_finite() && jac.iter().all(|v| v.is_finite())) {
            return;
        }
        let f2 = scale * scale;
        let outer = jac * jac.transpose() / f2;
        self.hessian += outer * probability;
        let slope = weight.slope(&[u], &[1.0]);
        if slope.is_finite() {
            self.response += outer * slope;
        }
        let cell = self.cell_of(key);
        *self.scores.entry(cell).or_insert_with(Vector6::zeros) += jac * (probability * residual / f2);
        self.squared_residuals += probability * u * u;
        self.weight += probability;
        self.residuals += 1;
    }

    /// `factor`·Jᵀ·n·nᵀ·J for a point-to-point row at `p` on a surface of normal `n`: the part
    /// of G that the rows it stands for add (N = n·nᵀ), `factor` = their W / F² summed.
    pub(crate) fn add_surface_response(&mut self, p: &Point, n: &Point, factor: f64) {
        let row = plane_jacobian(p, n, &self.centre);
        let term = row * row.transpose() * factor;
        if term.iter().all(|v| v.is_finite()) {
            self.response += term;
        }
    }

    /// The uncertainty about the frame's origin, with the matching's response factor s
    /// (1 for fixed correspondences); [`PoseUncertainty::UNKNOWN`] without enough weighted
    /// residuals to measure a variance (fewer than seven).
    pub(crate) fn finish(&self, matching_response: f64) -> PoseUncertainty {
        let dof = self.weight - 6.0;
        if dof.is_nan() || dof <= 0.0 || self.residuals < 7 || !self.hessian.iter().all(|v| v.is_finite()) {
            return PoseUncertainty::UNKNOWN;
        }
        let variance = self.squared_residuals / dof;
        let bread = self.response * matching_response;
        if !bread.iter().all(|v| v.is_finite()) {
            return PoseUncertainty::UNKNOWN;
        }
        let eigen = SymmetricEigen::new((bread + bread.transpose()) * 0.5);
        let largest = eigen.eigenvalues.max();
        if !(largest > 0.0 && largest.is_finite() && variance.is_finite()) {
            return PoseUncertainty::UNKNOWN;
        }
        let floor = FREE_EIGENVALUE_RATIO * largest;
        let mut scores = Matrix6::zeros();
        if self.scores.len() >= MIN_CELLS {
            for s in self.scores.values() {
                scores += s * s.transpose();
            }
        } else {
            scores = self.hessian * variance;
        }
        let mut inverse = Matrix6::zeros();
        let mut free = Matrix6::zeros();
        for k in 0..6 {
            let direction = eigen.eigenvectors.column(k);
            let outer = direction * direction.transpose();
            let lambda = eigen.eigenvalues[k];
            if lambda > floor {
                inverse += outer / lambda;
            } else {
                free += outer * (variance / floor);
            }
        }
        let covariance = inverse * scores * inverse + free;
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

    /// Weights that do not change with the residual: W = P = 1.
    const CONSTANT: RowWeight = RowWeight {
        probability: &|_: &[f64]| 1.0,
        step: 0.01,
    };

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
            sum.add_point(&p, None, &r, 1.0, 1.0, Some(&CONSTANT));
        }
        let u = sum.finish(1.0);
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
                sum.add_plane(&p, &[0.0, 0.0, 1.0], None, r, 1.0, 1.0, &CONSTANT);
            }
        }
        let u = sum.finish(1.0);
        let variance = |k: usize| u.covariance[(k, k)];
        // Constrained: rotation about x and y, translation along z. Free: the rest.
        let constrained = variance(0).max(variance(1)).max(variance(5));
        for free in [2, 3, 4] {
            assert!(variance(free) > 1e6 * constrained, "{free}: {}", variance(free));
        }
        assert!(u.information[(3, 3)].abs() < 1e-9 * u.information[(5, 5)]);
    }

    /// W = ∂(P(u)·u)/∂u by the central difference: for the Cauchy weight P = 1/(1 + u²),
    /// (1 − u²)/(1 + u²)², below P and negative beyond u = 1.
    #[test]
    fn the_slope_of_the_weighted_residual_is_measured() {
        let cauchy = RowWeight {
            probability: &|u: &[f64]| 1.0 / (1.0 + u.iter().map(|v| v * v).sum::<f64>()),
            step: 1e-4,
        };
        for u in [0.0f64, 0.5, 1.0, 2.0, -3.0] {
            let expected = (1.0 - u * u) / (1.0 + u * u).powi(2);
            assert!((cauchy.slope(&[u], &[1.0]) - expected).abs() < 1e-6, "{u}");
        }
        // A row of three columns along a unit direction d: dᵀ(P·I + u·∇Pᵀ)d.
        let (u, d) = ([0.3, -0.4, 1.2], [0.6, 0.0, 0.8]);
        let q = 1.0 + u.iter().map(|v| v * v).sum::<f64>();
        let along: f64 = u.iter().zip(d).map(|(a, b)| a * b).sum();
        let expected = 1.0 / q - 2.0 * along * along / (q * q);
        assert!((cauchy.slope(&u, &d) - expected).abs() < 1e-6);
    }

    /// Rows in the tails of a falling weight respond less to the pose than their weights say
    /// (W < P): the same rows with the weights' slope get a larger covariance than with
    /// constant weights of the same value.
    #[test]
    fn falling_weights_widen_the_covariance() {
        let cauchy = RowWeight {
            probability: &|u: &[f64]| 1.0 / (1.0 + u[0] * u[0]),
            step: 1e-4,
        };
        let (mut sloped, mut flat) = (
            InformationSum::about([0.0; 3], 0.0),
            InformationSum::about([0.0; 3], 0.0),
        );
        for i in 0..200 {
            let x = i as f64;
            let p = [(x * 0.71).sin(), (x * 0.37).cos(), (x * 0.53).sin()];
            let n = Vector3::new((x * 1.3).cos(), (x * 0.7).sin(), 1.0).normalize();
            let r = 0.8 * (x * 2.1).sin();
            let probability = 1.0 / (1.0 + r * r);
            sloped.add_plane(&p, &n.into(), None, r, 1.0, probability, &cauchy);
            let same = RowWeight {
                probability: &|_: &[f64]| probability,
                step: 1e-4,
            };
            flat.add_plane(&p, &n.into(), None, r, 1.0, probability, &same);
        }
        let (wide, narrow) = (sloped.finish(1.0), flat.finish(1.0));
        for k in 0..6 {
            assert!(wide.covariance[(k, k)] > 1.2 * narrow.covariance[(k, k)], "{k}");
        }
    }

    /// Rows keyed to one cell add their scores before squaring: 50 pairs of equal rows, each
    /// pair in a cell of its own, have twice the covariance of the same rows taken alone.
    #[test]
    fn rows_sharing_a_cell_are_correlated() {
        let (mut paired, mut alone) = (
            InformationSum::about([0.0; 3], 1.0),
            InformationSum::about([0.0; 3], 1.0),
        );
        for i in 0..100 {
            let pair = i / 2;
            let p = [(pair % 10) as f64 * 0.3, (pair / 10) as f64 * 0.3, 0.0];
            let r = if pair % 2 == 0 { 0.01 } else { -0.01 };
            let key = [pair as f64 + 0.5, 0.5, 0.5];
            paired.add_plane(&p, &[0.0, 0.0, 1.0], Some(&key), r, 1.0, 1.0, &CONSTANT);
            alone.add_plane(&p, &[0.0, 0.0, 1.0], None, r, 1.0, 1.0, &CONSTANT);
        }
        let (paired, alone) = (paired.finish(1.0), alone.finish(1.0));
        // Rotation about x and y and translation along z are constrained.
        for (r, c) in [(0, 0), (1, 1), (5, 5), (0, 5), (1, 5)] {
            let ratio = paired.covariance[(r, c)] / alone.covariance[(r, c)];
            assert!((ratio - 2.0).abs() < 1e-6, "({r}, {c}): {ratio}");
        }
    }

    /// The matching's response s < 1 scales G: the covariance by 1/s².
    #[test]
    fn a_weaker_response_widens_the_covariance() {
        let mut sum = InformationSum::about([0.0; 3], 0.0);
        for k in 0..60 {
            let x = k as f64;
            let p = [(x * 0.37).sin(), (x * 0.91).cos(), (x * 0.13).sin()];
            let r = [
                0.01 * (x * 1.7).sin(),
                -0.02 * (x * 0.3).cos(),
                0.005 * (x * 2.9).sin(),
            ];
            sum.add_point(&p, None, &r, 1.0, 1.0, Some(&CONSTANT));
        }
        let (full, half) = (sum.finish(1.0), sum.finish(0.5));
        let ratio = half.covariance.component_div(&full.covariance);
        assert!(ratio.iter().all(|v| (v - 4.0).abs() < 1e-6), "{ratio}");
    }

    /// Too few residuals to measure a variance: unknown, never NaN.
    #[test]
    fn too_few_rows_are_unknown() {
        let mut sum = InformationSum::about([0.0; 3], 0.0);
        sum.add_point(
            &[1.0, 0.0, 0.0],
            None,
            &[0.1, 0.0, 0.0],
            1.0,
            1.0,
            Some(&CONSTANT),
        );
        sum.add_plane(
            &[0.0, 1.0, 0.0],
            &[f64::NAN, 0.0, 1.0],
            None,
            0.1,
            1.0,
            1.0,
            &CONSTANT,
        );
        assert_eq!(sum.finish(1.0), PoseUncertainty::UNKNOWN);
    }
}
