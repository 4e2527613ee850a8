//! `sie_context_register_d` (ICP: kd-tree matching, normals, both metrics) on arbitrary small
//! clouds at any magnitude (2^-1024 to 2^1016), with runs of exact duplicates and points at
//! 0 0 0: the inputs that made `src/nn.rs` panic and the matching quadratic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

fuzz_target!(|data: &[u8]| {
    let Some((&[settings, magnitude, copies, split], rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    let scale = 2f64.powi(8 * i32::from(magnitude as i8));
    let mut points: Vec<[f64; 3]> = rest
        .chunks_exact(12)
        .map(|c| {
            let value =
                |k: usize| f64::from(f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().unwrap())) * scale;
            [value(0), value(1), value(2)]
        })
        .collect();
    // Duplicates of the first point and of 0 0 0, as depth frames hold.
    if let Some(&first) = points.first() {
        for k in 0..copies as usize {
            points.push(if k % 2 == 0 { first } else { [0.0; 3] });
        }
    }
    let cut = (split as usize * points.len() / 255).clamp(1.min(points.len()), points.len());
    let (source, target) = points.split_at(cut);
    let mut out = [-7.0f64; 16];
    // SAFETY: the arrays hold their counts of packed points; `out` holds 16 doubles.
    unsafe {
        let ctx = sie_context_new();
        let _ = sie_context_set_threads(ctx, 1 + u32::from(settings & 1));
        let _ = sie_context_set_metric(ctx, u32::from((settings >> 1) & 1));
        let _ = sie_context_set_skip_non_finite(ctx, settings & 4 != 0);
        let _ = sie_context_set_skip_origin(ctx, settings & 8 != 0);
        let _ = sie_context_set_cost_function(ctx, u32::from((settings >> 4) & 3), 0.05);
        let _ = sie_context_set_max_iterations(ctx, 1 + u32::from(settings >> 6) * 10);
        let status = sie_context_register_d(
            ctx,
            source.as_ptr().cast(),
            source.len(),
            0,
            target.as_ptr().cast(),
            target.len(),
            0,
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
                // ICP: the initial guess, a narrow β₀, a scale-free lead, a half turn, a period
                // shift or a quarter turn (no warm start here; no global stage, whose starts are 7).
                assert!(
                    matches!(summary.start, 0 | 1 | 2 | 5 | 6 | 8) && summary.starts_run >= 1,
                    "{summary:?}"
                );
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
                let mut matches = vec![0i64; source.len()];
                let got = sie_context_get_correspondences(
                    ctx,
                    matches.as_mut_ptr(),
                    matches.len(),
                    std::ptr::null_mut(),
                );
                assert_eq!(got, sie_status::Ok);
                assert!(matches.iter().all(|&t| (-1..target.len() as i64).contains(&t)));
            }
            sie_status::NonFiniteInput | sie_status::TooFewPoints | sie_status::InvalidArgument => {
                assert!(out.iter().all(|&v| v == -7.0), "outputs written on error");
            }
            other => panic!("unexpected status {other:?}"),
        }
        sie_context_free(ctx);
    }
});
