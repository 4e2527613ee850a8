//! Rigid-transform helpers and the two weighted least-squares solves of the IRLS step
//! (eq. regprob2): closed-form weighted Kabsch for point-to-point and one Gauss-Newton step for
//! point-to-plane.
use nalgebra::{Matrix3, Matrix4, Matrix6, Rotation3, SymmetricEigen, Vector3, Vector6};

use crate::point::Point;

/// How far RᵀR of a given rigid transform may be from I (max |RᵀR − I|): the rotation block is
/// then made exactly orthonormal. Published ground truths are orthonormal only to the digits
/// they were printed with: the 3DMatch `gt.log` matrices, GeoTransformer's `gt.npy` and PCL's
/// office test matrix to 5e-5–7e-5.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-3;
/// A correction of the rotation block larger than this (largest entry change) is reported:
/// the matrix was rounded beyond what a matrix inverse leaves.
pub const NOTABLE_CORRECTION: f64 = 1e-6;
/// How far the last row may be from 0 0 0 1 (rounding from a general 4×4 inverse).
const LAST_ROW_TOLERANCE: f64 = 1e-6;
/// Singular-value ratio below which the point-to-point cross-covariance is rank ≤ 1
/// (all points collinear or coincident: rotation about that line is undetermined).
const KABSCH_RANK_RATIO: f64 = 1e-10;
/// Eigenvalue ratio below which a direction of the (scaled) point-to-plane system is treated as
/// unconstrained and left out of the step.
const PLANE_RANK_RATIO: f64 = 1e-9;

/// T · p: the point p moved by the 4×4 homogeneous transform T (last row ignored).
#[inline]
pub fn transform_point(t: &Matrix4<f64>, p: &Point) -> Point {
    [
        t[(0, 0)] * p[0] + t[(0, 1)] * p[1] + t[(0, 2)] * p[2] + t[(0, 3)],
        t[(1, 0)] * p[0] + t[(1, 1)] * p[1] + t[(1, 2)] * p[2] + t[(1, 3)],
        t[(2, 0)] * p[0] + t[(2, 1)] * p[1] + t[(2, 2)] * p[2] + t[(2, 3)],
    ]
}

/// Whether every coordinate is finite (neither NaN nor ±∞): the one test behind [`NonFinite`](crate::point::NonFinite).
#[inline]
pub fn is_finite(p: &Point) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// Index of the first point with a NaN or infinite coordinate ([`is_finite`]), if any.
pub fn first_non_finite(points: &[Point]) -> Option<usize> {
    points.iter().position(|p| !is_finite(p))
}

/// The corners (smallest and largest coordinate on each axis) of the points' bounding box.
pub fn bounding_box<'a>(points: impl IntoIterator<Item = &'a Point>) -> (Vector3<f64>, Vector3<f64>) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        let v = Vector3::from(*p);
        lo = lo.inf(&v);
        hi = hi.sup(&v);
    }
    (lo, hi)
}

/// The length of the diagonal of the points' bounding box (success bounds are a share of it).
pub fn bounding_box_diagonal<'a>(points: impl IntoIterator<Item = &'a Point>) -> f64 {
    let (lo, hi) = bounding_box(points);
    (hi - lo).norm()
}

/// Euclidean length of a vector.
#[inline]
pub fn length(v: &Point) -> f64 {
    dot(v, v).sqrt()
}

