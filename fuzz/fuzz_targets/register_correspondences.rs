//! `sie_context_register_correspondences` on arbitrary float pairs and settings.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

fuzz_target!(|data: &[u8]| {
    let Some((&settings, rest)) = data.split_first() else { return };
    let floats: Vec<f32> = rest
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let n = floats.len() / 6;
    let (source, target) = floats[..6 * n].split_at(3 * n);
    let mut out = [-7.0f64; 16];
    // SAFETY: the arrays hold n packed points each; `out` holds 16 doubles.
    unsafe {
        let ctx = sie_context_new();
        let _ = sie_context_set_cost_function(ctx, (settings & 7) as u32, 0.05);
        let _ = sie_context_set_skip_non_finite(ctx, settings & 8 != 0);
        let _ = sie_context_set_histogram_mode(ctx, ((settings >> 4) & 1) as u32);
        let _ = sie_context_set_max_iterations(ctx, 1 + (settings >> 5) as u32 * 8);
        let status = sie_context_register_correspondences(
            ctx,
            source.as_ptr(),
            0,
            target.as_ptr(),
            0,
            n,
            std::ptr::null(),
            out.as_mut_ptr(),
        );
        match status {
            sie_status::Ok => {
                assert!(out.iter().all(|v| v.is_finite()), "{out:?}");
                assert_eq!(&out[12..], &[0.0, 0.0, 0.0, 1.0]);
                let mut summary = sie_summary::default();
                assert_eq!(sie_context_get_summary(ctx, &mut summary), sie_status::Ok);
                assert!(summary.inlier_fraction.is_finite() && summary.rmse.is_finite());
            }
            sie_status::NonFiniteInput | sie_status::TooFewPoints | sie_status::InvalidArgument => {
                assert!(out.iter().all(|&v| v == -7.0), "outputs written on error");
            }
            other => panic!("unexpected status {other:?}"),
        }
        sie_context_free(ctx);
    }
});
