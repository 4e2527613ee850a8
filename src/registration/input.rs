//! Input rules shared by the registration entry points: counts, finite values, the initial
//! guess, per-point noise (§4.4), and dropping non-finite points on request.

use nalgebra::Matrix4;

use super::config::RegistrationConfig;
use super::result::RegistrationResult;
use crate::error::Error;
use crate::geometry::{first_non_finite, is_finite};
use crate::nn::{Locations, distinct_locations};
use crate::noise::{CloudRole, NoiseModel, NoiseScales, cloud_sigmas};
use crate::point::{NonFinite, Point};

/// Which points the caller asked to drop before registering (`non_finite`, `skip_origin`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Skip {
    pub(crate) non_finite: NonFinite,
    /// Points at exactly 0 0 0 (0.0 == -0.0): depth sensors' invalid pixels.
    pub(crate) origin: bool,
}

impl Skip {
    pub(crate) fn of(config: &RegistrationConfig) -> Self {
        Skip {
            non_finite: config.non_finite,
            origin: config.skip_origin,
        }
    }

    /// Whether any point can be dropped.
    pub(crate) fn any(&self) -> bool {
        self.non_finite == NonFinite::Skip || self.origin
    }

    /// Whether a point survives.
    pub(crate) fn keeps(&self, p: &Point) -> bool {
        (self.non_finite == NonFinite::Reject || is_finite(p)) && !(self.origin && *p == [0.0; 3])
    }

    /// Indices of the points kept, or `None` when every point is (nothing to copy).
    pub(crate) fn kept_indices(&self, points: &[Point]) -> Option<Vec<u32>> {
        if !self.any() || points.iter().all(|p| self.keeps(p)) {
            return None;
        }
        Some(
            (0..points.len() as u32)
                .filter(|&i| self.keeps(&points[i as usize]))
                .collect(),
        )
    }
}

/// The caller's points a registration works on when that is not simply all of them: the ones
/// [`Skip`] keeps, each distinct location once. A block of identical points (a LiDAR's missing
/// returns written as 0 0 0, a cloud that stores every point twice) is one location's evidence:
/// counted N times, its N equal residuals would be a spike SIE fits as the inliers (σ at the
/// rounding level, the pose held where the block matches itself), and a cloud's spacing would
/// be 0. Every copy still gets its location's per-point results.
pub(crate) struct Selection {
    /// The caller's index of each working point (its location's first copy), ascending.
    first: Vec<u32>,
    /// The caller's points grouped by location and the location of each working point; `None`
    /// when no kept point has a copy.
    copies: Option<(Locations, Vec<u32>)>,
    /// Distinct locations among the caller's points, dropped ones included.
    locations: usize,
    /// The caller's points kept, copies included.
    kept_points: usize,
}

impl Selection {
    /// The selection of `points` under `skip`, or `None` when it is every point (nothing to
    /// copy or map). One hash pass over the points when nothing repeats.
    ///
    /// Errors: more than u32::MAX − 1 points ([`Error::InvalidArgument`], `what` names the
    /// cloud), no memory for the grouping ([`Error::OutOfMemory`]).
    pub(crate) fn of(points: &[Point], skip: Skip, what: &str) -> Result<Option<Selection>, Error> {
        if points.len() >= u32::MAX as usize {
            return Err(Error::InvalidArgument(format!(
                "{what} has {} points; at most {} are supported",
                points.len(),
                u32::MAX - 1
            )));
        }
        let Some(locations) = distinct_locations(points)? else {
            return Ok(skip
                .kept_indices(points)
                .map(|kept| Selection::of_kept(kept, points.len())));
        };
        let count = locations.count();
        let kept: Vec<u32> = (0..count as u32)
            .filter(|&l| skip.keeps(&points[locations.of(l)[0] as usize]))
            .collect();
        let first = kept.iter().map(|&l| locations.of(l)[0]).collect();
        let kept_points = kept.iter().map(|&l| locations.of(l).len()).sum();
        Ok(Some(Selection {
            first,
            copies: Some((locations, kept)),
            locations: count,
            kept_points,
        }))
    }