/// Dot product a · b.
#[inline]
pub fn dot(a: &Point, b: &Point) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Cross product a × b.
#[inline]
pub fn cross(a: &Point, b: &Point) -> Point {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// SplitMix64: a well-mixed 64-bit hash of `x` (deterministic thinning and subsets keyed on
/// point indices).
#[inline]
pub(crate) fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The point as an nalgebra column vector.
#[inline]
pub fn vector(p: &Point) -> Vector3<f64> {
    Vector3::new(p[0], p[1], p[2])
}

/// The rotation block R (top-left 3×3) of a homogeneous transform.
pub fn rotation_part(t: &Matrix4<f64>) -> Matrix3<f64> {
    t.fixed_view::<3, 3>(0, 0).into_owned()
}

/// The translation t (last column, first three rows) of a homogeneous transform.
pub fn translation_part(t: &Matrix4<f64>) -> Vector3<f64> {
    t.fixed_view::<3, 1>(0, 3).into_owned()
}

/// The homogeneous transform [R t; 0 0 0 1].
pub fn from_parts(r: &Matrix3<f64>, t: &Vector3<f64>) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(t);
    m
}

/// Rotation angle of a rotation matrix, accurate near 0 (atan2 of sin and cos).
pub fn rotation_angle(r: &Matrix3<f64>) -> f64 {
    let sin = 0.5
        * Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        )
        .norm();
    let cos = 0.5 * (r.trace() - 1.0);
    sin.atan2(cos)
}

/// How far an update from `old` to `new` moves things: the rotation angle (radians) and the
/// distance the point `anchor` moves. With `anchor` at the data's centroid both are
/// independent of the frame the clouds are expressed in (the translation vector of T is not:
/// far from the origin a small rotation changes it a lot).
pub fn transform_change(old: &Matrix4<f64>, new: &Matrix4<f64>, anchor: &Point) -> (f64, f64) {
    let dr = rotation_part(new) * rotation_part(old).transpose();
    let (a, b) = (transform_point(old, anchor), transform_point(new, anchor));
    let moved = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    (rotation_angle(&dr), moved)
}

/// Per-axis median of a point set (origin for none): a centre that a few far-off points do
/// not move.
pub fn median_point(points: &[Point]) -> Point {
    if points.is_empty() {
        return [0.0; 3];
    }
    std::array::from_fn(|axis| {
        let mut values: Vec<f64> = points.iter().map(|p| p[axis]).collect();
        crate::median::median(&mut values).unwrap_or(0.0)
    })
}

/// Centroid of a point set (origin for none).
pub fn centroid(points: &[Point]) -> Point {
    if points.is_empty() {
        return [0.0; 3];
    }
    let sum = points
        .iter()
        .fold([0.0; 3], |s, p| [s[0] + p[0], s[1] + p[1], s[2] + p[2]]);
    let n = points.len() as f64;
    [sum[0] / n, sum[1] / n, sum[2] / n]
}

/// Checks that `matrix` (named `name` in messages) is a homogeneous rigid transform: finite,
/// last row 0 0 0 1 to 1e-6 (a guess composed with a general 4×4 inverse, e.g. Eigen's
/// `inverse()`, carries rounding there), rotation block orthonormal to
/// [`ORTHONORMAL_TOLERANCE`] with det +1. [`orthonormalised`] (or [`make_rigid`]) then makes it
/// exact. Only when the matrix fails and its transpose would pass does the message suggest
/// that it is stored column-major.
pub fn check_rigid(matrix: &Matrix4<f64>, name: &str) -> Result<(), String> {
    rigid_problem(matrix, name).map_or(Ok(()), |problem| {
        let transposed_passes = rigid_problem(&matrix.transpose(), name).is_none();
        Err(if transposed_passes {
            format!("{problem}; its transpose is a rigid transform: is the matrix column-major? (row-major is expected)")
        } else {
            problem
        })
    })
}

