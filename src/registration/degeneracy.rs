//! How well the surfaces under an ICP result fix its pose (project issue 29). A corridor seen
//! over part of its length, or a small patch of a larger plane, fits equally well anywhere
//! along its surfaces. Point-to-point's own conditioning (the Kabsch cross-covariance's
//! singular values) sees the spread of the points, not their surfaces, and misses that.
//! Point-to-plane's normal matrix sees it in principle, but from per-point normals: each is
//! tilted by the points' noise (σ = 5 mm at 10 neighbours: a few degrees), and Σ n·nᵀ of tilts
//! that large puts an eigenvalue of a few 1e-3 on a direction nothing fixes.
//!
//! So both metrics are judged at their result by one measure: J_i = [(p_i − c)×n_i / s, n_i]
//! per pair, drawn by weight (p_i the moved source point, n_i the surface normal at its
//! target, c and s the weighted centroid and RMS spread of the p_i), conditioning λ_min / λ_max of
//! Σ w_i J_iᵀJ_i (`geometry::plane_conditioning_by`, as point-to-plane's solve measures it). A
//! translation t along the surfaces changes no n_iᵀ(p_i + t − q_i): an eigenvalue near 0. The
//! normals come from up to [`SURFACE_NEIGHBOURS`] neighbours, where noise tilts them a fifth as much
//! (a 25th of the false constraint), and are estimated for a few thousand targets only.

use crate::geometry::{PlaneConditioning, plane_conditioning_by};
use crate::parallel::Workers;
use crate::point::Point;
use crate::registration::target::PreparedTarget;

/// Pairs whose normals are estimated, at most: a 6 × 6 matrix of well-spread rows is about as
/// clear from a thousand as from every point (the real-scan tables' verdicts and poses are
/// those of 2 048 draws; at 512 one search ends elsewhere: docs/performance.md).
pub(crate) const SURFACE_PAIRS: usize = 1_024;
/// Neighbours of a surface normal. A normal's tilt from noise σ over a neighbourhood of k
/// points on a surface is about σ / (spacing · k) (radius ∝ √k, averaging over k): 5 times less
/// than at the 10 neighbours of point-to-plane's normals, and still a neighbourhood, not an
/// object (its radius about 2.5 times theirs) …
pub(crate) const SURFACE_NEIGHBOURS: usize = 50;
/// … on a target of at least this many times as many points; a smaller one has fewer, down to
/// its per-point normals' count (361 points of the PCL test bunny: 50 neighbours are a seventh
/// of it, curved, and most are no plane).
const NEIGHBOURHOOD_SHARE: usize = 64;

/// Neighbours of a surface normal on a target of `points` points whose per-point normals use
/// `normal_neighbours`.
pub(crate) fn surface_neighbours(points: usize, normal_neighbours: usize) -> usize {
    (points / NEIGHBOURHOOD_SHARE).clamp(normal_neighbours.min(SURFACE_NEIGHBOURS), SURFACE_NEIGHBOURS)
}

/// The rows whose pairs judge the surfaces, with their weights, ascending: every row of
/// positive probability with it as weight when there are at most [`SURFACE_PAIRS`] of them;
/// otherwise a systematic sample with probability proportional to it (one draw each
/// ΣP / SURFACE_PAIRS of the running sum, a row's weight its draws): Σ w·J·Jᵀ keeps its
/// expectation, and the inliers, not the outliers, take the draws, for SIE's P(inlier) and a
/// baseline's relative weights alike. A NaN or negative probability counts as 0.
pub(crate) fn surface_rows(probabilities: &[f64]) -> Vec<(usize, f64)> {
    let weight = |p: f64| if p > 0.0 && p.is_finite() { p } else { 0.0 };
    let weighted = || probabilities.iter().enumerate().map(|(row, &p)| (row, weight(p)));
    if weighted().filter(|(_, w)| *w > 0.0).count() <= SURFACE_PAIRS {
        return weighted().filter(|(_, w)| *w > 0.0).collect();
    }
    let total: f64 = weighted().map(|(_, w)| w).sum();
    let step = total / SURFACE_PAIRS as f64;
    let (mut running, mut next_draw) = (0.0, step / 2.0);
    let mut chosen = Vec::with_capacity(SURFACE_PAIRS);
    for (row, w) in weighted() {
        running += w;
        let mut draws = 0u32;
        while running > next_draw && draws as usize <= SURFACE_PAIRS {
            draws += 1;
            next_draw += step;
        }
        if draws > 0 {
            chosen.push((row, f64::from(draws)));
        }
    }
    chosen
}

