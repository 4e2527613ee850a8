//! Noise normalisation (§4.4): each residual is divided by a per-correspondence scale F(i)
//! before the histogram is built, so every inlier shares one σ.
//!
//! Scales come per point and per cloud, each in that cloud's own sensor frame; a correspondence
//! (source i, target j) combines them as the sum of variances, F = sqrt(σ_s(i)² + σ_t(j)²)
//! ("the variance of the resulting residual is the sum of the variances of the two").

/// Which cloud a batch of points belongs to (also the C callback's `cloud` argument).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CloudRole {
    /// The source cloud (the one moved onto the target).
    Source = 0,
    /// The target cloud.
    Target = 1,
}

/// Built-in per-point noise models.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseModel {
    /// Same noise everywhere: no normalisation (F = 1), σ is in input units.
    Constant,
    /// Structured-light / ToF depth cameras: σ ∝ z² (§6, PrimeSense), z the coordinate along
    /// the optical axis in the cloud's own frame.
    QuadraticDepth,
}

/// Smallest per-point σ the quadratic model returns (|z| below 1 mm is not a valid depth).
const MIN_DEPTH_SIGMA: f64 = 1e-6;

/// Supplies per-point relative noise σ for a whole cloud in one call (never per point).
pub trait NoiseScales {
    /// Fills `out[i]` with the relative noise σ of `points[i]` (given in that cloud's own
    /// frame). The points are the ones the registration works on: dropped ones are left out
    /// and ICP gives a location the cloud holds several times once. Values must be finite and
    /// > 0; an `Err` aborts the registration.
    fn point_sigmas(&mut self, cloud: CloudRole, points: &[[f64; 3]], out: &mut [f64]) -> Result<(), String>;
}

impl NoiseScales for NoiseModel {
    fn point_sigmas(
        &mut self,
        _cloud: CloudRole,
        points: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), String> {
        match self {
            NoiseModel::Constant => out.fill(1.0),
            NoiseModel::QuadraticDepth => {
                for (o, p) in out.iter_mut().zip(points) {
                    *o = (p[2] * p[2]).max(MIN_DEPTH_SIGMA);
                }
            }
        }
        Ok(())
    }
}

/// Asks `scales` for one cloud's σ and checks them. Errors name the first bad index.
pub fn cloud_sigmas(
    scales: &mut dyn NoiseScales,
    cloud: CloudRole,
    points: &[[f64; 3]],
) -> Result<Vec<f64>, String> {
    let mut out = vec![f64::NAN; points.len()];
    scales.point_sigmas(cloud, points, &mut out)?;
    if let Some((i, v)) = out
        .iter()
        .enumerate()
        .find(|(_, v)| !(v.is_finite() && **v > 0.0))
    {
        let name = match cloud {
            CloudRole::Source => "source",
            CloudRole::Target => "target",
        };
        return Err(format!(
            "noise scale sigma[{i}] of the {name} cloud is {v}; scales must be finite and > 0"
        ));
    }
    Ok(out)
}

/// F for a correspondence from the two points' σ: the residual's variance is the sum.
#[inline]
pub fn combine(source_sigma: f64, target_sigma: f64) -> f64 {
    (source_sigma * source_sigma + target_sigma * target_sigma).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_depth_is_z_squared_and_combines_as_variances() {
        let pts = [[0.0, 0.0, 2.0], [1.0, 1.0, -3.0]];
        let s = cloud_sigmas(&mut NoiseModel::QuadraticDepth, CloudRole::Source, &pts).unwrap();
        assert_eq!(s, vec![4.0, 9.0]);
        assert!((combine(3.0, 4.0) - 5.0).abs() < 1e-15);
    }

    #[test]
    fn bad_scales_are_reported_with_index() {
        struct Bad;
        impl NoiseScales for Bad {
            fn point_sigmas(&mut self, _: CloudRole, _: &[[f64; 3]], out: &mut [f64]) -> Result<(), String> {
                out.fill(1.0);
                out[2] = 0.0;
                Ok(())
            }
        }
        let err = cloud_sigmas(&mut Bad, CloudRole::Target, &[[0.0; 3]; 4]).unwrap_err();
        assert!(err.contains("sigma[2] of the target cloud"), "{err}");
    }
}