/// What makes `matrix` not a rigid transform, if anything.
fn rigid_problem(matrix: &Matrix4<f64>, name: &str) -> Option<String> {
    // Row-major index, as C callers store it.
    if let Some(index) = matrix.transpose().iter().position(|v| !v.is_finite()) {
        return Some(format!(
            "{name}[{index}] is {}; the transform must be finite",
            matrix[(index / 4, index % 4)]
        ));
    }
    if !homogeneous_last_row(matrix) {
        let last_row = [matrix[(3, 0)], matrix[(3, 1)], matrix[(3, 2)], matrix[(3, 3)]];
        return Some(format!(
            "{name}: last row is {last_row:?}; a homogeneous transform ends in 0 0 0 1 (row-major)"
        ));
    }
    let rotation = rotation_part(matrix);
    let orthogonality_error = (rotation.transpose() * rotation - Matrix3::identity()).amax();
    if orthogonality_error > ORTHONORMAL_TOLERANCE {
        return Some(format!(
            "{name}: the rotation part is not orthonormal (max |R^T R - I| = {orthogonality_error:e} \
             > {ORTHONORMAL_TOLERANCE:e}, more than rounding)"
        ));
    }
    let determinant = rotation.determinant();
    if determinant < 0.0 {
        return Some(format!(
            "{name}: the rotation part is a reflection (det = {determinant})"
        ));
    }
    None
}

/// True when the last row is 0 0 0 1 to within 1e-6.
pub(crate) fn homogeneous_last_row(matrix: &Matrix4<f64>) -> bool {
    (0..4).all(|col| (matrix[(3, col)] - if col == 3 { 1.0 } else { 0.0 }).abs() <= LAST_ROW_TOLERANCE)
}

/// A transform made exactly rigid, and how much that changed it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid {
    /// The rigid transform (rotation block exactly orthonormal, last row 0 0 0 1).
    pub transform: Matrix4<f64>,
    /// Largest change of a rotation-block entry (0 for an exact rotation; above
    /// [`NOTABLE_CORRECTION`] the matrix was visibly rounded and is worth a note).
    pub correction: f64,
}

/// [`check_rigid`], then [`orthonormalised`]: the nearest rigid transform and the correction.
pub fn make_rigid(matrix: &Matrix4<f64>, name: &str) -> Result<Rigid, String> {
    check_rigid(matrix, name)?;
    let transform = orthonormalised(matrix);
    let correction = (rotation_part(&transform) - rotation_part(matrix)).amax();
    Ok(Rigid {
        transform,
        correction,
    })
}

/// Projects the rotation block onto SO(3) (nearest rotation), keeping the translation; the last
/// row becomes exactly 0 0 0 1.
pub fn orthonormalised(t: &Matrix4<f64>) -> Matrix4<f64> {
    let svd = rotation_part(t).svd(true, true);
    let (u, v_t) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * v_t).determinant().signum();
    from_parts(&(u * d * v_t), &translation_part(t))
}

/// Result of one weighted solve.
pub struct Solve {
    /// The solved transform: the weighted fit (point-to-point), or the current transform moved
    /// by one Gauss-Newton step (point-to-plane).
    pub transform: Matrix4<f64>,
    /// Some direction of the problem was not constrained by the data.
    pub rank_deficient: bool,
    /// How well the weighted data constrain the pose, 0 (not at all in some direction) to 1
    /// (equally in all): point-to-plane, the smallest over the largest eigenvalue of the
    /// normal matrix with rotations scaled to lengths; point-to-point, the second singular
    /// value over the first of the cross-covariance (planar data still fix a rotation).
    pub conditioning: f64,
}

/// Pairs whose largest coordinate magnitude is outside [2^-64, 2^64] are solved scaled by a
/// power of two (exact): the cross-covariance holds squared coordinates, which overflow from
/// ~1e154 (the SVD then returns NaN) and underflow below ~1e-154.
const UNSCALED_MAX_EXPONENT: i32 = 64;

/// argmin_{R,t} Σ w_i‖R·a_i + t − b_i‖² (weighted Kabsch / Umeyama without scale).
/// `None` when the weights sum to zero. Any finite coordinates: beyond 2^±64 the points are
/// scaled by a power of two first, so their squares neither overflow nor underflow.
pub fn weighted_rigid_fit(pairs: &[(Point, Point)], weights: &[f64]) -> Option<Solve> {
    weighted_rigid_fit_by(pairs.len(), |i| pairs[i], weights)
}

