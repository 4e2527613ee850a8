//! SIE on its own (§4): the inlier probability of every row of a residual matrix, for callers
//! that do their own estimation (the C ABI's `sie_estimate_inliers`).

use super::estimator::SieEstimator;
use super::histogram::{ARITHMETIC_LIMIT, HistogramModel};
use super::options::SieOptions;
use crate::error::Error;
use crate::median::median;
use crate::memory;

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
/// refits (§4.5), and returns P(I|R_i) per row. The answer does not depend on the residuals'
/// unit (extreme magnitudes are fitted in a unit of their own).
///
/// Errors: bad options or shape, fewer than [`MIN_ESTIMATE_ROWS`] rows, a non-finite value, a
/// row scale that is not finite and > 0, a β that is not finite and ≥ 0, and
/// [`Error::OutOfMemory`] when the estimate's working set cannot be had.
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
        return Err(Error::TooFewPoints(
            "residual rows: 0 given, at least 1 needed".into(),
        ));
    }
    check_estimate_values(residuals, cols, row_scales, beta)?;
    // Asked for up front: a memory limit is an error here, not an abort part-way.
    memory::ensure_available(memory::estimate_bytes(residuals.len()), "the inlier estimate")?;
    let normalised: Vec<f64> = match row_scales {
        None => residuals.to_vec(),
        Some(scales) => residuals
            .chunks_exact(cols)
            .zip(scales)
            .flat_map(|(row, s)| row.iter().map(move |r| r / s))
            .collect(),
    };
    // After every argument check, so that a bad argument is reported as such.
    if rows < MIN_ESTIMATE_ROWS {
        return Err(Error::TooFewPoints(format!(
            "residual rows: {rows} given, at least {MIN_ESTIMATE_ROWS} needed"
        )));
    }
    // Residuals of extreme magnitude are fitted in a unit of their own (the answer does not
    // depend on units; squares of 1e-160 or 1e160 would not survive), β with them; a β wider
    // than any residual by far puts every residual at the model's centre.
    let unit = residual_unit(&normalised);
    let scaled: Vec<f64>;
    let normalised = if unit == 1.0 {
        normalised
    } else {
        scaled = normalised.iter().map(|r| r / unit).collect();
        scaled
    };
    let beta = (beta / unit).min(ARITHMETIC_LIMIT);
    let mut sie = SieEstimator::new(options.clone());
    sie.prepare(&normalised, cols);
    sie.set_beta(&[beta]);
    sie.fit(&normalised, cols);
    sie.adapt_penalty();
    sie.fit(&normalised, cols);
    let mut probabilities = vec![0.0; rows];
    let prior = sie.probabilities(&normalised, cols, &mut probabilities);
    let mut models = sie.models().to_vec();
    // Back in the caller's unit. A model of residuals near ±f64::MAX may not fit in it (on a few
    // samples the range refits can widen σ far past them): it saturates instead of turning ∞.
    let in_caller_unit = |value: f64| (value * unit).clamp(-f64::MAX, f64::MAX);
    for model in &mut models {
        model.inlier.sigma = in_caller_unit(model.inlier.sigma);
        model.inlier.mu = in_caller_unit(model.inlier.mu);
        model.beta = in_caller_unit(model.beta);
        model.lo = in_caller_unit(model.lo);
        model.hi = in_caller_unit(model.hi);
    }
    Ok(InlierEstimate {
        probabilities,
        models,
        prior,
    })
}

/// The value rules of [`estimate_inliers`], for every entry point (the C ABI checks them before
/// it asks for memory): residuals finite (the error names the row and column), one row scale per
/// row, finite and > 0, and β finite and >= 0. `residuals` holds whole rows of `cols` >= 1.
fn check_estimate_values(
    residuals: &[f64],
    cols: usize,
    row_scales: Option<&[f64]>,
    beta: f64,
) -> Result<(), Error> {
    require_finite_values("residuals", residuals, cols)?;
    if let Some(scales) = row_scales {
        let rows = residuals.len() / cols;
        if scales.len() != rows {
            return Err(Error::InvalidArgument(format!(
                "{} row scales for {rows} rows",
                scales.len()
            )));
        }
        require_finite_values("row_scales", scales, 1)?;
        if let Some(i) = scales.iter().position(|&s| s <= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "row_scales[{i}] is {}; scales must be finite and > 0",
                scales[i]
            )));
        }
    }
    if !(beta.is_finite() && beta >= 0.0) {
        return Err(Error::InvalidArgument(format!(
            "beta must be finite and >= 0, got {beta}"
        )));
    }
    Ok(())
}

/// The first NaN or infinite value of a row-major matrix of `cols` columns, named with its
/// flat index, row and column.
fn require_finite_values(name: &str, values: &[f64], cols: usize) -> Result<(), Error> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(Error::NonFinite(format!(
            "{name}[{index}] is {} (row index {}, column index {}, from 0)",
            values[index],
            index / cols,
            index % cols
        ))),
    }
}

/// Residual magnitudes in [1/SAFE, SAFE] are fitted as given (results bit for bit as before).
const SAFE: f64 = 1e30;

/// 1, or the median residual magnitude when that lies outside the safe range.
fn residual_unit(residuals: &[f64]) -> f64 {
    let mut magnitudes: Vec<f64> = residuals.iter().map(|r| r.abs()).filter(|r| *r > 0.0).collect();
    match median(&mut magnitudes) {
        Some(typical) if !(1.0 / SAFE..=SAFE).contains(&typical) => typical,
        _ => 1.0,
    }
}
