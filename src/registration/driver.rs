//! The IRLS driver: β annealing (§4.3), adaptive k (§4.5), convergence and stop reasons.
use nalgebra::Matrix4;

use super::{Error, InlierEstimate, Point, RegistrationConfig, RegistrationResult};
use crate::noise::NoiseScales;
use crate::sie::SieOptions;

/// Registers matched pairs: `source[i]` corresponds to `target[i]` (point-to-point).
pub fn register_correspondences(
    source: &[Point],
    target: &[Point],
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    noise: Option<&mut dyn NoiseScales>,
) -> Result<RegistrationResult, Error> {
    let _ = (source, target, init, config, noise);
    Err(Error::InvalidArgument("not implemented yet".into()))
}

/// ICP of `source` onto `target` (nearest-neighbour matching, kd-tree built once).
/// `target_normals` (unit, one per target point) are used for point-to-plane; without them
/// normals come from k-NN PCA on the target.
pub fn register_clouds(
    source: &[Point],
    target: &[Point],
    target_normals: Option<&[Point]>,
    init: Option<&Matrix4<f64>>,
    config: &RegistrationConfig,
    noise: Option<&mut dyn NoiseScales>,
) -> Result<RegistrationResult, Error> {
    let _ = (source, target, target_normals, init, config, noise);
    Err(Error::InvalidArgument("not implemented yet".into()))
}

/// SIE on a residual matrix (row-major rows × cols), each row divided by `row_scales[i]` when
/// given; β is the regulariser (0 for none). Fits with k = k₀, adapts k from P(I|H) and refits.
pub fn estimate_inliers(
    residuals: &[f64],
    cols: usize,
    row_scales: Option<&[f64]>,
    beta: f64,
    options: &SieOptions,
) -> Result<InlierEstimate, Error> {
    let _ = (residuals, cols, row_scales, beta, options);
    Err(Error::InvalidArgument("not implemented yet".into()))
}