/// [`weighted_rigid_fit`] with pair i given by `pair(i)` for i < `count` (no slice of pairs
/// needed: ICP reads them from its matches by index). The same arithmetic in the same order.
pub fn weighted_rigid_fit_by(
    count: usize,
    pair: impl Fn(usize) -> (Point, Point),
    weights: &[f64],
) -> Option<Solve> {
    // Pairs of weight 0 (a far-off garbage point among them) take no part in the fit.
    let largest = (0..count.min(weights.len()))
        .filter(|&i| weights[i] > 0.0)
        .map(&pair)
        .flat_map(|(a, b)| a.into_iter().chain(b))
        .fold(0.0f64, |m, c| m.max(c.abs()));
    let exponent = if largest > 0.0 && largest.is_finite() {
        largest.log2().floor() as i32
    } else {
        0
    };
    if exponent.abs() <= UNSCALED_MAX_EXPONENT {
        return unscaled_rigid_fit(count, pair, weights);
    }
    // R is unchanged by a common scale s of both point sets and t scales with it: fit s·a ↦ s·b.
    let shift = (-exponent).clamp(-1000, 1000);
    let scale = 2f64.powi(shift);
    let scaled = |i: usize| {
        let (a, b) = pair(i);
        (a.map(|c| c * scale), b.map(|c| c * scale))
    };
    let mut solve = unscaled_rigid_fit(count, scaled, weights)?;
    let translation = translation_part(&solve.transform) * 2f64.powi(-shift);
    solve
        .transform
        .fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&translation);
    Some(solve)
}

fn unscaled_rigid_fit(
    count: usize,
    pair: impl Fn(usize) -> (Point, Point),
    weights: &[f64],
) -> Option<Solve> {
    let total: f64 = weights.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    let mut mean_a = Vector3::zeros();
    let mut mean_b = Vector3::zeros();
    for (i, &w) in weights.iter().take(count).enumerate() {
        let (a, b) = pair(i);
        mean_a += w * vector(&a);
        mean_b += w * vector(&b);
    }
    mean_a /= total;
    mean_b /= total;
    // Centred second pass: exact for far-from-origin (e.g. georeferenced) coordinates.
    let mut cross = Matrix3::zeros();
    for (i, &w) in weights.iter().take(count).enumerate() {
        let (a, b) = pair(i);
        cross += w * (vector(&a) - mean_a) * (vector(&b) - mean_b).transpose();
    }
    let svd = cross.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    let largest = s.max();
    let rank_deficient = !(largest.is_finite() && largest > 0.0)
        || s.iter().filter(|&&v| v > KABSCH_RANK_RATIO * largest).count() < 2;
    // R = V·diag(1, 1, det(V·Uᵀ))·Uᵀ keeps a proper rotation.
    let v = v_t.transpose();
    let mut d = Matrix3::identity();
    d[(2, 2)] = (v * u.transpose()).determinant().signum();
    let r = v * d * u.transpose();
    let t = mean_b - r * mean_a;
    Some(Solve {
        transform: from_parts(&r, &t),
        rank_deficient,
        conditioning: if largest > 0.0 {
            {
                let mut sorted = [s[0], s[1], s[2]];
                sorted.sort_by(|a, b| b.total_cmp(a));
                sorted[1] / sorted[0]
            }
        } else {
            0.0
        },
    })
}

/// One weighted Gauss-Newton step for Σ w_i (n_iᵀ(T·a_i − q_i))², linearised at the current
/// transform. `points[i]` = (T·a_i, q_i, n_i). The update is the exact rotation about the
/// weighted centroid (so rotation and translation are decoupled and well scaled); directions
/// the data do not constrain are left unchanged. `None` when the weights sum to zero.
pub fn point_to_plane_step(
    current: &Matrix4<f64>,
    points: &[(Point, Point, Point)],
    weights: &[f64],
) -> Option<Solve> {
    point_to_plane_step_by(
        current,
        points.len(),
        |i| points[i].0,
        |i| (points[i].1, points[i].2),
        weights,
    )
}