/// One pair: the source point moved by the result, its matched target (curve-order index
/// into the prepared target), its weight (`surface_rows`) and its row.
pub(crate) struct SurfacePair {
    pub(crate) moved: Point,
    pub(crate) target: u32,
    pub(crate) weight: f64,
    pub(crate) row: usize,
}

/// A pair with the surface normal at its target.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SurfaceRow {
    pub(crate) moved: Point,
    pub(crate) target: u32,
    pub(crate) normal: Point,
    pub(crate) weight: f64,
    pub(crate) row: usize,
}

/// The pairs with their surface normals estimated at their targets now (given normals are per
/// point, as noisy as point-to-plane's own), and with the targets' per-point normals
/// (`PreparedTarget::surface_and_point_normals`). Left out of the first: pairs whose target has
/// no surface normal (no plane in its neighbourhood); of the second: those without a per-point
/// normal; of both: those whose point, normal or weight is not finite.
pub(crate) fn surface_sample(
    pairs: &[SurfacePair],
    target: &PreparedTarget,
    workers: &Workers,
) -> (Vec<SurfaceRow>, Vec<SurfaceRow>) {
    let targets: Vec<u32> = pairs.iter().map(|pair| pair.target).collect();
    let neighbours = surface_neighbours(target.indexed_len(), target.normal_neighbours());
    let (surface, point) = target.surface_and_point_normals(&targets, neighbours, workers);
    let with = |normals: Vec<Point>| -> Vec<SurfaceRow> {
        pairs
            .iter()
            .zip(normals)
            .map(|(pair, normal)| SurfaceRow {
                moved: pair.moved,
                target: pair.target,
                normal,
                weight: pair.weight,
                row: pair.row,
            })
            .filter(|row| {
                row.normal != [0.0; 3]
                    && row.normal.iter().chain(&row.moved).all(|c| c.is_finite())
                    && row.weight.is_finite()
                    && row.weight > 0.0
            })
            .collect()
    };
    (with(surface), with(point))
}

