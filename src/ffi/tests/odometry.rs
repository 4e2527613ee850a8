//! Odometry through the ABI: statuses per frame, poses written only for accepted frames, bad
//! frames returning their error with the caller's buffers and the trajectory untouched.

use core::ptr::{null, null_mut};

use super::*;
use crate::geometry::{rotation_angle, rotation_part, translation_part};
use crate::synthetic::room_trajectory;

fn packed(points: &[crate::Point]) -> Vec<f32> {
    points.iter().flat_map(|p| p.map(|v| v as f32)).collect()
}

fn matrix(row_major: &[f64; 16]) -> Matrix4<f64> {
    Matrix4::from_row_slice(row_major)
}

/// The odometry's stored pose.
fn pose_of(odometry: *const sie_odometry) -> [f64; 16] {
    let mut pose = [0.0; 16];
    // SAFETY: live odometry, 16 writable doubles.
    assert_eq!(
        unsafe { sie_odometry_pose(odometry, pose.as_mut_ptr()) },
        sie_status::Ok
    );
    pose
}

#[test]
fn frames_get_statuses_and_bad_ones_change_nothing() {
    let trajectory = room_trajectory(40, 3_000, 0.01, 7);
    let world = trajectory.poses[0].try_inverse().unwrap();
    let frames: Vec<Vec<f32>> = trajectory.frames.iter().map(|f| packed(f)).collect();
    let ctx = Context::new();
    let mut odometry: *mut sie_odometry = null_mut();
    // SAFETY (all calls): live context and odometry, arrays of the stated sizes, or NULL.
    unsafe {
        assert_eq!(
            sie_context_odometry_new(ctx.0, null_mut()),
            sie_status::NullArgument
        );
        assert_eq!(
            sie_context_set_max_iterations(ctx.0, 0),
            sie_status::InvalidArgument
        );
        assert_eq!(sie_context_odometry_new(ctx.0, &mut odometry), sie_status::Ok);
        let (mut pose, mut status) = ([7.0; 16], 99u32);
        let register = |xyz: &[f32], pose: &mut [f64; 16], status: &mut u32| {
            sie_context_odometry_register_frame(
                ctx.0,
                odometry,
                xyz.as_ptr(),
                xyz.len() / 3,
                0,
                pose.as_mut_ptr(),
                status,
            )
        };
        assert_eq!(register(&frames[0], &mut pose, &mut status), sie_status::Ok);
        assert_eq!(status, sie_frame_status::First as u32);
        assert_eq!(matrix(&pose), Matrix4::identity());
        assert_eq!(register(&frames[1], &mut pose, &mut status), sie_status::Ok);
        assert_eq!(status, sie_frame_status::Accepted as u32);
        let mut summary = sie_summary::default();
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::Ok);
        assert_eq!(summary.verdict, sie_verdict::Good as u32);
        let accepted = pose;
        assert_eq!(pose_of(odometry), accepted);

        // Bad frames: their error, the buffers and the trajectory as they were.
        let (mut untouched_pose, mut untouched_status) = ([7.0; 16], 99u32);
        let with_nan: Vec<f32> = frames[2]
            .iter()
            .enumerate()
            .map(|(i, &v)| if i == 4 { f32::NAN } else { v })
            .collect();
        for (name, xyz, expected) in [
            ("two points", &frames[2][..6], sie_status::TooFewPoints),
            ("a NaN", &with_nan[..], sie_status::NonFiniteInput),
        ] {
            assert_eq!(
                register(xyz, &mut untouched_pose, &mut untouched_status),
                expected,
                "{name}"
            );
            assert_eq!((untouched_pose, untouched_status), ([7.0; 16], 99), "{name}");
            assert_eq!(pose_of(odometry), accepted, "{name}");
            assert!(!ctx.has_result(), "{name}: no result stored");
        }
        assert_eq!(
            sie_context_odometry_register_frame(
                ctx.0,
                odometry,
                null(),
                5,
                0,
                pose.as_mut_ptr(),
                &mut status
            ),
            sie_status::NullArgument
        );
        assert!(ctx.last_error().contains("xyz"), "{}", ctx.last_error());
        assert_eq!(
            sie_context_odometry_register_frame(
                ctx.0,
                null_mut(),
                frames[2].as_ptr(),
                5,
                0,
                pose.as_mut_ptr(),
                &mut status
            ),
            sie_status::NullArgument
        );
        assert!(ctx.last_error().contains("odometry"), "{}", ctx.last_error());
        assert_eq!(
            register(&frames[1], &mut untouched_pose, &mut untouched_status),
            sie_status::Ok
        );
        assert_eq!(
            (untouched_pose, untouched_status),
            ([7.0; 16], sie_frame_status::Repeated as u32)
        );

        // Two frames came bad (2 and 3 above, as the sensor moved on): frame 3 continues from
        // a guess two frames further, and lands on the truth.
        assert_eq!(register(&frames[3], &mut pose, &mut status), sie_status::Ok);
        assert_eq!(status, sie_frame_status::Accepted as u32);
        let error = (world * trajectory.poses[3]).try_inverse().unwrap() * matrix(&pose);
        let (degrees, metres) = (
            rotation_angle(&rotation_part(&error)).to_degrees(),
            translation_part(&error).norm(),
        );
        assert!(degrees < 0.1 && metres < 0.005, "{degrees:.3}° / {metres:.4} m");
        assert_eq!(pose_of(odometry), pose);

        sie_odometry_skip_frame(null_mut());
        sie_odometry_free(odometry);
        sie_odometry_free(null_mut());
        assert_eq!(
            sie_odometry_pose(null(), pose.as_mut_ptr()),
            sie_status::NullArgument
        );
    }
}