/// [`point_to_plane_step`] with row i given by `moved(i)` = T·a_i and `plane(i)` = (q_i, n_i)
/// for i < `count` (ICP reads them from its matches and the target by index instead of
/// copying 72 bytes a row). The same arithmetic in the same order.
pub fn point_to_plane_step_by(
    current: &Matrix4<f64>,
    count: usize,
    moved: impl Fn(usize) -> Point,
    plane: impl Fn(usize) -> (Point, Point),
    weights: &[f64],
) -> Option<Solve> {
    let total: f64 = weights.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    let weights = &weights[..count.min(weights.len())];
    let system = PlaneSystem::new(total, moved, plane, weights);
    let eigen = SymmetricEigen::new(system.hessian);
    let largest = eigen.eigenvalues.max();
    if !(largest.is_finite() && largest > 0.0) {
        return None;
    }
    let mut step = Vector6::zeros();
    let mut rank_deficient = false;
    for k in 0..6 {
        let lambda = eigen.eigenvalues[k];
        let direction = eigen.eigenvectors.column(k);
        if lambda > PLANE_RANK_RATIO * largest {
            step -= direction * (direction.dot(&system.gradient) / lambda);
        } else {
            rank_deficient = true;
        }
    }
    let (centre, length) = (system.centre, system.length);
    let omega = Vector3::new(step[0], step[1], step[2]) / length;
    let shift = Vector3::new(step[3], step[4], step[5]);
    let rotation = Rotation3::new(omega).into_inner();
    // p ↦ R(p − c) + c + v
    let delta = from_parts(&rotation, &(centre - rotation * centre + shift));
    Some(Solve {
        transform: orthonormalised(&(delta * current)),
        rank_deficient,
        conditioning: (eigen.eigenvalues.min() / largest).max(0.0),
    })
}

/// How well point-to-plane rows fix a pose, as [`point_to_plane_step_by`] measures it (its
/// `conditioning`): the smallest over the largest eigenvalue of Σ w_i·J_iᵀJ_i, J_i =
/// [(p_i − c)×n_i / s, n_i], c the weighted centroid and s the weighted RMS distance from it.
/// Needs no target point (the residuals do not enter). 0 when the weights sum to zero or the
/// rows leave some direction entirely free; a non-finite point, normal or weight also gives 0.
pub(crate) fn plane_conditioning_by(
    count: usize,
    moved: impl Fn(usize) -> Point,
    normal: impl Fn(usize) -> Point,
    weights: &[f64],
) -> PlaneConditioning {
    let free = PlaneConditioning {
        ratio: 0.0,
        loosest: None,
    };
    let weights = &weights[..count.min(weights.len())];
    let total: f64 = weights.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        return free;
    }
    let system = PlaneSystem::new(total, &moved, |i| (moved(i), normal(i)), weights);
    let eigen = SymmetricEigen::new(system.hessian);
    let (smallest, largest) = (eigen.eigenvalues.min(), eigen.eigenvalues.max());
    if !(largest.is_finite() && largest > 0.0 && smallest.is_finite()) {
        return free;
    }
    let weakest = eigen.eigenvalues.imin();
    let direction = eigen.eigenvectors.column(weakest);
    PlaneConditioning {
        ratio: (smallest / largest).clamp(0.0, 1.0),
        loosest: Some(LooseDirection::of(&Vector6::from_iterator(
            direction.iter().copied(),
        ))),
    }
}

/// [`plane_conditioning_by`]'s answer: the conditioning, and the pose's direction of least
/// constraint (`None` where nothing is constrained at all).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PlaneConditioning {
    pub(crate) ratio: f64,
    pub(crate) loosest: Option<LooseDirection>,
}

