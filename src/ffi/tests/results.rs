//! The getters: caller-sized buffers, the summary's values and layout, the histograms.

use core::ptr::null_mut;

use super::*;
use crate::ffi::input::write_buffer;

#[test]
fn buffers_are_sized_queried_and_never_partially_written() {
    let values = [1.0, 2.0, 3.0];
    let mut len = 0usize;
    unsafe {
        assert_eq!(
            write_buffer(null_mut::<f64>(), 0, &raw mut len, &values, "x"),
            Ok(())
        );
        assert_eq!(len, 3);
        let error = write_buffer(null_mut::<f64>(), 0, null_mut(), &values, "x").unwrap_err();
        assert_eq!(error.status, sie_status::NullArgument);
        let error = write_buffer(null_mut::<f64>(), 3, &raw mut len, &values, "x").unwrap_err();
        assert_eq!(error.status, sie_status::NullArgument);
        let mut small = [-9.0; 2];
        len = 77;
        let error = write_buffer(small.as_mut_ptr(), 2, &raw mut len, &values, "source points").unwrap_err();
        assert_eq!(error.status, sie_status::BufferTooSmall);
        assert_eq!(error.message, "capacity 2 is smaller than the 3 source points");
        assert_eq!((small, len), ([-9.0; 2], 77));
        let mut big = [-9.0; 5];
        assert_eq!(
            write_buffer(big.as_mut_ptr(), 5, &raw mut len, &values, "x"),
            Ok(())
        );
        assert_eq!((big, len), ([1.0, 2.0, 3.0, -9.0, -9.0], 3));
        assert_eq!(
            write_buffer(big.as_mut_ptr(), 5, null_mut(), &values, "x"),
            Ok(())
        );
    }
}

#[test]
fn getters_report_no_result_before_a_registration() {
    let ctx = Context::new();
    let mut summary = sie_summary::default();
    let mut model = sie_model::default();
    let mut len = 0;
    unsafe {
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::NoResult);
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, null_mut(), 0, &mut len),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_correspondences(ctx.0, null_mut(), 0, &mut len),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                0,
                &mut model,
                null_mut(),
                null_mut(),
                null_mut(),
                null_mut(),
                0
            ),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_trace(ctx.0, null_mut(), 0, &mut len),
            sie_status::NoResult
        );
    }
    assert!(ctx.last_error().starts_with("no result"), "{}", ctx.last_error());
}

#[test]
fn getters_copy_the_stored_result() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let mut summary = sie_summary::default();
    assert_eq!(
        unsafe { sie_context_get_summary(ctx.0, &mut summary) },
        sie_status::Ok
    );
    assert_eq!(summary.sigma, [0.5, 0.0, 0.0]);
    assert_eq!(summary.beta, [0.25, 0.0, 0.0]);
    assert_eq!((summary.source_count, summary.correspondence_count), (3, 2));
    assert_eq!(summary.stop_reason, sie_stop_reason::IterationLimit as u32);
    assert_eq!(
        (summary.iterations, summary.histogram_count, summary.converged),
        (7, 1, false)
    );
    assert_eq!(summary.verdict, sie_verdict::Doubtful as u32);
    assert_eq!(summary.start, sie_start_kind::ScaleFreeLead as u32);
    assert_eq!(
        (
            summary.significance,
            summary.conditioning,
            summary.sigma_to_spacing,
            summary.margin,
            summary.runner_up_significance
        ),
        (41.5, 0.25, 0.75, 41.5 / 12.0, 12.0)
    );
    assert_eq!(
        (summary.starts_run, summary.hypotheses, summary.agreeing_starts),
        (3, 0, 2)
    );

    let mut probabilities = [0.0; 3];
    let mut correspondences = [0i64; 3];
    let mut len = 0;
    unsafe {
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, probabilities.as_mut_ptr(), 3, &mut len),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_get_correspondences(ctx.0, correspondences.as_mut_ptr(), 3, null_mut()),
            sie_status::Ok
        );
    }
    assert_eq!((probabilities, len), ([0.9, 0.0, 0.8], 3));
    assert_eq!(correspondences, [4, -1, 2]);

    let mut trace = [sie_trace_entry::default(); 2];
    assert_eq!(
        unsafe { sie_context_get_trace(ctx.0, trace.as_mut_ptr(), 2, &mut len) },
        sie_status::Ok
    );
    assert_eq!(len, 1);
    assert_eq!(
        (trace[0].iteration, trace[0].annealing, trace[0].correspondences),
        (1, true, 3)
    );
    // The transform reached by that update, row-major like every transform of the C API.
    assert_eq!(trace[0].transform[3], 1.5);
    assert_eq!(trace[0].transform[11], -0.5);
    assert_eq!(trace[0].transform[15], 1.0);
    assert_eq!(trace[1], sie_trace_entry::default());
}

