//! The units a registration computes in. The answer must not depend on the caller's units, but
//! floating point has a range: coordinates near 1e160 overflow when squared, near 1e-160 they
//! lose their precision in subnormals, and so do residuals divided by per-point noise scales of
//! such magnitudes. Input outside a safe range is moved into it (centred, divided by a length
//! and a noise unit), registered, and every number of the result is moved back. Input inside
//! the range is used as given (no copy, the results bit for bit as before).

use nalgebra::{Matrix4, Vector3};

use super::config::RegistrationConfig;
use super::result::{RegistrationResult, TraceEntry};
use crate::geometry::{from_parts, rotation_part, translation_part};
use crate::point::Point;
use crate::sie::WarmStart;

/// Coordinates, and noise scales, whose magnitudes lie in [1/SAFE, SAFE] are used as given:
/// squares of differences stay far from overflow and underflow.
const SAFE: f64 = 1e30;

/// Where a start beyond f64's range in these units is held (`transform_in`): far from clouds
/// of unit size, yet with residuals whose fourth powers (a normal matrix's eigen-solve squares
/// its entries) stay within f64's range.
const FAR_START: f64 = 1e50;

/// A change of units: p ↦ (p − centre) / length for coordinates, F ↦ F / noise for per-point
/// noise scales.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Units {
    centre: Vector3<f64>,
    length: f64,
    noise: f64,
}

impl Units {
    pub(crate) const IDENTITY: Units = Units {
        centre: Vector3::new(0.0, 0.0, 0.0),
        length: 1.0,
        noise: 1.0,
    };

    /// Units for these clouds (the target sets them: its per-axis median and the median
    /// distance of its points from it, robust to a few garbage points) and noise scales (their
    /// median).
    pub(crate) fn choose(source: &[Point], target: &[Point], sigmas: &[&[f64]]) -> Units {
        Units::of_lengths(source, target).with_noise_of(sigmas)
    }