/// The direction in which the inliers constrain a pose least: a translation along a unit
/// axis, or a rotation about a unit axis through the inliers' centroid, whichever part of the
/// weakest eigenvector (rotation scaled by the inliers' spread) is the larger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LooseDirection {
    /// Translation along this unit vector (target frame).
    Translation([f64; 3]),
    /// Rotation about this unit axis (target frame) through the inliers' centroid.
    Rotation([f64; 3]),
}

impl LooseDirection {
    /// From an eigenvector of [`PlaneSystem`]'s normal matrix: (ω·s, v).
    fn of(weakest: &Vector6<f64>) -> Self {
        let rotation = Vector3::new(weakest[0], weakest[1], weakest[2]);
        let translation = Vector3::new(weakest[3], weakest[4], weakest[5]);
        // The sign of an eigenvector is arbitrary: the largest component is made positive.
        let unit = |v: Vector3<f64>| {
            let v = v.normalize();
            let sign = if v[v.iamax()] < 0.0 { -1.0 } else { 1.0 };
            [sign * v.x, sign * v.y, sign * v.z]
        };
        if translation.norm() >= rotation.norm() {
            LooseDirection::Translation(unit(translation))
        } else {
            LooseDirection::Rotation(unit(rotation))
        }
    }
}

/// The normal equations of weighted point-to-plane rows Σ w_i (n_iᵀ(p_i − q_i))², linearised
/// about the rows' weighted centroid with the rotation unknowns scaled by their spread.
struct PlaneSystem {
    /// Σ w·J·Jᵀ.
    hessian: Matrix6<f64>,
    /// Σ w·r·J.
    gradient: Vector6<f64>,
    /// The weighted centroid c of the moved points.
    centre: Vector3<f64>,
    /// The scale of the rotation unknowns: the weighted RMS distance from c (1 when 0).
    length: f64,
}

impl PlaneSystem {
    /// Rows i < `weights.len()`: p_i = `moved(i)`, (q_i, n_i) = `plane(i)`; `total` = Σ w.
    fn new(
        total: f64,
        moved: impl Fn(usize) -> Point,
        plane: impl Fn(usize) -> (Point, Point),
        weights: &[f64],
    ) -> Self {
        let mut centre = Vector3::zeros();
        for (i, &w) in weights.iter().enumerate() {
            centre += w * vector(&moved(i));
        }
        centre /= total;
        let spread = (weights
            .iter()
            .enumerate()
            .map(|(i, &w)| w * (vector(&moved(i)) - centre).norm_squared())
            .sum::<f64>()
            / total)
            .sqrt();
        // Rotation unknowns are scaled by the spread so all six columns have length units.
        let length = if spread > 0.0 { spread } else { 1.0 };
        // Σ w·J·Jᵀ, lower triangle only (all that SymmetricEigen reads): (w·J_r)·J_c for c ≤ r,
        // the products and sums of the full outer product, 21 of its 36.
        let mut lower = [0.0; 21];
        let mut gradient = Vector6::zeros();
        for (i, &w) in weights.iter().enumerate() {
            if w == 0.0 {
                continue;
            }
            let (p, (q, n)) = (moved(i), plane(i));
            let normal = vector(&n);
            let arm = vector(&p) - centre;
            let residual = normal.dot(&(vector(&p) - vector(&q)));
            let rot = arm.cross(&normal) / length;
            let jac = [rot.x, rot.y, rot.z, normal.x, normal.y, normal.z];
            let mut k = 0;
            for r in 0..6 {
                let weighted = w * jac[r];
                for &c in &jac[..=r] {
                    lower[k] += weighted * c;
                    k += 1;
                }
            }
            gradient += w * residual * Vector6::from(jac);
        }
        let mut hessian = Matrix6::zeros();
        let mut k = 0;
        for r in 0..6 {
            for c in 0..=r {
                hessian[(r, c)] = lower[k];
                hessian[(c, r)] = lower[k];
                k += 1;
            }
        }
        PlaneSystem {
            hessian,
            gradient,
            centre,
            length,
        }
    }
}

