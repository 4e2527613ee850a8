//! Read access to the last successful registration stored in a context.
// The C signatures are fixed: one pointer per optional output array.
#![allow(clippy::too_many_arguments)]

use super::boundary::{FfiError, boundary};
use super::input::{check_optional_output, check_output, write_buffer, write_output};
use super::{
    ContextState, sie_context, sie_model, sie_start_kind, sie_status, sie_stop_reason, sie_summary,
    sie_trace_entry, sie_verdict,
};
use crate::{HistogramModel, ModelWidth};
use crate::{RegistrationResult, StartKind, StopReason, TraceEntry, Verdict};

fn stored_result(state: &ContextState) -> Result<&RegistrationResult, FfiError> {
    state.result.as_ref().ok_or_else(|| {
        FfiError::new(
            sie_status::NoResult,
            "no result: no registration has succeeded on this context since it was created or \
             since the last failed one",
        )
    })
}

fn summary_of(result: &RegistrationResult, init_correction: f64) -> sie_summary {
    let first_three = |values: &[f64]| {
        let mut out = [0.0; 3];
        for (o, v) in out.iter_mut().zip(values) {
            *o = *v;
        }
        out
    };
    let stop_reason = match result.stop_reason {
        StopReason::Converged => sie_stop_reason::Converged,
        StopReason::IterationLimit => sie_stop_reason::IterationLimit,
        StopReason::Degenerate => sie_stop_reason::Degenerate,
        StopReason::Cancelled => sie_stop_reason::Cancelled,
    };
    let (quality, search) = (&result.quality, &result.search);
    let verdict = match quality.verdict {
        Verdict::Good => sie_verdict::Good,
        Verdict::Doubtful => sie_verdict::Doubtful,
        Verdict::Unsupported => sie_verdict::Unsupported,
    };
    let start = match search.start {
        StartKind::InitialGuess => sie_start_kind::InitialGuess,
        StartKind::NarrowBeta => sie_start_kind::NarrowBeta,
        StartKind::ScaleFreeLead => sie_start_kind::ScaleFreeLead,
        StartKind::Hypothesis => sie_start_kind::Hypothesis,
        StartKind::WarmStart => sie_start_kind::WarmStart,
        StartKind::HalfTurn => sie_start_kind::HalfTurn,
        StartKind::PeriodShift => sie_start_kind::PeriodShift,
        StartKind::FeatureMatch => sie_start_kind::FeatureMatch,
        StartKind::QuarterTurn => sie_start_kind::QuarterTurn,
    };
    sie_summary {
        sigma: first_three(&result.sigma),
        beta: first_three(&result.beta),
        penalty: result.penalty,
        noise_shape: result.noise_shape,
        inlier_fraction: result.inlier_fraction,
        rmse: result.rmse,
        init_correction,
        source_count: result.probabilities.len() as u64,
        correspondence_count: result.correspondences.iter().filter(|&&c| c >= 0).count() as u64,
        iterations: result.iterations,
        stop_reason: stop_reason as u32,
        histogram_count: u32::try_from(result.histograms.len()).unwrap_or(u32::MAX),
        converged: result.converged,
        verdict: verdict as u32,
        start: start as u32,
        significance: quality.significance,
        conditioning: quality.conditioning,
        // Every output is finite: a zero spacing is reported as the largest double, and
        // an unbounded margin (no start ended elsewhere) as 0.
        sigma_to_spacing: if quality.sigma_to_spacing == f64::INFINITY {
            f64::MAX
        } else {
            quality.sigma_to_spacing
        },
        margin: if quality.margin.is_finite() {
            quality.margin
        } else {
            0.0
        },
        runner_up_significance: search.runner_up_significance,
        starts_run: search.starts_run,
        hypotheses: search.hypotheses,
        agreeing_starts: search.agreeing_starts,
    }
}

pub(crate) fn model_of(histogram: &HistogramModel) -> sie_model {
    sie_model {
        mu: histogram.inlier.mu,
        sigma: histogram.inlier.sigma,
        alpha: histogram.inlier.alpha,
        noise_shape: histogram.inlier.p,
        beta: histogram.beta,
        penalty: histogram.penalty,
        range_lo: histogram.lo,
        range_hi: histogram.hi,
        mean_inlier_probability: histogram.mean_inlier_probability,
        bins: histogram.bins() as u64,
        samples_in_range: histogram.samples_in_range as u64,
        peak_found: histogram.peak_found,
    }
}

pub(crate) fn trace_entry_of(entry: &TraceEntry) -> sie_trace_entry {
    sie_trace_entry {
        sigma: entry.sigma,
        beta: entry.beta,
        penalty: entry.penalty,
        inlier_fraction: entry.inlier_fraction,
        rmse: entry.rmse,
        translation_change: entry.translation_change,
        rotation_change: entry.rotation_change,
        correspondences: entry.correspondences as u64,
        iteration: entry.iteration,
        annealing: entry.annealing,
        transform: super::input::row_major(&entry.transform),
    }
}

