//! Prepared targets (one shared by contexts on several threads) and warm starts read from a
//! summary.

use core::ptr::{null, null_mut};

use super::*;

/// Packed float triples of a synthetic room scene, for full registrations through the ABI.
fn packed(points: &[crate::Point]) -> Vec<f32> {
    points.iter().flat_map(|p| p.map(|v| v as f32)).collect()
}

#[test]
fn prepared_target_arguments_are_checked_and_outputs_untouched() {
    let ctx = Context::new();
    let xyz = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let mut target: *mut sie_target = null_mut();
    let mut transform = [7.0; 16];
    // SAFETY (all calls): valid arrays or NULL, as each contract allows.
    unsafe {
        assert_eq!(
            sie_context_prepare_target(null_mut(), xyz.as_ptr(), 4, 0, null(), 0, &mut target),
            sie_status::NullArgument
        );
        assert_eq!(
            sie_context_prepare_target(ctx.0, xyz.as_ptr(), 4, 0, null(), 0, null_mut()),
            sie_status::NullArgument
        );
        assert!(ctx.last_error().contains("out_target"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_prepare_target(ctx.0, xyz.as_ptr(), 0, 0, null(), 0, &mut target),
            sie_status::TooFewPoints
        );
        let non_unit = [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5];
        assert_eq!(
            sie_context_prepare_target(ctx.0, xyz.as_ptr(), 4, 0, non_unit.as_ptr(), 0, &mut target),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("normals[3]"), "{}", ctx.last_error());
        assert!(target.is_null(), "not written on error");
        assert_eq!(
            sie_context_prepare_target_d(ctx.0, [0.0f64; 12].as_ptr(), 4, 0, null(), 0, &mut target),
            sie_status::Ok
        );
        assert_eq!(sie_target_point_count(target), 4);
        assert_eq!(
            sie_context_register_to(ctx.0, xyz.as_ptr(), 4, 0, null(), null(), transform.as_mut_ptr()),
            sie_status::NullArgument
        );
        assert!(ctx.last_error().contains("target"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_register_to(ctx.0, xyz.as_ptr(), 2, 0, target, null(), transform.as_mut_ptr()),
            sie_status::TooFewPoints
        );
        assert_eq!(transform, [7.0; 16]);
        assert_eq!(
            sie_target_estimate_normals(target, 1025),
            sie_status::InvalidArgument
        );
        sie_target_free(target);
    }
}

#[test]
fn contexts_on_several_threads_share_one_prepared_target() {
    let scene = crate::synthetic::room_scene(3_000, 0.01, 31);
    let (source, target_points) = (packed(&scene.source), packed(&scene.target));
    let serial = Context::new();
    let mut expected = [0.0; 16];
    let mut target: *mut sie_target = null_mut();
    // SAFETY: packed arrays of the stated counts; outputs valid.
    unsafe {
        assert_eq!(sie_context_set_threads(serial.0, 1), sie_status::Ok);
        assert_eq!(
            sie_context_register(
                serial.0,
                source.as_ptr(),
                3_000,
                0,
                target_points.as_ptr(),
                3_000,
                0,
                null(),
                expected.as_mut_ptr()
            ),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_prepare_target(serial.0, target_points.as_ptr(), 3_000, 0, null(), 0, &mut target),
            sie_status::Ok
        );
    }
    // The pointer crosses threads as an address: the target is Sync, and outlives the scope.
    let address = target as usize;
    let results: Vec<[f64; 16]> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..4)
            .map(|_| {
                let source = &source;
                scope.spawn(move || {
                    let ctx = Context::new();
                    let mut transform = [0.0; 16];
                    // SAFETY: live context and target; packed source of 3000 points.
                    let status = unsafe {
                        sie_context_set_threads(ctx.0, 1);
                        sie_context_register_to(
                            ctx.0,
                            source.as_ptr(),
                            3_000,
                            0,
                            address as *const sie_target,
                            null(),
                            transform.as_mut_ptr(),
                        )
                    };
                    assert_eq!(status, sie_status::Ok, "{}", ctx.last_error());
                    transform
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for transform in results {
        assert_eq!(transform.map(f64::to_bits), expected.map(f64::to_bits));
    }
    // SAFETY: created above, every user has returned.
    unsafe { sie_target_free(target) };
}

#[test]
fn warm_start_is_read_from_a_summary_and_checked() {
    let scene = crate::synthetic::room_scene(3_000, 0.01, 31);
    let (source, target) = (packed(&scene.source), packed(&scene.target));
    let ctx = Context::new();
    let mut transform = [0.0; 16];
    let mut summary = sie_summary::default();
    // SAFETY: live context, packed arrays of 3000 points, outputs valid.
    unsafe {
        assert_eq!(sie_context_set_threads(ctx.0, 1), sie_status::Ok);
        // `guess` NULL: the identity.
        let register = |guess: *const f64, transform: &mut [f64; 16]| {
            sie_context_register(
                ctx.0,
                source.as_ptr(),
                3_000,
                0,
                target.as_ptr(),
                3_000,
                0,
                guess,
                transform.as_mut_ptr(),
            )
        };
        assert_eq!(register(null(), &mut transform), sie_status::Ok);
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::Ok);
        assert_eq!(sie_context_set_warm_start(ctx.0, &summary), sie_status::Ok);
        let warm = ctx.config().warm_start.expect("stored");
        assert_eq!(warm.sigma, summary.sigma[0]);
        assert_eq!(
            (warm.penalty, warm.inlier_fraction),
            (summary.penalty, summary.inlier_fraction)
        );
        // The same pair from its own answer: the warm run is kept.
        let guess = transform;
        assert_eq!(register(guess.as_ptr(), &mut transform), sie_status::Ok);
        let mut warm_summary = sie_summary::default();
        assert_eq!(sie_context_get_summary(ctx.0, &mut warm_summary), sie_status::Ok);
        assert_eq!(warm_summary.start, sie_start_kind::WarmStart as u32);
        assert_eq!(warm_summary.starts_run, 1);
        assert!(warm_summary.iterations < summary.iterations);

        // NULL clears it, and so does a summary whose verdict is not GOOD (its successor
        // runs cold).
        assert_eq!(summary.verdict, sie_verdict::Good as u32);
        assert_eq!(sie_context_set_warm_start(ctx.0, null()), sie_status::Ok);
        assert_eq!(ctx.config().warm_start, None);
        assert_eq!(sie_context_set_warm_start(ctx.0, &summary), sie_status::Ok);
        let doubtful = sie_summary {
            verdict: sie_verdict::Doubtful as u32,
            ..summary
        };
        assert_eq!(sie_context_set_warm_start(ctx.0, &doubtful), sie_status::Ok);
        assert_eq!(ctx.config().warm_start, None);

        // A baseline's summary, out-of-range values and an unknown verdict are refused, saying
        // which, and leave the setting as it was.
        assert_eq!(sie_context_set_warm_start(ctx.0, &summary), sie_status::Ok);
        let before = ctx.config();
        assert!(before.warm_start.is_some());
        let refused = [
            (
                sie_summary {
                    histogram_count: 0,
                    ..summary
                },
                "previous holds no SIE noise model",
            ),
            (
                sie_summary {
                    sigma: [-1.0, 0.0, 0.0],
                    histogram_count: 1,
                    ..summary
                },
                "sigma",
            ),
            (
                sie_summary {
                    verdict: 9,
                    ..summary
                },
                "previous->verdict = 9",
            ),
        ];
        for (bad, says) in &refused {
            assert_eq!(
                sie_context_set_warm_start(ctx.0, bad),
                sie_status::InvalidArgument
            );
            assert!(ctx.last_error().contains(says), "{}", ctx.last_error());
        }
        let misaligned = (&summary as *const sie_summary)
            .cast::<u8>()
            .wrapping_add(1)
            .cast::<sie_summary>();
        assert_eq!(
            sie_context_set_warm_start(ctx.0, misaligned),
            sie_status::InvalidArgument
        );
        assert!(ctx.last_error().contains("not aligned"), "{}", ctx.last_error());
        assert_eq!(ctx.config(), before);
    }
}
