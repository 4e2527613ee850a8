//! The standalone estimator: SIE on any residual matrix.
// The C signature is fixed: one argument per input and output.
#![allow(clippy::too_many_arguments)]

use super::boundary::{FfiError, boundary};
use super::input::{check_optional_output, check_output, read_array, write_output};
use super::results::model_of;
use super::{sie_context, sie_model, sie_status};
use crate::estimate_inliers;

/// Statistical Inlier Estimation on a residual matrix, without registration: P(inlier) per row.
///
/// `residuals`: rows x cols doubles, row-major (one row per correspondence, one column per
/// residual component). `row_scales` (nullable, `rows` values, finite and > 0): each row is
/// divided by its scale first, e.g. the per-correspondence noise sigma. `beta` (finite, >= 0) is
/// the regulariser added to sigma when predicting; 0 for none. Uses the context's SIE settings
/// (histogram mode, noise shape) and does not touch its stored registration result.
///
/// Outputs, written only on success: `out_probabilities` (`rows` doubles); `out_models`
/// (nullable) receives one `sie_model` per histogram (1 when pooled, `cols` per column) and
/// must hold that many (`models_capacity`), else BUFFER_TOO_SMALL; `out_model_count` (nullable)
/// receives the number of histograms.
///
/// Errors: NULL_ARGUMENT, TOO_FEW_POINTS (fewer than 10 rows: too few for a histogram to
/// fit), INVALID_ARGUMENT (cols is 0, bad scale or beta), NON_FINITE_INPUT (names the index),
/// BUFFER_TOO_SMALL, BUSY,
/// OUT_OF_MEMORY. Residuals of any finite magnitude are accepted: the answer does not
/// depend on their unit, and a residual beyond 1e100 times the typical one is an outlier.
///
/// # Safety
/// `ctx` is NULL or a live context; `residuals` is NULL or readable for rows*cols doubles;
/// `row_scales` is NULL or readable for `rows` doubles; `out_probabilities` is NULL or writable
/// for `rows` doubles; `out_models` is NULL or writable for `models_capacity` models;
/// `out_model_count` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_estimate_inliers(
    ctx: *mut sie_context,
    residuals: *const f64,
    rows: usize,
    cols: usize,
    row_scales: *const f64,
    beta: f64,
    out_probabilities: *mut f64,
    out_models: *mut sie_model,
    models_capacity: usize,
    out_model_count: *mut usize,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        check_output(out_probabilities, "out_probabilities")?;
        check_optional_output(out_models, "out_models")?;
        check_optional_output(out_model_count, "out_model_count")?;
        if residuals.is_null() {
            return Err(FfiError::null("residuals"));
        }
        if rows == 0 {
            return Err(FfiError::new(sie_status::TooFewPoints, "rows is 0"));
        }
        if cols == 0 {
            return Err(FfiError::invalid("cols is 0"));
        }
        let len = rows
            .checked_mul(cols)
            .ok_or_else(|| FfiError::invalid(format!("rows * cols overflows ({rows} * {cols})")))?;
        // SAFETY: readable per the contract.
        let matrix = unsafe { read_array(residuals, len, "residuals") }?;
        let scales = if row_scales.is_null() {
            None
        } else {
            // SAFETY: readable per the contract.
            Some(unsafe { read_array(row_scales, rows, "row_scales") }?)
        };
        let estimate = estimate_inliers(&matrix, cols, scales.as_deref(), beta, &call.state.config.sie)?;
        let model_count = estimate.models.len();
        if !out_models.is_null() && models_capacity < model_count {
            return Err(FfiError::new(
                sie_status::BufferTooSmall,
                format!("models_capacity {models_capacity} is smaller than the {model_count} histograms"),
            ));
        }
        let models: Vec<sie_model> = estimate.models.iter().map(model_of).collect();
        // Sliced so a wrong length from the core fails loudly instead of overrunning.
        let probabilities = &estimate.probabilities[..rows];
        // SAFETY: all pointers were checked above and are writable for the documented lengths.
        unsafe {
            write_output(out_probabilities, probabilities);
            if !out_models.is_null() {
                write_output(out_models, &models);
            }
            if !out_model_count.is_null() {
                out_model_count.write(model_count);
            }
        }
        Ok(())
    })
}