    /// The points `kept` (the caller's indices, ascending) of `given`, none of them a copy of
    /// another.
    pub(crate) fn of_kept(kept: Vec<u32>, given: usize) -> Selection {
        Selection {
            kept_points: kept.len(),
            first: kept,
            copies: None,
            locations: given,
        }
    }

    /// The caller's points kept, copies included (what "too few points" is judged by).
    pub(crate) fn kept_points(&self) -> usize {
        self.kept_points
    }

    /// The caller's index of each working point.
    pub(crate) fn first(&self) -> &[u32] {
        &self.first
    }

    /// [`Selection::first`], the rest dropped.
    pub(crate) fn into_first(self) -> Vec<u32> {
        self.first
    }

    /// Working points over the caller's distinct locations: what an inlier fraction over the
    /// working points is scaled by, so that dropped locations count 0.
    pub(crate) fn share(&self) -> f64 {
        self.first.len() as f64 / self.locations.max(1) as f64
    }

    /// The caller's indices of working point `k` and its copies.
    fn copies_of(&self, k: usize) -> &[u32] {
        match &self.copies {
            Some((locations, kept)) => locations.of(kept[k]),
            None => std::slice::from_ref(&self.first[k]),
        }
    }
}

/// Maps per-point results of a registration on the working points of `source` back to the
/// caller's indexing (every copy of a location gets its results; dropped points probability 0
/// and no match): `target_first` maps working target indices to the caller's (`None`:
/// unchanged).
pub(crate) fn expand(
    mut result: RegistrationResult,
    source: &Selection,
    source_count: usize,
    target_first: Option<&[u32]>,
) -> RegistrationResult {
    let mut probabilities = vec![0.0; source_count];
    let mut correspondences = vec![-1i64; source_count];
    for k in 0..source.first.len() {
        let target = match (result.correspondences[k], target_first) {
            (t, Some(map)) if t >= 0 => map[t as usize] as i64,
            (t, _) => t,
        };
        for &original in source.copies_of(k) {
            probabilities[original as usize] = result.probabilities[k];
            correspondences[original as usize] = target;
        }
    }
    let share = source.share();
    result.inlier_fraction *= share;
    for entry in &mut result.trace {
        entry.inlier_fraction *= share;
    }
    result.probabilities = probabilities;
    result.correspondences = correspondences;
    result
}

pub(crate) fn require_points(what: &str, count: usize, minimum: usize) -> Result<(), Error> {
    if count < minimum {
        return Err(Error::TooFewPoints(format!(
            "{what}: {count} given, at least {minimum} needed"
        )));
    }
    Ok(())
}

pub(crate) fn require_finite(what: &str, points: &[Point]) -> Result<(), Error> {
    match first_non_finite(points) {
        None => Ok(()),
        Some(i) => Err(Error::NonFinite(format!(
            "{what}[{i}] = {:?} is not finite",
            points[i]
        ))),
    }
}

/// Clouds whose spreads (RMS distance of the points from their centroid) differ this many times
/// are checked for a scale at which they cannot meet ([`require_meeting_scales`]).
const SCALE_GAP: f64 = 20.0;
/// Spreads this many times apart are checked for a smaller cloud that fits between two points
/// of the larger (a few points close together are a legitimate source below it).
const FIT_GAP: f64 = 100.0;
/// A smaller cloud that reaches no further than this many of the larger cloud's spacings from
/// its centre, and is sampled as finely for its size as the larger one, is a scaled copy.
const COPY_REACH: f64 = 10.0;
/// Resolutions (spacing over spread) within this factor of each other count as the same.
const COPY_RESOLUTION: f64 = 3.0;
/// Points a cloud's spread is taken over (evenly strided, as the prepared target's).
const SPREAD_SAMPLE: usize = 1024;
/// Source points whose nearest other source point gives the source's spacing, when needed.
const SPACING_SAMPLE: usize = 32;

/// One cloud as [`require_meeting_scales`] compares it, in the caller's units.
struct Scale {
    role: &'static str,
    spread: f64,
    spacing: f64,
}

