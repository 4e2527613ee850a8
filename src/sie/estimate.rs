//! SIE on its own (§4): the inlier probability of every row of a residual matrix, for callers
//! that do their own estimation (the C ABI's `sie_estimate_inliers`).

use super::{HistogramModel, SieEstimator, SieOptions};
use crate::error::Error;

/// Largest residual magnitude `estimate_inliers` accepts (see there).
const MAX_RESIDUAL: f64 = 1e140;

/// Standalone SIE fits a histogram: below this many rows there is no peak to fit, and the
/// answer (every P at its cap) would mean nothing.
pub const MIN_ESTIMATE_ROWS: usize = 10;

/// Standalone SIE on a residual matrix.
#[derive(Clone, Debug, PartialEq)]
pub struct InlierEstimate {
    /// P(I|R_i) per row.
    pub probabilities: Vec<f64>,
    /// One model per histogram.
    pub models: Vec<HistogramModel>,
    /// P(I): mean per-component posterior.
    pub prior: f64,
}

/// SIE on a residual matrix (row-major rows × cols), each row divided by `row_scales[i]` when
/// given; β is the regulariser (0 for none). Fits with k = k₀, then adapts k from P(I|H) and
/// refits (§4.5), and returns P(I|R_i) per row. Scaled residuals above 1e140 in magnitude are
/// refused (their squares would overflow in the fit).
pub fn estimate_inliers(
    residuals: &[f64],
    cols: usize,
    row_scales: Option<&[f64]>,
    beta: f64,
    options: &SieOptions,
) -> Result<InlierEstimate, Error> {
    options.validate().map_err(Error::InvalidArgument)?;
    if cols == 0 {
        return Err(Error::InvalidArgument("cols must be >= 1".into()));
    }
    if residuals.len() % cols != 0 {
        return Err(Error::InvalidArgument(format!(
            "{} residual values do not form rows of {cols}",
            residuals.len()
        )));
    }
    let rows = residuals.len() / cols;
    if rows == 0 {
        return Err(Error::TooFewPoints("residual rows: 0 given, at least 1 needed".into()));
    }
    if let Some(i) = residuals.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite(format!("residuals[{i}] is {}", residuals[i])));
    }
    if !(beta.is_finite() && beta >= 0.0) {
        return Err(Error::InvalidArgument(format!(
            "beta must be finite and >= 0, got {beta}"
        )));
    }
    let normalised: Vec<f64> = match row_scales {
        None => residuals.to_vec(),
        Some(scales) => {
            if scales.len() != rows {
                return Err(Error::InvalidArgument(format!(
                    "{} row scales for {rows} rows",
                    scales.len()
                )));
            }
            if let Some(i) = scales.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
                return Err(Error::InvalidArgument(format!(
                    "row_scales[{i}] is {}; scales must be finite and > 0",
                    scales[i]
                )));
            }
            residuals
                .chunks_exact(cols)
                .zip(scales)
                .flat_map(|(row, s)| row.iter().map(move |r| r / s))
                .collect()
        }
    };
    // Squares of the residuals are summed (RMS start, histogram moments): beyond this they
    // overflow and the fit would end with an infinite σ.
    if let Some(i) = normalised.iter().position(|v| v.abs() > MAX_RESIDUAL) {
        return Err(Error::InvalidArgument(format!(
            "residual {i} is {:e} after row scaling; magnitudes above {MAX_RESIDUAL:e} cannot be squared \
             and summed without overflow (rescale the residuals)",
            normalised[i]
        )));
    }
    // After every argument check, so that a bad argument is reported as such.
    if rows < MIN_ESTIMATE_ROWS {
        return Err(Error::TooFewPoints(format!(
            "residual rows: {rows} given, at least {MIN_ESTIMATE_ROWS} needed"
        )));
    }
    let mut sie = SieEstimator::new(options.clone());
    sie.prepare(&normalised, cols);
    sie.set_beta(&[beta]);
    sie.fit(&normalised, cols);
    sie.adapt_penalty();
    sie.fit(&normalised, cols);
    let mut probabilities = vec![0.0; rows];
    let prior = sie.probabilities(&normalised, cols, &mut probabilities);
    Ok(InlierEstimate {
        probabilities,
        models: sie.models().to_vec(),
        prior,
    })
}