/// Copies the summary of the last successful registration to `*out`. NO_RESULT before the
/// first successful registration and after a failed one.
///
/// # Safety
/// `ctx` is NULL or a live context; `out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_get_summary(
    ctx: *const sie_context,
    out: *mut sie_summary,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        check_output(out, "out")?;
        let state = &*call.state;
        let summary = summary_of(stored_result(state)?, state.init_correction);
        // SAFETY: checked above; writable per the contract.
        unsafe { write_output(out, &[summary]) };
        Ok(())
    })
}

/// Copies P(inlier) of every source point (0 for unmatched points), indexed by source point,
/// from the last successful registration. For baseline costs: the IRLS weight divided by the
/// largest weight.
///
/// Buffers (same for all array getters): `capacity` is the number of elements `out` holds. If
/// it is smaller than the result (`sie_summary.source_count` here) the call returns
/// BUFFER_TOO_SMALL and writes nothing. On success `*out_len` (nullable) receives the number of
/// elements written. To query the length, pass `out` = NULL, `capacity` = 0 and a non-NULL
/// `out_len`.
///
/// # Safety
/// `ctx` is NULL or a live context; `out` is NULL or writable for `capacity` doubles;
/// `out_len` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_get_inlier_probabilities(
    ctx: *const sie_context,
    out: *mut f64,
    capacity: usize,
    out_len: *mut usize,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = &*call.state;
        let result = stored_result(state)?;
        // SAFETY: forwarded contract.
        unsafe { write_buffer(out, capacity, out_len, &result.probabilities, "source points") }
    })
}

/// Copies the matched target index of every source point (-1 if unmatched), indexed by source
/// point, from the last successful registration. Buffer rules as in
/// `sie_context_get_inlier_probabilities`.
///
/// # Safety
/// `ctx` is NULL or a live context; `out` is NULL or writable for `capacity` int64_t;
/// `out_len` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_get_correspondences(
    ctx: *const sie_context,
    out: *mut i64,
    capacity: usize,
    out_len: *mut usize,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = &*call.state;
        let result = stored_result(state)?;
        // SAFETY: forwarded contract.
        unsafe { write_buffer(out, capacity, out_len, &result.correspondences, "source points") }
    })
}

/// Copies SIE histogram `index` (< `sie_summary.histogram_count`) of the last successful
/// registration: its model to `*out_model` and, per bin, the raw counts, the smoothed counts
/// the model was fitted to, the fitted model G (with sigma, without beta) at the bin centres, and
/// P(inlier) at the bin centres. Bin b covers [range_lo + b*w, range_lo + (b+1)*w) with
/// w = (range_hi - range_lo) / bins.
///
/// Each array is optional (NULL = not wanted). If any is given, `capacity` (elements per array)
/// must be at least `out_model->bins`, otherwise BUFFER_TOO_SMALL and nothing is written; call
/// once with all arrays NULL to learn `bins`. INVALID_ARGUMENT if `index` is out of range
/// (baseline costs have no histograms).
///
/// # Safety
/// `ctx` is NULL or a live context; `out_model` is NULL or writable; each non-NULL array is
/// writable for `capacity` doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_get_histogram(
    ctx: *const sie_context,
    index: usize,
    out_model: *mut sie_model,
    out_counts: *mut f64,
    out_smoothed: *mut f64,
    out_model_values: *mut f64,
    out_probability: *mut f64,
    capacity: usize,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        check_output(out_model, "out_model")?;
        let arrays = [
            (out_counts, "out_counts"),
            (out_smoothed, "out_smoothed"),
            (out_model_values, "out_model_values"),
            (out_probability, "out_probability"),
        ];
        for (ptr, name) in arrays {
            check_optional_output(ptr, name)?;
        }
        let state = &*call.state;
        let result = stored_result(state)?;
        let histogram = result.histograms.get(index).ok_or_else(|| {
            FfiError::invalid(format!(
                "index {index} is out of range: the result has {} histograms",
                result.histograms.len()
            ))
        })?;
        let bins = histogram.bins();
        let any_array = arrays.iter().any(|(ptr, _)| !ptr.is_null());
        if any_array && capacity < bins {
            return Err(FfiError::new(
                sie_status::BufferTooSmall,
                format!("capacity {capacity} is smaller than the {bins} bins of histogram {index}"),
            ));
        }
        let model_values: Vec<f64> = (0..bins)
            .map(|bin| histogram.model(histogram.bin_centre(bin), ModelWidth::Sigma))
            .collect();
        let contents: [&[f64]; 4] = [
            &histogram.counts,
            &histogram.smoothed,
            &model_values,
            &histogram.probability,
        ];
        // SAFETY: every pointer was checked above and, when non-NULL, holds `capacity >= bins`
        // doubles per the contract.
        unsafe {
            write_output(out_model, &[model_of(histogram)]);
            for ((ptr, _), values) in arrays.into_iter().zip(contents) {
                if !ptr.is_null() {
                    write_output(ptr, &values[..values.len().min(bins)]);
                }
            }
        }
        Ok(())
    })
}

