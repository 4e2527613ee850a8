//! `sie_estimate_inliers` on arbitrary residual matrices (NaN and infinities included).
#![no_main]
use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

fuzz_target!(|data: &[u8]| {
    let Some((&settings, rest)) = data.split_first() else { return };
    let cols = 1 + (settings & 3) as usize;
    let values: Vec<f64> = rest
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let rows = values.len() / cols;
    let mut probabilities = vec![-1.0; rows.max(1)];
    let mut models = [sie_model::default(); 4];
    let mut count = 0usize;
    let beta = if settings & 16 != 0 { 0.05 } else { 0.0 };
    // SAFETY: every buffer is sized for the call.
    unsafe {
        let ctx = sie_context_new();
        let _ = sie_context_set_histogram_mode(ctx, ((settings >> 2) & 1) as u32);
        let _ = sie_context_set_noise_shape(ctx, [2.0, 1.0, 0.0, 2.0][((settings >> 5) & 3) as usize]);
        let status = sie_estimate_inliers(
            ctx,
            values.as_ptr(),
            rows,
            cols,
            std::ptr::null(),
            beta,
            probabilities.as_mut_ptr(),
            models.as_mut_ptr(),
            models.len(),
            &mut count,
        );
        match status {
            sie_status::Ok => {
                assert!(probabilities[..rows].iter().all(|p| (0.0..=1.0).contains(p)));
                assert!(models[..count].iter().all(|m| m.sigma.is_finite() && m.alpha.is_finite()));
            }
            sie_status::NonFiniteInput | sie_status::TooFewPoints | sie_status::InvalidArgument => {
                assert!(probabilities.iter().all(|&p| p == -1.0), "outputs written on error");
            }
            other => panic!("unexpected status {other:?}"),
        }
        sie_context_free(ctx);
    }
});
