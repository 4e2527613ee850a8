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

    /// Copies are grouped (−0.0 equals 0.0), dropped points leave whole locations out, and
    /// every copy gets its location's results back; the share counts locations.
    use crate::registration::covariance::PoseUncertainty;
    use crate::registration::result::{Quality, SearchReport, StageTimes, StopReason};

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
        let working = RegistrationResult {
            transform: Matrix4::identity(),
            stop_reason: StopReason::Converged,
            converged: true,
            iterations: 1,
            sigma: vec![0.01],
            beta: vec![0.0001],
            penalty: 1.0,
            noise_shape: 2.0,
            inlier_fraction: 1.4 / 3.0,
            rmse: 0.01,
            probabilities: vec![0.9, 0.5, 0.0],
            correspondences: vec![4, -1, 1],
            histograms: Vec::new(),
            trace: Vec::new(),
            times: StageTimes::default(),
            search: SearchReport::default(),
            quality: Quality::default(),
            uncertainty: PoseUncertainty::UNKNOWN,
        };
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