/// Copies the per-iteration trace of the last successful registration (empty unless
/// `sie_context_set_trace(ctx, true)` was set before it): one entry per update of every start,
/// in the order they ran (`sie_summary.iterations` entries). Buffer rules as in
/// `sie_context_get_inlier_probabilities`.
///
/// # Safety
/// `ctx` is NULL or a live context; `out` is NULL or writable for `capacity` entries;
/// `out_len` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_get_trace(
    ctx: *const sie_context,
    out: *mut sie_trace_entry,
    capacity: usize,
    out_len: *mut usize,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let state = &*call.state;
        let entries: Vec<sie_trace_entry> = stored_result(state)?.trace.iter().map(trace_entry_of).collect();
        // SAFETY: forwarded contract.
        unsafe { write_buffer(out, capacity, out_len, &entries, "trace entries") }
    })
}

/// Copies the uncertainty of the last successful registration's pose: its 6x6 covariance to
/// `out_covariance` and its inverse, the information matrix, to `out_information`, each as 36
/// doubles in ROW-major order (M[6*row + col]). Either pointer may be NULL to skip that
/// matrix, not both (NULL_ARGUMENT); two buffers that overlap are INVALID_ARGUMENT. Nothing is
/// written unless the call succeeds.
///
/// Convention: the returned T_target_source is perturbed on the LEFT, T = Exp(d) * T_hat, with
/// d = (w, v): w the rotation vector (radians, rows/columns 0..2) FIRST, then v the
/// translation (rows/columns 3..5), both in the TARGET frame and in the caller's units (the
/// covariance in rad^2, rad*length and length^2; the information in their inverses). To first
/// order, p_target moves by w x p_target + v.
///
/// It is computed from the final inliers: their residuals weighted by P(inlier) and the noise
/// scales, with the noise variance measured from those residuals (so it holds whatever noise
/// shape was fitted). Directions the inliers leave free (sliding along a plane, turning about a
/// symmetry axis) get a far larger variance and a far smaller information than the constrained
/// ones: by many orders of magnitude with exact normals, but with normals estimated from noisy
/// points only by about (point spacing / noise)^2, since the normals' scatter seems to hold
/// the sliding; check `sie_summary.conditioning` and `verdict` as well. Both matrices are all
/// zeros when the result has too few weighted residuals to measure a variance (e.g. a baseline
/// cost that weighted none).
///
/// # Safety
/// `ctx` is NULL or a live context; `out_covariance` and `out_information` are each NULL or
/// writable for 36 doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sie_context_get_pose_uncertainty(
    ctx: *const sie_context,
    out_covariance: *mut f64,
    out_information: *mut f64,
) -> sie_status {
    // SAFETY: NULL or live per the contract.
    boundary(unsafe { ctx.as_ref() }, |call| {
        let outputs = [
            (out_covariance, "out_covariance"),
            (out_information, "out_information"),
        ];
        if outputs.iter().all(|(ptr, _)| ptr.is_null()) {
            return Err(FfiError::new(
                sie_status::NullArgument,
                "out_covariance and out_information are both NULL: pass at least one",
            ));
        }
        for (ptr, name) in outputs {
            check_optional_output(ptr, name)?;
        }
        if overlap(out_covariance, out_information, POSE_MATRIX_LEN) {
            return Err(FfiError::invalid(
                "out_covariance and out_information overlap: each needs its own 36 doubles",
            ));
        }
        let uncertainty = stored_result(&*call.state)?.uncertainty;
        // nalgebra stores column-major; the transpose's storage is the row-major matrix.
        let contents = [
            uncertainty.covariance.transpose(),
            uncertainty.information.transpose(),
        ];
        for ((ptr, _), matrix) in outputs.into_iter().zip(contents) {
            if !ptr.is_null() {
                // SAFETY: checked above (aligned, disjoint from the other output) and writable
                // for 36 doubles per the contract.
                unsafe { write_output(ptr, matrix.as_slice()) };
            }
        }
        Ok(())
    })
}

/// Doubles in one 6x6 matrix of `sie_context_get_pose_uncertainty`.
const POSE_MATRIX_LEN: usize = 36;

/// Whether two non-NULL arrays of `len` doubles share any byte (by address only).
fn overlap(a: *mut f64, b: *mut f64, len: usize) -> bool {
    if a.is_null() || b.is_null() {
        return false;
    }
    let bytes = len * core::mem::size_of::<f64>();
    let (a, b) = (a.addr(), b.addr());
    a < b.saturating_add(bytes) && b < a.saturating_add(bytes)
}