/// The conditioning of the surfaces under a sample (see the module documentation); fewer than
/// 6 rows give 0.
pub(crate) fn surface_conditioning(rows: &[SurfaceRow]) -> PlaneConditioning {
    // Six unknowns: fewer rows cannot fix them all.
    if rows.len() < 6 {
        return PlaneConditioning {
            ratio: 0.0,
            loosest: None,
        };
    }
    let weights: Vec<f64> = rows.iter().map(|row| row.weight).collect();
    plane_conditioning_by(rows.len(), |i| rows[i].moved, |i| rows[i].normal, &weights)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::LooseDirection;
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
        conditioning_and_direction_of(points, weight).ratio
    }

    fn conditioning_and_direction_of(points: &[Point], weight: f64) -> PlaneConditioning {
        let target = PreparedTarget::new(points, None, &PrepareOptions::default()).unwrap();
        let workers = Workers::new(1).unwrap();
        let pairs: Vec<SurfacePair> = (0..target.points().len())
            .map(|t| SurfacePair {
                moved: target.points()[t],
                target: t as u32,
                weight,
                row: t,
            })
            .collect();
        surface_conditioning(&surface_sample(&pairs, &target, &workers).0)
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
        let sliding = conditioning_and_direction_of(&faces(&corridor), 1.0);
        assert!(sliding.ratio < 1e-6);
        // Floor and walls normal to z and y: the corridor runs along x.
        match sliding.loosest {
            Some(LooseDirection::Translation(axis)) => assert!(axis[0] > 0.999, "{axis:?}"),
            other => panic!("corridor: {other:?}"),
        }
        assert!(conditioning_of(&faces(&[Z]), 1.0) < 1e-6);
    }

    /// Four walls around z, no floor or ceiling: the translation along z is free.
    #[test]
    fn walls_alone_leave_the_vertical_free() {
        let walls = [X, Y, X.map(|c| -c), Y.map(|c| -c)];
        let loose = conditioning_and_direction_of(&faces(&walls), 1.0);
        assert!(loose.ratio < 1e-6);
        match loose.loosest {
            Some(LooseDirection::Translation(axis)) => assert!(axis[2] > 0.999, "{axis:?}"),
            other => panic!("walls: {other:?}"),
        }
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
            row: t,
        };
        let conditioning = |pairs: &[SurfacePair], target: &PreparedTarget| {
            surface_conditioning(&surface_sample(pairs, target, &workers).0).ratio
        };
        let five: Vec<SurfacePair> = (0..5)
            .map(|t| pair(t * 1600, target.points()[t * 1600]))
            .collect();
        assert_eq!(conditioning(&five, &target), 0.0);
        assert_eq!(conditioning(&[], &target), 0.0);
        let mut all: Vec<SurfacePair> = (0..closed.len()).map(|t| pair(t, target.points()[t])).collect();
        let clean = conditioning(&all, &target);
        all[7].moved = [f64::NAN; 3];
        let with_nan = conditioning(&all, &target);
        assert!(with_nan.is_finite() && (with_nan - clean).abs() < 0.01 * clean);
        // Points on a line have no plane, hence no normal: every pair is left out.
        let line: Vec<Point> = (0..200).map(|i| [0.01 * i as f64, 0.0, 0.0]).collect();
        let target = PreparedTarget::new(&line, None, &PrepareOptions::default()).unwrap();
        let on_line: Vec<SurfacePair> = (0..line.len()).map(|t| pair(t, target.points()[t])).collect();
        assert_eq!(conditioning(&on_line, &target), 0.0);
    }

    /// Few rows: all of positive weight, as they are. Many: about SURFACE_PAIRS draws, in
    /// proportion to the weights (a row of weight 0.01 among rows of 1 is rarely drawn).
    #[test]
    fn surface_rows_are_drawn_in_proportion_to_their_weight() {
        let few = [0.9, 0.0, f64::NAN, 0.6, -1.0, 0.01];
        assert_eq!(surface_rows(&few), vec![(0, 0.9), (3, 0.6), (5, 0.01)]);
        let many: Vec<f64> = (0..4 * SURFACE_PAIRS)
            .map(|i| if i % 4 == 0 { 1.0 } else { 0.01 })
            .collect();
        let rows = surface_rows(&many);
        let draws: f64 = rows.iter().map(|r| r.1).sum();
        assert!((draws - SURFACE_PAIRS as f64).abs() <= 1.0, "{draws}");
        let on_inliers: f64 = rows.iter().filter(|r| r.0 % 4 == 0).map(|r| r.1).sum();
        assert!(on_inliers > 0.95 * draws, "{on_inliers} of {draws}");
        assert!(rows.windows(2).all(|w| w[0].0 < w[1].0));
        assert!(surface_rows(&[]).is_empty() && surface_rows(&[0.0; 10]).is_empty());
    }

    #[test]
    fn small_targets_get_smaller_neighbourhoods() {
        assert_eq!(surface_neighbours(361, 10), 10);
        assert_eq!(surface_neighbours(1_600, 10), 25);
        assert_eq!(surface_neighbours(20_000, 10), SURFACE_NEIGHBOURS);
        assert_eq!(surface_neighbours(20_000, 200), SURFACE_NEIGHBOURS);
        assert_eq!(surface_neighbours(100, 10), 10);
    }
}