/// Refuses clouds that cannot meet at any pose because they are in different units. Checked
/// only when the spreads differ [`SCALE_GAP`] times; the spacings and the smaller cloud's
/// radius are computed (the target's spacing asked for) only then. Two cases:
/// - the spreads differ [`FIT_GAP`] times and every point of the smaller cloud lies within half
///   a spacing of its centre: the whole of it fits between two neighbouring points of the other
///   (millimetres against metres);
/// - the smaller cloud reaches only [`COPY_REACH`] of the larger's spacings, and its points lie
///   as close for its size as the larger's do ([`COPY_RESOLUTION`]): the two are the same kind
///   of cloud at two scales (centimetres or inches against metres). A small piece of a scene
///   is sampled far more finely for its size than the scene, and a dense small object in a
///   sparse map covers many of the map's spacings, so neither is refused.
///
/// The target's points are in units `target_length` times the caller's (the prepared target's);
/// the message speaks the caller's. Error: [`Error::InvalidArgument`] naming both scales.
pub(crate) fn require_meeting_scales(
    source: &[Point],
    target: &[Point],
    target_length: f64,
    target_spacing: impl FnOnce() -> f64,
) -> Result<(), Error> {
    let source_spread = spread(source);
    let target_spread = target_length * spread(target);
    let source_is_smaller = source_spread < target_spread;
    let (small_spread, large_spread) = if source_is_smaller {
        (source_spread, target_spread)
    } else {
        (target_spread, source_spread)
    };
    if !(small_spread > 0.0 && large_spread >= SCALE_GAP * small_spread) {
        return Ok(());
    }
    let small_radius = if source_is_smaller {
        radius(source)
    } else {
        target_length * radius(target)
    };
    let source = Scale {
        role: "source",
        spread: source_spread,
        spacing: sampled_spacing(source),
    };
    let target = Scale {
        role: "target",
        spread: target_spread,
        spacing: target_spacing(),
    };
    let (small, large) = if source_is_smaller {
        (source, target)
    } else {
        (target, source)
    };
    let (role, other) = (small.role, large.role);
    if large_spread >= FIT_GAP * small_spread && 2.0 * small_radius < large.spacing {
        return Err(Error::InvalidArgument(format!(
            "every {role} point lies within {:.3e} of the {role}'s centre, and the {other}'s \
             points lie {:.3e} apart: the whole {role} fits between two {other} points, so \
             no pose can match it; are both clouds in the same units (millimetres against metres)?",
            small_radius, large.spacing
        )));
    }
    let resolutions = (small.spacing / small.spread) / (large.spacing / large.spread);
    if small_radius < COPY_REACH * large.spacing
        && (1.0 / COPY_RESOLUTION..=COPY_RESOLUTION).contains(&resolutions)
    {
        return Err(Error::InvalidArgument(format!(
            "the {role} spreads {:.0}x less than the {other} ({:.3e} against {:.3e}) and its \
             points lie {:.0}x closer ({:.3e} against {:.3e} apart): the same kind of cloud at \
             two scales, the whole {role} within {:.1} of the {other}'s spacings; are both \
             clouds in the same units (centimetres or inches against metres)?",
            large.spread / small.spread,
            small.spread,
            large.spread,
            large.spacing / small.spacing,
            small.spacing,
            large.spacing,
            small_radius / large.spacing
        )));
    }
    Ok(())
}

/// The centroid of `points` in units of their largest coordinate (so that sums and squares
/// cannot overflow or vanish at any magnitude), with that unit; `None` for no extent to measure.
fn scaled_centre<'a>(points: impl Iterator<Item = &'a Point> + Clone) -> Option<([f64; 3], f64)> {
    let unit = points
        .clone()
        .flat_map(|p| p.iter())
        .fold(0.0, |m: f64, c| m.max(c.abs()));
    let n = points.clone().count() as f64;
    if n == 0.0 || !(unit > 0.0 && unit.is_finite()) {
        return None;
    }
    let centre = std::array::from_fn(|a| points.clone().map(|p| p[a] / unit).sum::<f64>() / n);
    Some((centre, unit))
}

fn squared_offset(p: &Point, centre: &[f64; 3], unit: f64) -> f64 {
    (0..3).map(|a| (p[a] / unit - centre[a]).powi(2)).sum()
}

