//! The input checks of `sie_estimate_inliers`.

use core::ptr::{null, null_mut};

use super::*;

#[test]
fn estimate_rejects_bad_input_before_running() {
    let ctx = Context::new();
    let mut residuals = vec![0.1; 12];
    let mut probabilities = [-1.0; 4];
    let run = |residuals: &[f64], rows, cols, scales: *const f64, beta, out: &mut [f64]| unsafe {
        sie_estimate_inliers(
            ctx.0,
            residuals.as_ptr(),
            rows,
            cols,
            scales,
            beta,
            out.as_mut_ptr(),
            null_mut(),
            0,
            null_mut(),
        )
    };
    assert_eq!(
        run(&residuals, 0, 3, null(), 0.0, &mut probabilities),
        sie_status::TooFewPoints
    );
    assert_eq!(
        run(&residuals, 4, 0, null(), 0.0, &mut probabilities),
        sie_status::InvalidArgument
    );
    assert_eq!(
        run(&residuals, 4, 3, null(), -1.0, &mut probabilities),
        sie_status::InvalidArgument
    );
    let scales = [1.0, 1.0, 0.0, 1.0];
    assert_eq!(
        run(&residuals, 4, 3, scales.as_ptr(), 0.0, &mut probabilities),
        sie_status::InvalidArgument
    );
    assert!(ctx.last_error().contains("row_scales[2]"), "{}", ctx.last_error());
    // Finite but too large to square is no longer refused (the estimate rescales; a fuzzer
    // once found σ = inf from such input): four rows are too few, whatever their magnitude.
    residuals[5] = 2e152;
    assert_eq!(
        run(&residuals, 4, 3, null(), 0.0, &mut probabilities),
        sie_status::TooFewPoints
    );
    residuals[5] = 0.1;
    residuals[7] = f64::NEG_INFINITY;
    assert_eq!(
        run(&residuals, 4, 3, null(), 0.0, &mut probabilities),
        sie_status::NonFiniteInput
    );
    assert_eq!(
        ctx.last_error(),
        "residuals[7] is -inf (row index 2, column index 1, from 0)"
    );
    let status = unsafe {
        sie_estimate_inliers(
            ctx.0,
            null(),
            4,
            3,
            null(),
            0.0,
            probabilities.as_mut_ptr(),
            null_mut(),
            0,
            null_mut(),
        )
    };
    assert_eq!(status, sie_status::NullArgument);
    assert_eq!(ctx.last_error(), "residuals is NULL");
    assert_eq!(probabilities, [-1.0; 4]);
}
