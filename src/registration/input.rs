//! Input rules shared by the registration entry points: counts, finite values, the initial
//! guess, per-point noise (§4.4), and dropping non-finite points on request.

use nalgebra::Matrix4;

use super::config::RegistrationConfig;
use super::result::RegistrationResult;
use crate::error::Error;
use crate::geometry::{first_non_finite, is_finite};
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

/// Maps per-point results of a registration on kept points back to the caller's indexing:
/// `source_kept[i]` is the original index of kept source point i, `target_kept` likewise for
/// target indices (`None`: target indices are unchanged).
pub(crate) fn expand(
    mut result: RegistrationResult,
    source_kept: &[u32],
    source_count: usize,
    target_kept: Option<&[u32]>,
) -> RegistrationResult {
    let mut probabilities = vec![0.0; source_count];
    let mut correspondences = vec![-1i64; source_count];
    for (k, &original) in source_kept.iter().enumerate() {
        probabilities[original as usize] = result.probabilities[k];
        let target = result.correspondences[k];
        correspondences[original as usize] = match target_kept {
            Some(map) if target >= 0 => map[target as usize] as i64,
            _ => target,
        };
    }
    let share = source_kept.len() as f64 / source_count.max(1) as f64;
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
