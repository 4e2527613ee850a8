//! How well the surfaces under an ICP result fix its pose (project issue 29). A corridor seen
//! over part of its length, or a small patch of a larger plane, fits equally well anywhere
//! along its surfaces. Point-to-point's own conditioning (the Kabsch cross-covariance's
//! singular values) sees the spread of the points, not their surfaces, and misses that.
//! Point-to-plane's normal matrix sees it in principle, but from per-point normals: each is
//! tilted by the points' noise (σ = 5 mm at 10 neighbours: a few degrees), and Σ n·nᵀ of tilts
//! that large puts an eigenvalue of a few 1e-3 on a direction nothing fixes.
//!
//! So both metrics are judged at their result by one measure: J_i = [(p_i − c)×n_i / s, n_i]
//! per inlier pair (p_i the moved source point, n_i the surface normal at its target, c and s
//! the weighted centroid and RMS spread of the p_i), conditioning λ_min / λ_max of
//! Σ w_i J_iᵀJ_i (`geometry::plane_conditioning_by`, as point-to-plane's solve measures it). A
//! translation t along the surfaces changes no n_iᵀ(p_i + t − q_i): an eigenvalue near 0. The
//! normals come from [`SURFACE_NEIGHBOURS`] neighbours, where noise tilts them a fifth as much
//! (a 25th of the false constraint), and are estimated for a few thousand targets only.

use crate::geometry::plane_conditioning_by;
use crate::parallel::Workers;
use crate::point::Point;
use crate::registration::target::PreparedTarget;

/// Pairs at least this likely inliers take part: the surfaces the result rests on.
pub(crate) const INLIER_PROBABILITY: f64 = 0.5;
/// At most this many of them (evenly strided): a 6 × 6 matrix of well-spread rows is as
/// clear from 2 000 as from every point, and only their normals are estimated.
pub(crate) const SURFACE_PAIRS: usize = 2_048;
/// Neighbours of a surface normal. A normal's tilt from noise σ over a neighbourhood of k
/// points on a surface is about σ / (spacing · k) (radius ∝ √k, averaging over k): 5 times less
/// than at the 10 neighbours of point-to-plane's normals, and still a neighbourhood, not an
/// object (its radius about 2.5 times theirs).
pub(crate) const SURFACE_NEIGHBOURS: usize = 50;

/// The rows (indices into `probabilities`) whose pairs judge the surfaces: those above
/// [`INLIER_PROBABILITY`], every ⌈count / SURFACE_PAIRS⌉-th of them, ascending. A NaN
/// probability is no inlier.
pub(crate) fn surface_rows(probabilities: &[f64]) -> Vec<usize> {
    let inlier = |p: f64| p > INLIER_PROBABILITY;
    let inliers = probabilities.iter().filter(|&&p| inlier(p)).count();
    let stride = inliers.div_ceil(SURFACE_PAIRS).max(1);
    probabilities
        .iter()
        .enumerate()
        .filter(|(_, p)| inlier(**p))
        .map(|(row, _)| row)
        .step_by(stride)
        .collect()
}

/// One inlier pair: the source point moved by the result, its matched target (curve-order
/// index into the prepared target) and its inlier probability (the weight).
pub(crate) struct SurfacePair {
    pub(crate) moved: Point,
    pub(crate) target: u32,
    pub(crate) weight: f64,
}

