//! `sie_context_register_correspondences_d` on arbitrary pairs and settings, grown into the
//! shapes that broke it: magnitudes from 2^-1024 to 2^1016 (squares that overflow or
//! underflow), exact duplicates of a pair, and non-finite values.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

fuzz_target!(|data: &[u8]| {
    let Some((&[settings, magnitude, copies], rest)) = data.split_first_chunk::<3>() else {
        return;
    };
    // Coordinates scaled by 2^(8·magnitude as i8): the same geometry at any magnitude.
    let scale = 2f64.powi(8 * i32::from(magnitude as i8));
    let mut values: Vec<f64> = rest
        .chunks_exact(4)
        .map(|c| f64::from(f32::from_le_bytes(c.try_into().unwrap())) * scale)
        .collect();
    values.truncate(values.len() / 6 * 6);
    // Exact duplicates of the first pair, as depth frames hold (up to 255 more).
    if values.len() >= 6 {
        let first: Vec<f64> = values[..6].to_vec();
        for _ in 0..copies {
            values.extend_from_slice(&first);
        }
    }
    let n = values.len() / 6;
    let (source, target): (Vec<f64>, Vec<f64>) = (
        values.chunks_exact(6).flat_map(|p| p[..3].to_vec()).collect(),
        values.chunks_exact(6).flat_map(|p| p[3..].to_vec()).collect(),
    );
    let mut out = [-7.0f64; 16];
    // SAFETY: the arrays hold n packed points each; `out` holds 16 doubles.
    unsafe {
        let ctx = sie_context_new();
        let _ = sie_context_set_cost_function(ctx, (settings & 7) as u32, 0.05);
        let _ = sie_context_set_skip_non_finite(ctx, settings & 8 != 0);
        let _ = sie_context_set_histogram_mode(ctx, ((settings >> 4) & 1) as u32);
        let _ = sie_context_set_skip_origin(ctx, settings & 32 != 0);
        let _ = sie_context_set_max_iterations(ctx, 1 + (settings >> 6) as u32 * 8);
        let status = sie_context_register_correspondences_d(
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
                // The verdict, its evidence and the search: valid codes, never NaN or inf.
                assert!((1..=3).contains(&summary.verdict), "{summary:?}");
                assert!(summary.start <= 3 && summary.starts_run >= 1, "{summary:?}");
                assert!(
                    (1..=summary.starts_run).contains(&summary.agreeing_starts),
                    "{summary:?}"
                );
                for value in [
                    summary.significance,
                    summary.conditioning,
                    summary.sigma_to_spacing,
                    summary.margin,
                    summary.runner_up_significance,
                ] {
                    assert!(value.is_finite() && value >= 0.0, "{summary:?}");
                }
            }
            sie_status::NonFiniteInput | sie_status::TooFewPoints | sie_status::InvalidArgument => {
                assert!(out.iter().all(|&v| v == -7.0), "outputs written on error");
            }
            other => panic!("unexpected status {other:?}"),
        }
        sie_context_free(ctx);
    }
});
