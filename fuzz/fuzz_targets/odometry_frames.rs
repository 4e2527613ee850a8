//! Odometry (`sie_context_odometry_*`, `sie_odometry_*`): any points cut into up to four frames,
//! some sent twice, at either precision, with any skip settings and both metrics. Every call
//! returns OK with a known frame status, or a registration error with neither output written;
//! a pose is written for FIRST, ACCEPTED and LOOSE only, and the odometry's pose moves only then.
#![no_main]
use std::ptr::null_mut;

use libfuzzer_sys::fuzz_target;
use sie::ffi::*;

mod common;
use common::*;

fuzz_target!(|data: &[u8]| {
    let Some((&[settings, cuts, order, magnitude], rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    // At most 150 points in all (a registration per frame, up to eight frames sent: the cost of an
    // input stays that of the other ICP targets').
    let mut all = points(rest, magnitude);
    all.truncate(150);
    // Up to four frames: three cut points from `cuts`, two bits each.
    let mut bounds = vec![0];
    for k in 0..3 {
        let share = usize::from((cuts >> (2 * k)) & 3);
        let last = *bounds.last().unwrap();
        bounds.push((last + share * all.len() / 8).min(all.len()));
    }
    bounds.push(all.len());
    let frames: Vec<&[[f64; 3]]> = bounds.windows(2).map(|w| &all[w[0]..w[1]]).collect();
    let use_f64 = settings & 1 != 0;
    let padding = usize::from((settings >> 1) & 3);

    // SAFETY (the whole block): every array holds its count of points at its stride; outputs are
    // sized for their calls; the context and the odometry are live until freed.
    unsafe {
        let ctx = sie_context_new();
        assert_eq!(sie_context_set_threads(ctx, 1), sie_status::Ok);
        assert_eq!(
            sie_context_set_skip_non_finite(ctx, settings & 8 != 0),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_set_skip_origin(ctx, settings & 16 != 0),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_set_metric(ctx, u32::from((settings >> 5) & 1)),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_set_starts(ctx, u32::from((settings >> 6) & 1)),
            sie_status::Ok
        );
        assert_eq!(
            sie_context_set_max_iterations(ctx, if settings & 128 != 0 { 6 } else { 2 }),
            sie_status::Ok
        );
        let mut odometry = null_mut();
        assert_eq!(sie_context_odometry_new(ctx, &mut odometry), sie_status::Ok);
        let mut pose_now = [0.0; 16];
        assert_eq!(sie_odometry_pose(odometry, pose_now.as_mut_ptr()), sie_status::Ok);
        for (k, frame) in frames.iter().enumerate() {
            // A frame sent twice when its bit of `order` says so.
            for _ in 0..1 + usize::from((order >> k) & 1) {
                let mut pose = [UNTOUCHED; 16];
                let mut status = u32::MAX;
                let result = if use_f64 {
                    let xyz = strided(frame, padding, |v| v, f64::NAN);
                    sie_context_odometry_register_frame_d(
                        ctx,
                        odometry,
                        xyz.as_ptr(),
                        frame.len(),
                        stride_bytes::<f64>(padding),
                        pose.as_mut_ptr(),
                        &mut status,
                    )
                } else {
                    let xyz = strided(&as_f32(frame), padding, |v| v as f32, f32::NAN);
                    sie_context_odometry_register_frame(
                        ctx,
                        odometry,
                        xyz.as_ptr(),
                        frame.len(),
                        stride_bytes::<f32>(padding),
                        pose.as_mut_ptr(),
                        &mut status,
                    )
                };
                let mut stored = [0.0; 16];
                assert_eq!(sie_odometry_pose(odometry, stored.as_mut_ptr()), sie_status::Ok);
                if result != sie_status::Ok {
                    let message = last_error(ctx);
                    assert!(
                        is_registration_error(result) || result == sie_status::OutOfMemory,
                        "{result:?}: {message}"
                    );
                    assert_eq!(
                        (pose, status),
                        ([UNTOUCHED; 16], u32::MAX),
                        "outputs written on error"
                    );
                    assert_eq!(stored, pose_now, "a refused frame moved the trajectory");
                    continue;
                }
                let moved = [
                    sie_frame_status::First,
                    sie_frame_status::Accepted,
                    sie_frame_status::Loose,
                ]
                .iter()
                .any(|&posed| status == posed as u32);
                assert!(
                    status <= sie_frame_status::Loose as u32,
                    "unknown frame status {status}"
                );
                if moved {
                    assert!(pose.iter().all(|v| v.is_finite()), "{pose:?}");
                    assert_eq!(stored, pose, "the pose written is not the odometry's");
                    pose_now = pose;
                } else {
                    assert_eq!(pose, [UNTOUCHED; 16], "a pose written for frame status {status}");
                    assert_eq!(stored, pose_now, "frame status {status} moved the trajectory");
                }
            }
        }
        sie_odometry_free(odometry);
        sie_context_free(ctx);
    }
});