    /// The length part of [`Units::choose`] (the noise unit 1).
    pub(crate) fn of_lengths(source: &[Point], target: &[Point]) -> Units {
        let largest = source
            .iter()
            .chain(target)
            .flat_map(|p| p.iter())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let mut units = Units::IDENTITY;
        if largest > SAFE || (largest > 0.0 && largest < 1.0 / SAFE) {
            let reference = if target.is_empty() { source } else { target };
            let centre = Vector3::from_fn(|axis, _| median(reference.iter().map(|p| p[axis]).collect()));
            let spread = median(
                reference
                    .iter()
                    .map(|p| {
                        // Scaled before squaring: no overflow at any magnitude.
                        let d = Vector3::new(p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]);
                        let m = d.amax();
                        if m > 0.0 { m * (d / m).norm() } else { 0.0 }
                    })
                    .collect(),
            );
            units.centre = centre;
            let length = if spread.is_finite() && spread > 0.0 {
                spread
            } else {
                largest
            };
            // No coordinate may leave f64's range in these units: |p − centre| ≤ 2·largest (the
            // centre is a median of coordinates), so a garbage point near ±f64::MAX stays finite
            // (an outlier) among clouds whose spread is small.
            units.length = length.max(largest / (f64::MAX / 8.0));
        }
        units
    }

    /// These units with the noise unit set by the noise scales (their median), when it lies
    /// outside the safe range.
    pub(crate) fn with_noise_of(mut self, sigmas: &[&[f64]]) -> Units {
        let all: Vec<f64> = sigmas.iter().flat_map(|s| s.iter().copied()).collect();
        if !all.is_empty() {
            let typical = median(all);
            if !(1.0 / SAFE..=SAFE).contains(&typical) {
                self.noise = typical;
            }
        }
        self
    }

    /// A point in these units back in the caller's.
    pub(crate) fn point_out(&self, p: &Point) -> Point {
        std::array::from_fn(|axis| p[axis] * self.length + self.centre[axis])
    }

    /// A length in these units back in the caller's.
    pub(crate) fn length_out(&self, length: f64) -> f64 {
        length * self.length
    }

    pub(crate) fn is_identity(&self) -> bool {
        *self == Units::IDENTITY
    }

    /// Points in these units.
    pub(crate) fn points(&self, points: &[Point]) -> Vec<Point> {
        points
            .iter()
            .map(|p| {
                std::array::from_fn(|axis| {
                    let offset = p[axis] - self.centre[axis];
                    // Apart the difference of two coordinates near ±f64::MAX can overflow.
                    if offset.is_finite() {
                        offset / self.length
                    } else {
                        p[axis] / self.length - self.centre[axis] / self.length
                    }
                })
            })
            .collect()
    }

    /// Noise scales in these units.
    pub(crate) fn sigmas(&self, sigmas: Option<Vec<f64>>) -> Option<Vec<f64>> {
        sigmas.map(|s| s.into_iter().map(|v| v / self.noise).collect())
    }

    /// A transform between the caller's frames, in these units: N·T·N⁻¹.
    pub(crate) fn transform_in(&self, t: &Matrix4<f64>) -> Matrix4<f64> {
        let r = rotation_part(t);
        let translation = (r * self.centre + translation_part(t) - self.centre) / self.length;
        // A guess farther than f64's range from clouds this small: a start as hopeless (and as
        // far, for the search) at ±FAR_START, where its residuals' squares stay finite.
        let translation = translation.map(|v| if v.is_finite() { v } else { FAR_START.copysign(v) });
        from_parts(&r, &translation)
    }

    /// A transform in these units back in the caller's: N⁻¹·T·N.
    pub(crate) fn transform_out(&self, t: &Matrix4<f64>) -> Matrix4<f64> {
        let r = rotation_part(t);
        let translation = translation_part(t) * self.length + self.centre - r * self.centre;
        from_parts(&r, &translation)
    }

    /// A config in these units (the warm start's σ is a residual).
    pub(crate) fn config_in(&self, config: &RegistrationConfig) -> RegistrationConfig {
        let residual = self.length * self.noise;
        RegistrationConfig {
            warm_start: config.warm_start.map(|warm| WarmStart {
                sigma: warm.sigma / residual,
                ..warm
            }),
            ..config.clone()
        }
    }

    /// A trace entry in the caller's units.
    pub(crate) fn entry_out(&self, entry: &mut TraceEntry) {
        let residual = self.length * self.noise;
        entry.sigma *= residual;
        entry.beta *= residual;
        entry.rmse *= self.length;
        entry.translation_change *= self.length;
        entry.transform = self.transform_out(&entry.transform);
    }

    /// Every length of a result in the caller's units (σ, β and the histograms are in units of
    /// the noise-normalised residual: length / noise unit).
    pub(crate) fn result_out(&self, result: &mut RegistrationResult) {
        let residual = self.length * self.noise;
        result.transform = self.transform_out(&result.transform);
        result.uncertainty = result.uncertainty.in_frame(self.length, &self.centre);
        for v in result.sigma.iter_mut().chain(&mut result.beta) {
            *v *= residual;
        }
        result.rmse *= self.length;
        for model in &mut result.histograms {
            model.inlier.sigma *= residual;
            model.inlier.mu *= residual;
            model.beta *= residual;
            model.lo *= residual;
            model.hi *= residual;
        }
        for entry in &mut result.trace {
            self.entry_out(entry);
        }
    }
}

/// Median of the values (NaN-free input; 0 for none).
fn median(mut values: Vec<f64>) -> f64 {
    crate::median::median(&mut values).unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Translation3};

    #[test]
    fn transforms_round_trip() {
        let units = Units {
            centre: Vector3::new(1e160, -2e160, 3e159),
            length: 5e158,
            noise: 1.0,
        };
        let t = Translation3::new(3e159, 1e158, -2e159).to_homogeneous()
            * Rotation3::from_euler_angles(0.1, -0.4, 1.2).to_homogeneous();
        let back = units.transform_out(&units.transform_in(&t));
        let scale = t.abs().max();
        assert!((back - t).abs().max() <= 1e-14 * scale, "{back} vs {t}");
    }

    #[test]
    fn moderate_input_is_left_alone() {
        let points = vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]];
        assert!(Units::choose(&points, &points, &[&[1e-3, 2e-3]]).is_identity());
        assert!(!Units::choose(&points, &points, &[&[1e-160]]).is_identity());
        let huge = vec![[1e77, 0.0, 0.0], [0.0, 1e77, 0.0]];
        assert!(!Units::choose(&huge, &huge, &[]).is_identity());
    }
}