/// Every verdict and start kind maps to its C value; the infinite values the core uses for "no
/// start ended elsewhere" and "zero spacing" come out finite (outputs are never inf or NaN).
#[test]
fn summary_encodes_verdicts_starts_and_unbounded_values_finitely() {
    let ctx = Context::new();
    let cases = [
        (
            Verdict::Good,
            StartKind::InitialGuess,
            sie_verdict::Good,
            sie_start_kind::InitialGuess,
        ),
        (
            Verdict::Doubtful,
            StartKind::NarrowBeta,
            sie_verdict::Doubtful,
            sie_start_kind::NarrowBeta,
        ),
        (
            Verdict::Unsupported,
            StartKind::Hypothesis,
            sie_verdict::Unsupported,
            sie_start_kind::Hypothesis,
        ),
    ];
    for (verdict, start, c_verdict, c_start) in cases {
        let mut result = sample_result();
        result.quality = Quality {
            verdict,
            significance: 7.0,
            conditioning: 0.5,
            sigma_to_spacing: f64::INFINITY,
            loose_direction: None,
            scaled_source: None,
            margin: f64::INFINITY,
        };
        result.search = SearchReport {
            start,
            hypotheses: 512,
            starts_run: 1,
            significance: 7.0,
            agreeing_starts: 1,
            runner_up_significance: 0.0,
        };
        ctx.inject_result(result);
        let mut summary = sie_summary::default();
        assert_eq!(
            unsafe { sie_context_get_summary(ctx.0, &mut summary) },
            sie_status::Ok
        );
        assert_eq!(
            (summary.verdict, summary.start),
            (c_verdict as u32, c_start as u32)
        );
        assert_eq!((summary.margin, summary.runner_up_significance), (0.0, 0.0));
        assert_eq!(summary.sigma_to_spacing, f64::MAX);
        assert_eq!((summary.starts_run, summary.hypotheses), (1, 512));
    }
    // A zeroed summary reads "no verdict", as its stop reason reads "none".
    assert_eq!(sie_summary::default().verdict, sie_verdict::None as u32);
}

/// The summary is caller-allocated: its layout is the ABI. The fields added in 0.2 follow the
/// 0.1 ones without moving them, u32 pairs before the doubles so no padding is left inside.
#[test]
fn summary_layout_is_the_documented_one() {
    use core::mem::{offset_of, size_of};
    assert_eq!(offset_of!(sie_summary, converged), 116);
    assert_eq!(offset_of!(sie_summary, verdict), 120);
    assert_eq!(offset_of!(sie_summary, start), 124);
    assert_eq!(offset_of!(sie_summary, significance), 128);
    assert_eq!(offset_of!(sie_summary, runner_up_significance), 160);
    assert_eq!(offset_of!(sie_summary, starts_run), 168);
    assert_eq!(offset_of!(sie_summary, agreeing_starts), 176);
    assert_eq!(size_of::<sie_summary>(), 184);
}

#[test]
fn histograms_are_copied_per_bin() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let mut model = sie_model::default();
    let mut counts = [-1.0; 4];
    let mut model_values = [-1.0; 4];
    let mut probability = [-1.0; 4];
    let none = null_mut();
    unsafe {
        assert_eq!(
            sie_context_get_histogram(ctx.0, 0, &mut model, none, none, none, none, 0),
            sie_status::Ok
        );
        assert_eq!(model.bins, 4);
        assert_eq!(
            (model.sigma, model.beta, model.range_hi, model.peak_found),
            (0.5, 0.25, 2.0, true)
        );
        assert_eq!(
            sie_context_get_histogram(ctx.0, 0, &mut model, counts.as_mut_ptr(), none, none, none, 3),
            sie_status::BufferTooSmall
        );
        assert_eq!(counts, [-1.0; 4]);
        assert_eq!(
            sie_context_get_histogram(ctx.0, 1, &mut model, none, none, none, none, 0),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("index 1"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                0,
                &mut model,
                counts.as_mut_ptr(),
                none,
                model_values.as_mut_ptr(),
                probability.as_mut_ptr(),
                4
            ),
            sie_status::Ok
        );
    }
    assert_eq!(counts, [9.0, 7.0, 2.0, 1.0]);
    assert_eq!(probability, [0.99, 0.9, 0.4, 0.1]);
    // Bin centres 0.25, 0.75, ...: G(x) = 10·exp(-(x/0.5)²/2), without β.
    let expected = 10.0 * (-0.5f64 * 0.25).exp();
    assert!((model_values[0] - expected).abs() < 1e-12, "{}", model_values[0]);
}