/// RMS distance of `points` from their centroid, over at most [`SPREAD_SAMPLE`] evenly strided
/// points (0 for none).
fn spread(points: &[Point]) -> f64 {
    let step = points.len().div_ceil(SPREAD_SAMPLE).max(1);
    let sample = points.iter().step_by(step);
    let Some((centre, unit)) = scaled_centre(sample.clone()) else {
        return 0.0;
    };
    let n = sample.clone().count() as f64;
    unit * (sample.map(|p| squared_offset(p, &centre, unit)).sum::<f64>() / n).sqrt()
}

/// The largest distance of a point of `points` from their centroid (0 for none).
fn radius(points: &[Point]) -> f64 {
    let Some((centre, unit)) = scaled_centre(points.iter()) else {
        return 0.0;
    };
    unit * points
        .iter()
        .map(|p| squared_offset(p, &centre, unit))
        .fold(0.0, f64::max)
        .sqrt()
}

/// Median distance from [`SPACING_SAMPLE`] evenly strided points to their nearest other point
/// (at another place), by brute force: no index is built for a check that rarely runs.
fn sampled_spacing(points: &[Point]) -> f64 {
    let Some((_, unit)) = scaled_centre(points.iter()) else {
        return 0.0;
    };
    let step = points.len().div_ceil(SPACING_SAMPLE).max(1);
    let mut gaps: Vec<f64> = points
        .iter()
        .step_by(step)
        .filter_map(|p| {
            points
                .iter()
                .filter(|q| *q != p)
                .map(|q| (0..3).map(|a| ((p[a] - q[a]) / unit).powi(2)).sum::<f64>())
                .min_by(f64::total_cmp)
                .map(|squared| unit * squared.sqrt())
        })
        .collect();
    crate::median::median(&mut gaps).unwrap_or(0.0)
}

/// How far a given normal's length may be from 1.
pub const NORMAL_LENGTH_TOLERANCE: f64 = 1e-3;

/// Given normals (point-to-plane's target normals) must be unit vectors, within
/// [`NORMAL_LENGTH_TOLERANCE`], or exactly 0 0 0 for a point without one (never matched). The one
/// rule for every entry point (Rust API, C ABI, CLI); non-finite normals are left to the
/// non-finite rule (refused, or "no normal" with [`NonFinite::Skip`]). The error names
/// `what[index]` and the length found.
pub fn require_unit_normals(what: &str, normals: &[Point]) -> Result<(), Error> {
    for (index, normal) in normals.iter().enumerate().filter(|(_, n)| is_finite(n)) {
        let length = normal.iter().map(|v| v * v).sum::<f64>().sqrt();
        if length != 0.0 && (length - 1.0).abs() > NORMAL_LENGTH_TOLERANCE {
            return Err(Error::InvalidArgument(format!(
                "{what}[{index}] has length {length}; normals must be unit vectors (or 0 0 0 for none)"
            )));
        }
    }
    Ok(())
}

/// The initial guess must be a rigid transform (`geometry::check_rigid`); it is then projected
/// exactly onto SO(3).
pub fn checked_initial_guess(init: Option<&Matrix4<f64>>) -> Result<Matrix4<f64>, Error> {
    let Some(t) = init else {
        return Ok(Matrix4::identity());
    };
    crate::geometry::check_rigid(t, "initial guess").map_err(Error::InvalidArgument)?;
    Ok(crate::geometry::orthonormalised(t))
}

/// The per-point σ that were given, for `Units::choose`.
pub(crate) fn sigma_slices<'a>(source: &'a Option<Vec<f64>>, target: &'a Option<Vec<f64>>) -> Vec<&'a [f64]> {
    [source, target]
        .into_iter()
        .flatten()
        .map(Vec::as_slice)
        .collect()
}

/// Per-point σ of both clouds (§4.4), or `None` when noise is constant.
pub(crate) type Sigmas = (Option<Vec<f64>>, Option<Vec<f64>>);