/// The centroid of `points` and their principal axes (the columns, unit length).
pub(crate) fn principal_axes(points: &[[f64; 3]]) -> (Vector3<f64>, Matrix3<f64>) {
    let centroid = Vector3::from(centroid(points));
    let scatter = points.iter().fold(Matrix3::zeros(), |sum, p| {
        let d = Vector3::from(*p) - centroid;
        sum + d * d.transpose()
    });
    (centroid, SymmetricEigen::new(scatter).eigenvectors)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Translation3;

    fn example_transform() -> Matrix4<f64> {
        let r = Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        Translation3::new(0.4, -1.0, 2.0).to_homogeneous() * r.to_homogeneous()
    }

    /// A guess built with a general 4×4 inverse has rounding in its last row; that is accepted
    /// and made exact, a real non-rigid last row is not.
    #[test]
    fn last_row_rounding_is_accepted_and_removed() {
        let mut rounded = example_transform();
        rounded[(3, 3)] = 0.999_999_999_999_999_8;
        rounded[(3, 1)] = -1e-17;
        assert_eq!(check_rigid(&rounded, "guess"), Ok(()));
        let exact = orthonormalised(&rounded);
        assert_eq!(exact.row(3), Matrix4::<f64>::identity().row(3));
        assert!((exact - example_transform()).amax() < 1e-12);
        let mut column_major = example_transform();
        column_major[(3, 0)] = 0.4;
        let message = check_rigid(&column_major, "guess").unwrap_err();
        assert!(message.contains("last row"), "{message}");
    }

    fn cube_points() -> Vec<Point> {
        (0..60)
            .map(|i| {
                let f = i as f64;
                [
                    (f * 0.37).sin() * 2.0,
                    (f * 0.91).cos(),
                    (f * 0.13).sin() * 3.0 + 0.1 * f,
                ]
            })
            .collect()
    }

    #[test]
    fn weighted_kabsch_recovers_exact_transform() {
        let t = example_transform();
        let pairs: Vec<(Point, Point)> = cube_points()
            .iter()
            .map(|a| (*a, transform_point(&t, a)))
            .collect();
        let solve = weighted_rigid_fit(&pairs, &vec![1.0; pairs.len()]).unwrap();
        assert!((solve.transform - t).abs().max() < 1e-10);
        assert!(!solve.rank_deficient);
    }

    /// The cross-covariance squares coordinates: at 1e200 it overflowed (NaN from the SVD),
    /// at 1e-200 it underflowed to 0 (rank deficient, identity). Scaled, both are exact.
    #[test]
    fn weighted_kabsch_is_exact_at_any_magnitude() {
        let t = example_transform();
        for scale in [1e200, 1e77, 1e-200, 1e-300] {
            let pairs: Vec<(Point, Point)> = cube_points()
                .iter()
                .map(|a| {
                    let b = transform_point(&t, a);
                    (a.map(|c| c * scale), b.map(|c| c * scale))
                })
                .collect();
            let solve = weighted_rigid_fit(&pairs, &vec![1.0; pairs.len()]).unwrap();
            assert!(!solve.rank_deficient, "{scale:e}");
            let rotation_error = (rotation_part(&solve.transform) - rotation_part(&t)).amax();
            let translation_error =
                (translation_part(&solve.transform) / scale - translation_part(&t)).amax();
            assert!(
                rotation_error < 1e-10 && translation_error < 1e-10,
                "{scale:e}: {}",
                solve.transform
            );
        }
    }

    #[test]
    fn zero_weights_drop_outliers_from_kabsch() {
        let t = example_transform();
        let mut pairs: Vec<(Point, Point)> = cube_points()
            .iter()
            .map(|a| (*a, transform_point(&t, a)))
            .collect();
        let mut weights = vec![1.0; pairs.len()];
        pairs.push(([0.0; 3], [100.0, 50.0, -3.0]));
        weights.push(0.0);
        let solve = weighted_rigid_fit(&pairs, &weights).unwrap();
        assert!((solve.transform - t).abs().max() < 1e-10);
    }

    #[test]
    fn collinear_points_are_rank_deficient() {
        let pairs: Vec<(Point, Point)> = (0..10)
            .map(|i| ([i as f64, 0.0, 0.0], [i as f64, 1.0, 0.0]))
            .collect();
        let solve = weighted_rigid_fit(&pairs, &[1.0; 10]).unwrap();
        assert!(solve.rank_deficient);
        assert!(solve.transform.iter().all(|v| v.is_finite()));
        assert!(weighted_rigid_fit(&pairs, &[0.0; 10]).is_none());
    }

    #[test]
    fn point_to_plane_converges_on_a_box() {
        // Points on the six faces of a box, normals known: GN from a small offset converges.
        let t_true = Translation3::new(0.05, -0.03, 0.02).to_homogeneous()
            * Rotation3::from_euler_angles(0.03, 0.02, -0.04).to_homogeneous();
        let mut target = Vec::new();
        for i in 0..15 {
            for j in 0..15 {
                let (u, v) = (i as f64 / 14.0 * 2.0 - 1.0, j as f64 / 14.0 * 2.0 - 1.0);
                for (p, n) in [
                    ([u, v, 1.0], [0.0, 0.0, 1.0]),
                    ([u, v, -1.0], [0.0, 0.0, -1.0]),
                    ([u, 1.0, v], [0.0, 1.0, 0.0]),
                    ([u, -1.0, v], [0.0, -1.0, 0.0]),
                    ([1.0, u, v], [1.0, 0.0, 0.0]),
                    ([-1.0, u, v], [-1.0, 0.0, 0.0]),
                ] {
                    target.push((p, n));
                }
            }
        }
        let inverse = t_true.try_inverse().unwrap();
        let source: Vec<Point> = target.iter().map(|(p, _)| transform_point(&inverse, p)).collect();
        let mut t = Matrix4::identity();
        for _ in 0..10 {
            let pts: Vec<(Point, Point, Point)> = source
                .iter()
                .zip(&target)
                .map(|(a, (q, n))| (transform_point(&t, a), *q, *n))
                .collect();
            t = point_to_plane_step(&t, &pts, &vec![1.0; pts.len()])
                .unwrap()
                .transform;
        }
        assert!((t - t_true).abs().max() < 1e-9, "{t}");
    }

    #[test]
    fn single_plane_is_rank_deficient_and_finite() {
        let pts: Vec<(Point, Point, Point)> = (0..100)
            .map(|i| {
                let p = [(i % 10) as f64, (i / 10) as f64, 0.1];
                (p, [p[0], p[1], 0.0], [0.0, 0.0, 1.0])
            })
            .collect();
        let solve = point_to_plane_step(&Matrix4::identity(), &pts, &vec![1.0; 100]).unwrap();
        assert!(solve.rank_deficient);
        // The constrained direction (z) is solved, the rest is left alone.
        assert!((solve.transform[(2, 3)] + 0.1).abs() < 1e-12);
        assert!(solve.transform[(0, 3)].abs() < 1e-12 && solve.transform[(1, 3)].abs() < 1e-12);
    }

    #[test]
    fn rotation_angle_is_accurate_for_tiny_angles() {
        let r = Rotation3::from_axis_angle(&Vector3::x_axis(), 1e-9).into_inner();
        assert!((rotation_angle(&r) - 1e-9).abs() < 1e-15);
        let r = Rotation3::from_axis_angle(&Vector3::y_axis(), 3.0).into_inner();
        assert!((rotation_angle(&r) - 3.0).abs() < 1e-12);
    }
}