/// A result whose matrices tell rows from columns: covariance (r, c) = 10·r + c, information
/// the negative.
fn result_with_uncertainty() -> RegistrationResult {
    let covariance = nalgebra::Matrix6::from_fn(|r, c| (10 * r + c) as f64);
    RegistrationResult {
        uncertainty: crate::PoseUncertainty {
            covariance,
            information: -covariance,
        },
        ..sample_result()
    }
}

#[test]
fn pose_uncertainty_is_copied_row_major_and_either_matrix_may_be_skipped() {
    let ctx = Context::new();
    ctx.inject_result(result_with_uncertainty());
    let expected: [f64; 36] = core::array::from_fn(|i| (10 * (i / 6) + i % 6) as f64);
    let mut covariance = [-1.0; 36];
    let mut information = [-1.0; 36];
    unsafe {
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, covariance.as_mut_ptr(), information.as_mut_ptr()),
            sie_status::Ok
        );
    }
    assert_eq!(covariance, expected);
    assert_eq!(information, expected.map(|v| -v));

    let mut only_information = [-1.0; 36];
    let mut only_covariance = [-1.0; 36];
    unsafe {
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, null_mut(), only_information.as_mut_ptr()),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, only_covariance.as_mut_ptr(), null_mut()),
            sie_status::Ok
        );
    }
    assert_eq!((only_covariance, only_information), (covariance, information));
}

/// Every refusal names what is wrong and writes into neither buffer.
#[test]
fn pose_uncertainty_refusals_write_nothing() {
    let ctx = Context::new();
    let mut covariance = [-1.0; 36];
    let mut information = [-1.0; 36];
    let untouched = |covariance: &[f64; 36], information: &[f64; 36]| {
        assert_eq!((*covariance, *information), ([-1.0; 36], [-1.0; 36]));
    };
    unsafe {
        assert_eq!(
            sie_context_get_pose_uncertainty(
                core::ptr::null(),
                covariance.as_mut_ptr(),
                information.as_mut_ptr()
            ),
            sie_status::NullArgument
        );
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, covariance.as_mut_ptr(), information.as_mut_ptr()),
            sie_status::NoResult
        );
        assert!(ctx.last_error().starts_with("no result"), "{}", ctx.last_error());
        untouched(&covariance, &information);

        ctx.inject_result(result_with_uncertainty());
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, null_mut(), null_mut()),
            sie_status::NullArgument
        );
        assert_eq!(
            ctx.last_error(),
            "out_covariance and out_information are both NULL: pass at least one"
        );
        // A misaligned buffer is refused before the other, valid one is written.
        let misaligned = information
            .as_mut_ptr()
            .cast::<u8>()
            .wrapping_add(1)
            .cast::<f64>();
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, covariance.as_mut_ptr(), misaligned),
            sie_status::InvalidArgument
        );
        assert!(
            ctx.last_error().starts_with("out_information ("),
            "{}",
            ctx.last_error()
        );
        let misaligned = covariance.as_mut_ptr().cast::<u8>().wrapping_add(4).cast::<f64>();
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, misaligned, information.as_mut_ptr()),
            sie_status::InvalidArgument
        );
        assert!(
            ctx.last_error().starts_with("out_covariance ("),
            "{}",
            ctx.last_error()
        );
        untouched(&covariance, &information);

        // One buffer for both, or two that share a double, would leave one matrix half
        // overwritten by the other.
        let mut shared = [-1.0; 72];
        for offset in [0, 35] {
            assert_eq!(
                sie_context_get_pose_uncertainty(ctx.0, shared.as_mut_ptr(), shared.as_mut_ptr().add(offset)),
                sie_status::InvalidArgument
            );
            assert!(ctx.last_error().contains("overlap"), "{}", ctx.last_error());
            assert_eq!(
                sie_context_get_pose_uncertainty(ctx.0, shared.as_mut_ptr().add(offset), shared.as_mut_ptr()),
                sie_status::InvalidArgument
            );
        }
        assert_eq!(shared, [-1.0; 72]);
        // Adjacent is fine.
        assert_eq!(
            sie_context_get_pose_uncertainty(ctx.0, shared.as_mut_ptr(), shared.as_mut_ptr().add(36)),
            sie_status::Ok
        );
        assert_eq!(shared[35], 55.0);
        assert_eq!(shared[36], 0.0);
        assert_eq!(shared[71], -55.0);
    }
}