pub(crate) fn noise_sigmas(
    config: &RegistrationConfig,
    callback: Option<&mut dyn NoiseScales>,
    source: &[Point],
    target: &[Point],
) -> Result<Sigmas, Error> {
    let mut builtin = config.noise;
    let scales: &mut dyn NoiseScales = match callback {
        Some(cb) => cb,
        None if config.noise == NoiseModel::Constant => return Ok((None, None)),
        None => &mut builtin,
    };
    let s = cloud_sigmas(scales, CloudRole::Source, source).map_err(Error::Callback)?;
    let t = cloud_sigmas(scales, CloudRole::Target, target).map_err(Error::Callback)?;
    Ok((Some(s), Some(t)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` points evenly along x over [0, length), at `x0`.
    fn segment(n: usize, length: f64, x0: f64) -> Vec<Point> {
        (0..n)
            .map(|k| [x0 + length * k as f64 / n as f64, 0.0, 0.0])
            .collect()
    }

    #[test]
    fn clouds_that_fit_between_two_points_of_the_other_are_refused_and_only_they() {
        // The target: 2000 points over [0, 1) (spacing 5e-4, spread 0.289).
        let target = segment(2000, 1.0, 0.0);
        let within = |source: &[Point]| require_meeting_scales(source, &target, 1.0, || 5e-4);
        // 10 points over 4e-4 (radius 2e-4): between two target points.
        let error = within(&segment(10, 4e-4, 0.5)).unwrap_err();
        assert!(
            matches!(&error, Error::InvalidArgument(m) if m.starts_with("every source point lies within 1.8")
                && m.contains("apart: the whole source fits") && m.contains("same units")),
            "{error:?}"
        );
        // 10 points over 2e-3 (spread 5.7e-4, 500 times smaller than the target's, radius 9e-4):
        // a piece of it a few target points cover.
        within(&segment(10, 2e-3, 0.5)).unwrap();
        // Spreads within SCALE_GAP of each other: the target's spacing is not even asked for.
        require_meeting_scales(&segment(100, 0.1, 0.0), &target, 1.0, || panic!("asked")).unwrap();
        // The other way round: the target (radius 1.8e-4 in the caller's units, held at 1/1000)
        // between two points of a source of 100 points over 1000 (spacing 10).
        let held = segment(10, 0.4, 0.0);
        let error = require_meeting_scales(&segment(100, 1000.0, 0.0), &held, 1e-3, || 4e-5).unwrap_err();
        assert!(
            matches!(&error, Error::InvalidArgument(m) if m.starts_with("every target point lies within 1.800e-4")
                && m.contains("the source's points lie 1.000e1 apart")),
            "{error:?}"
        );
        // Held at 30 times: its radius (5.4) reaches past half a source spacing, and its 10
        // points lie 10 times as far apart for its size as the source's 100.
        require_meeting_scales(&segment(100, 1000.0, 0.0), &held, 30.0, || 1.2).unwrap();
        // No extent to compare: left to the other rules.
        require_meeting_scales(&[[1.0; 3]; 5], &target, 1.0, || panic!("asked")).unwrap();
    }

    /// `n` × `n` points evenly over a square of side `side` in the xy plane.
    fn grid(n: usize, side: f64) -> Vec<Point> {
        let step = side / (n - 1) as f64;
        (0..n * n)
            .map(|k| [step * (k % n) as f64, step * (k / n) as f64, 0.0])
            .collect()
    }

    #[test]
    fn a_scaled_copy_is_refused_and_a_piece_or_a_small_cloud_is_not() {
        // The target: 60 × 60 points over 1 (spacing 1/59, spread 0.41, radius 0.71).
        let target = grid(60, 1.0);
        let spacing = 1.0 / 59.0;
        let within = |source: &[Point]| require_meeting_scales(source, &target, 1.0, || spacing);
        // The same square at 25 times its size: the target reaches 1.7 of its spacings.
        let error = within(&grid(60, 25.0)).unwrap_err();
        assert!(
            matches!(&error, Error::InvalidArgument(m) if m.starts_with("the target spreads 25x less than the source")
                && m.contains("points lie 25x closer") && m.contains("within 1.7 of the source's spacings")
                && m.contains("same units")),
            "{error:?}"
        );
        // Either way round, and held in other units.
        let held: Vec<Point> = target.iter().map(|p| p.map(|c| c * 1e3)).collect();
        let error = require_meeting_scales(&grid(60, 1.0 / 25.0), &held, 1e-3, || spacing).unwrap_err();
        assert!(
            matches!(&error, Error::InvalidArgument(m) if m.starts_with("the source spreads 25x less than the target")),
            "{error:?}"
        );
        // At 50 times with 2.5 times as many points a side: sampled 2.5 times more finely for its
        // size, within COPY_RESOLUTION (the target reaches 2.1 of its spacings).
        within(&grid(150, 50.0)).unwrap_err();
        // Ten times as many points a side at 25 times: sampled 10 times more finely for its size
        // (the target reaches 17 of its spacings).
        within(&grid(600, 25.0)).unwrap();
        // A piece of the target's own sampling (3 × 3 points): far coarser for its size.
        within(&grid(3, 2.0 * spacing)).unwrap();
        // Three points far apart against the square (34 times its spread), and three points
        // closer than its spacing (88 times less): both under FIT_GAP, neither a copy.
        within(&[[0.0; 3], [30.0, 0.0, 0.0], [0.0, 30.0, 0.0]]).unwrap();
        within(&[[0.0; 3], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]]).unwrap();
        // At 10 times the spreads are within SCALE_GAP: nothing is measured.
        require_meeting_scales(&grid(60, 10.0), &target, 1.0, || panic!("asked")).unwrap();
    }

    /// Copies are grouped (−0.0 equals 0.0), dropped points leave whole locations out, and
    /// every copy gets its location's results back; the share counts locations.
    #[test]
    fn selection_keeps_each_location_once_and_expands_to_every_copy() {
        let a = [1.0, 2.0, 3.0];
        let b = [4.0, 5.0, 6.0];
        let points = [
            a,
            [0.0; 3],
            b,
            a,
            [f64::NAN; 3],
            [-0.0, 0.0, 0.0],
            a,
            [7.0, 8.0, 9.0],
        ];
        let skip = Skip {
            non_finite: NonFinite::Skip,
            origin: true,
        };
        let selection = Selection::of(&points, skip, "source").unwrap().unwrap();
        assert_eq!(selection.first(), &[0, 2, 7]);
        assert_eq!(selection.kept_points(), 5);
        // Locations: a, origin, b, NaN, (7, 8, 9); three kept.
        assert_eq!(selection.share(), 3.0 / 5.0);
        let working = RegistrationResult::with_points(vec![0.9, 0.5, 0.0], vec![4, -1, 1], 1.4 / 3.0);
        let target_first = [3, 6, 9, 12, 15];
        let expanded = expand(working, &selection, points.len(), Some(&target_first));
        assert_eq!(expanded.probabilities, [0.9, 0.0, 0.5, 0.9, 0.0, 0.0, 0.9, 0.0]);
        assert_eq!(expanded.correspondences, [15, -1, -1, 15, -1, -1, 15, 6]);
        assert!((expanded.inlier_fraction - 1.4 / 5.0).abs() < 1e-15);

        let nothing_dropped = Skip {
            non_finite: NonFinite::Reject,
            origin: false,
        };
        assert!(
            Selection::of(&[a, b, [0.0; 3]], nothing_dropped, "source")
                .unwrap()
                .is_none()
        );
        let twice = Selection::of(&[a, b, a, b], nothing_dropped, "source")
            .unwrap()
            .unwrap();
        assert_eq!(
            (twice.first(), twice.kept_points(), twice.share()),
            (&[0, 1][..], 4, 1.0)
        );
    }

    #[test]
    fn unit_normals_rule() {
        let unit = [0.0, 0.6, 0.8];
        assert_eq!(
            require_unit_normals("n", &[unit, [0.0; 3], [1.0 + 5e-4, 0.0, 0.0]]),
            Ok(())
        );
        // Non-finite normals are the non-finite rule's concern (refused, or "no normal").
        assert_eq!(
            require_unit_normals("n", &[[f64::NAN, 0.0, 0.0], [0.0, f64::INFINITY, 0.0]]),
            Ok(())
        );
        let error = require_unit_normals("target normals", &[unit, unit, [0.0, 0.0, 0.5]]).unwrap_err();
        assert!(
            matches!(&error, Error::InvalidArgument(m) if m.starts_with("target normals[2] has length 0.5")),
            "{error}"
        );
    }
}
