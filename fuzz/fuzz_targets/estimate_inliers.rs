//! `sie_estimate_inliers` on arbitrary residual matrices (NaN and infinities included), grown
//! into the shapes that broke it: wide matrices (up to 256 columns), magnitudes from 2^-1024
//! to 2^1016, and repeated rows.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

fuzz_target!(|data: &[u8]| {
    let Some((&[settings, width, magnitude, copies], rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    let cols = 1 + width as usize;
    let scale = 2f64.powi(8 * i32::from(magnitude as i8));
    let mut values: Vec<f64> = rest
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()) * scale)
        .collect();
    values.truncate(values.len() / cols * cols);
    if values.len() >= cols {
        let first: Vec<f64> = values[..cols].to_vec();
        for _ in 0..copies {
            values.extend_from_slice(&first);
        }
    }
    let rows = values.len() / cols;
    let mut probabilities = vec![-1.0; rows.max(1)];
    let mut models = vec![sie_model::default(); cols];
    let mut count = 0usize;
    let beta = if settings & 16 != 0 { 0.05 } else { 0.0 };
    // SAFETY: every buffer is sized for the call.
    unsafe {
        let ctx = sie_context_new();
        let _ = sie_context_set_histogram_mode(ctx, u32::from((settings >> 2) & 1));
        let _ = sie_context_set_noise_shape(ctx, [2.0, 1.0, 0.0, 2.0][usize::from((settings >> 5) & 3)]);
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
                assert!(
                    models[..count]
                        .iter()
                        .all(|m| m.sigma.is_finite() && m.alpha.is_finite())
                );
            }
            sie_status::NonFiniteInput | sie_status::TooFewPoints | sie_status::InvalidArgument => {
                assert!(
                    probabilities.iter().all(|&p| p == -1.0),
                    "outputs written on error"
                );
            }
            other => panic!("unexpected status {other:?}"),
        }
        sie_context_free(ctx);
    }
});