/// The conditioning of the surfaces under `pairs` (see the module documentation), with
/// normals estimated at their targets now (given normals are per point, as noisy as
/// point-to-plane's own). Pairs whose target has no normal (no plane in its neighbourhood),
/// or whose point, normal or weight is not finite, are left out; fewer than 6 left give 0.
pub(crate) fn surface_conditioning(pairs: &[SurfacePair], target: &PreparedTarget, workers: &Workers) -> f64 {
    let targets: Vec<u32> = pairs.iter().map(|pair| pair.target).collect();
    let normals = target.surface_normals(&targets, SURFACE_NEIGHBOURS, workers);
    let with_normal: Vec<(Point, Point, f64)> = pairs
        .iter()
        .zip(normals)
        .map(|(pair, normal)| (pair.moved, normal, pair.weight))
        .filter(|(moved, normal, weight)| {
            *normal != [0.0; 3]
                && normal.iter().chain(moved).all(|c| c.is_finite())
                && weight.is_finite()
                && *weight > 0.0
        })
        .collect();
    // Six unknowns: fewer rows cannot fix them all.
    if with_normal.len() < 6 {
        return 0.0;
    }
    let weights: Vec<f64> = with_normal.iter().map(|row| row.2).collect();
    plane_conditioning_by(
        with_normal.len(),
        |i| with_normal[i].0,
        |i| with_normal[i].1,
        &weights,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::target::PrepareOptions;

    /// Points on the faces given by their normals: axis-aligned faces 1.5 from the origin
    /// (a box, one face per normal), each a sheared 40 × 40 grid about 2 × 2 wide, so that a
    /// surface neighbourhood near a face's edge stays on its face.
    fn faces(normals: &[Point]) -> Vec<Point> {
        let mut points = Vec::new();
        for n in normals {
            let axis = n.iter().position(|c| *c != 0.0).unwrap();
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            for i in 0..40 {
                for j in 0..40 {
                    let mut p = [0.0; 3];
                    p[axis] = n[axis] * 1.5;
                    p[a] = -1.0 + 0.05 * i as f64 + 0.006 * j as f64;
                    p[b] = -1.1 + 0.055 * j as f64;
                    points.push(p);
                }
            }
        }
        points
    }

    fn conditioning_of(points: &[Point], weight: f64) -> f64 {
        let target = PreparedTarget::new(points, None, &PrepareOptions::default()).unwrap();
        let workers = Workers::new(1).unwrap();
        let pairs: Vec<SurfacePair> = (0..target.points().len())
            .map(|t| SurfacePair {
                moved: target.points()[t],
                target: t as u32,
                weight,
            })
            .collect();
        surface_conditioning(&pairs, &target, &workers)
    }

    const X: Point = [1.0, 0.0, 0.0];
    const Y: Point = [0.0, 1.0, 0.0];
    const Z: Point = [0.0, 0.0, 1.0];

    /// A box fixes every direction; a floor and two parallel walls (a corridor) leave the
    /// translation along them free, one plane leaves three directions free.
    #[test]
    fn closed_surfaces_are_conditioned_and_sliding_ones_are_not() {
        let closed = [X, Y, Z, X.map(|c| -c), Y.map(|c| -c), Z.map(|c| -c)];
        assert!(conditioning_of(&faces(&closed), 1.0) > 0.05);
        let corridor = [Z, Y, Y.map(|c| -c)];
        assert!(conditioning_of(&faces(&corridor), 1.0) < 1e-6);
        assert!(conditioning_of(&faces(&[Z]), 1.0) < 1e-6);
    }

    /// Zero or NaN weights, too few pairs, NaN points or targets without a normal give 0 or
    /// are left out, never NaN.
    #[test]
    fn bad_rows_give_zero_not_nan() {
        let closed = faces(&[X, Y, Z, X.map(|c| -c), Y.map(|c| -c), Z.map(|c| -c)]);
        assert_eq!(conditioning_of(&closed, 0.0), 0.0);
        assert_eq!(conditioning_of(&closed, f64::NAN), 0.0);
        let target = PreparedTarget::new(&closed, None, &PrepareOptions::default()).unwrap();
        let workers = Workers::new(1).unwrap();
        let pair = |t: usize, moved: Point| SurfacePair {
            moved,
            target: t as u32,
            weight: 1.0,
        };
        let five: Vec<SurfacePair> = (0..5)
            .map(|t| pair(t * 1600, target.points()[t * 1600]))
            .collect();
        assert_eq!(surface_conditioning(&five, &target, &workers), 0.0);
        assert_eq!(surface_conditioning(&[], &target, &workers), 0.0);
        let mut all: Vec<SurfacePair> = (0..closed.len()).map(|t| pair(t, target.points()[t])).collect();
        let clean = surface_conditioning(&all, &target, &workers);
        all[7].moved = [f64::NAN; 3];
        let with_nan = surface_conditioning(&all, &target, &workers);
        assert!(with_nan.is_finite() && (with_nan - clean).abs() < 0.01 * clean);
        // Points on a line have no plane, hence no normal: every pair is left out.
        let line: Vec<Point> = (0..200).map(|i| [0.01 * i as f64, 0.0, 0.0]).collect();
        let target = PreparedTarget::new(&line, None, &PrepareOptions::default()).unwrap();
        let on_line: Vec<SurfacePair> = (0..line.len()).map(|t| pair(t, target.points()[t])).collect();
        assert_eq!(surface_conditioning(&on_line, &target, &workers), 0.0);
    }

    #[test]
    fn surface_rows_are_the_inliers_strided_to_the_limit() {
        assert_eq!(surface_rows(&[0.9, 0.2, f64::NAN, 0.6, 0.5]), vec![0, 3]);
        let many = vec![1.0; 3 * SURFACE_PAIRS + 5];
        let rows = surface_rows(&many);
        assert!(rows.len() <= SURFACE_PAIRS && rows.len() > SURFACE_PAIRS / 2);
        assert!(rows.windows(2).all(|w| w[1] - w[0] == 4));
    }
}
