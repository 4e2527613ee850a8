//! Reading caller memory: counts, byte strides, non-finite coordinates and transforms, and
//! registrations refused for their input.

use core::ptr::null;

use super::*;
use crate::NonFinite;
use crate::ffi::boundary::FfiError;
use crate::ffi::input::{read_points, read_transform, row_major};

/// A float count whose extent at stride 12 fits the address space, but whose f64 copy (24
/// bytes a point) does not: it passed the size check and panicked ("capacity overflow").
#[test]
fn counts_whose_copy_cannot_exist_are_invalid_arguments() {
    let ctx = Context::new();
    let floats = [0.5f32; 12];
    let mut out = [-7.0f64; 16];
    for count in [0x0aaa_aaaa_aaaa_aaa9usize, (isize::MAX as usize) / 12] {
        let status = unsafe {
            sie_context_register(
                ctx.0,
                floats.as_ptr(),
                count,
                12,
                floats.as_ptr(),
                4,
                0,
                null(),
                out.as_mut_ptr(),
            )
        };
        assert_eq!(
            status,
            sie_status::InvalidArgument,
            "{count:#x}: {}",
            ctx.last_error()
        );
        let message = ctx.last_error();
        assert!(
            message.contains("source_xyz") && message.contains("address space"),
            "{message}"
        );
        let status = unsafe {
            sie_context_register_correspondences(
                ctx.0,
                floats.as_ptr(),
                0,
                floats.as_ptr(),
                0,
                count,
                null(),
                out.as_mut_ptr(),
            )
        };
        assert_eq!(
            status,
            sie_status::InvalidArgument,
            "{count:#x}: {}",
            ctx.last_error()
        );
        let status = unsafe {
            sie_context_register_with_normals(
                ctx.0,
                floats.as_ptr(),
                4,
                0,
                floats.as_ptr(),
                count,
                12,
                floats.as_ptr(),
                12,
                null(),
                out.as_mut_ptr(),
            )
        };
        assert_eq!(
            status,
            sie_status::InvalidArgument,
            "{count:#x}: {}",
            ctx.last_error()
        );
        assert!(ctx.last_error().contains("target_xyz"), "{}", ctx.last_error());
    }
    assert!(out.iter().all(|&v| v == -7.0), "outputs must stay untouched");
}

#[repr(C)]
struct PaddedPoint {
    x: f32,
    y: f32,
    z: f32,
    pad: f32,
}

#[test]
fn points_are_read_with_byte_strides() {
    let cloud: Vec<PaddedPoint> = (0..4)
        .map(|i| PaddedPoint {
            x: i as f32,
            y: 10.0 + i as f32,
            z: 20.0 + i as f32,
            pad: f32::NAN,
        })
        .collect();
    let points =
        unsafe { read_points(&raw const cloud[0].x, 4, 16, "source_xyz", NonFinite::Reject) }.unwrap();
    assert_eq!(points[3], [3.0, 13.0, 23.0]);

    let packed = [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0];
    let points = unsafe { read_points(packed.as_ptr(), 2, 0, "target_xyz", NonFinite::Reject) }.unwrap();
    assert_eq!(points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    // Stride 32 over doubles: every other triple... of a 4-double record.
    let records = [1.0f64, 2.0, 3.0, -1.0, 4.0, 5.0, 6.0, -1.0];
    let points = unsafe { read_points(records.as_ptr(), 2, 32, "target_xyz", NonFinite::Reject) }.unwrap();
    assert_eq!(points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);

    for (stride, scalar) in [(10, "float"), (14, "float"), (8, "float")] {
        let error = unsafe { read_points(&raw const cloud[0].x, 4, stride, "source_xyz", NonFinite::Reject) }
            .unwrap_err();
        assert_eq!(error.status, sie_status::InvalidArgument, "{stride}");
        assert!(error.message.contains(scalar) && error.message.contains(&stride.to_string()));
    }
    let error = unsafe { read_points(packed.as_ptr(), 1, 12, "target_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
    let misaligned = unsafe { packed.as_ptr().byte_add(4) };
    let error = unsafe { read_points(misaligned, 1, 0, "target_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
    assert!(error.message.contains("aligned"), "{}", error.message);
    let error = unsafe { read_points(null::<f32>(), 1, 0, "source_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error, FfiError::null("source_xyz"));
    let error = unsafe {
        read_points(
            packed.as_ptr(),
            usize::MAX / 8,
            0,
            "target_xyz",
            NonFinite::Reject,
        )
    }
    .unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
}

#[test]
fn non_finite_coordinates_name_the_first_bad_point() {
    let mut xyz = vec![0.5f32; 3 * 20];
    xyz[3 * 17 + 1] = f32::NAN;
    xyz[3 * 19] = f32::INFINITY;
    let error = unsafe { read_points(xyz.as_ptr(), 20, 0, "source_xyz", NonFinite::Reject) }.unwrap_err();
    assert_eq!(error.status, sie_status::NonFiniteInput);
    assert!(
        error.message.starts_with("source_xyz[17] is NaN (y"),
        "{}",
        error.message
    );
}

#[test]
fn transforms_are_row_major_and_must_be_rigid() {
    let angle = 0.3f64;
    let (s, c) = angle.sin_cos();
    let row_major_t = [
        c, -s, 0.0, 1.0, s, c, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let rigid = unsafe { read_transform(row_major_t.as_ptr(), "init") }
        .unwrap()
        .unwrap();
    let matrix = rigid.transform;
    assert_eq!(matrix[(0, 3)], 1.0);
    assert!((matrix[(1, 0)] - s).abs() < 1e-15);
    let round_trip = row_major(&matrix);
    assert!(
        round_trip
            .iter()
            .zip(&row_major_t)
            .all(|(a, b)| (a - b).abs() < 1e-15)
    );
    assert!(rigid.correction < 1e-15);
    assert_eq!(unsafe { read_transform(null(), "init") }.unwrap(), None);

    let mut bad = row_major_t;
    bad[0] = 2.0 * c;
    let error = unsafe { read_transform(bad.as_ptr(), "init") }.unwrap_err();
    assert!(error.message.contains("orthonormal"), "{}", error.message);
    let mut bad = row_major_t;
    bad[12] = 1.0;
    let error = unsafe { read_transform(bad.as_ptr(), "init") }.unwrap_err();
    assert!(error.message.contains("last row"), "{}", error.message);
    // Rounding left by a general matrix inverse is accepted.
    let mut rounded = row_major_t;
    rounded[15] = 0.999_999_999_999_999_8;
    assert!(unsafe { read_transform(rounded.as_ptr(), "init") }.is_ok());
    let mut bad = row_major_t;
    bad[7] = f64::NAN;
    let error = unsafe { read_transform(bad.as_ptr(), "init") }.unwrap_err();
    assert!(error.message.contains("init[7] is NaN"), "{}", error.message);
    let mirror = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    let error = unsafe { read_transform(mirror.as_ptr(), "init") }.unwrap_err();
    assert_eq!(error.status, sie_status::InvalidArgument);
    assert!(error.message.contains("reflection"), "{}", error.message);
}

/// Published ground truths are rounded (3DMatch's gt.log, GeoTransformer's gt.npy and PCL's
/// office matrix are orthonormal to 5e-5–7e-5): accepted within 1e-3, made exact, and the
/// correction reported in the summary; the transpose is suggested only when it would be valid.
#[test]
fn rounded_guesses_are_made_rigid_and_the_correction_reported() {
    let rotation = nalgebra::Rotation3::from_euler_angles(0.4, -0.7, 2.1);
    let mut t = Matrix4::identity();
    t.fixed_view_mut::<3, 3>(0, 0).copy_from(rotation.matrix());
    t[(0, 3)] = 1.25;
    // Printed with 4 decimals: orthonormal to ~5e-5, like the published matrices.
    let rounded = row_major(&t).map(|v| (v * 1e4).round() / 1e4);
    let as_matrix = Matrix4::from_row_slice(&rounded);
    let r = as_matrix.fixed_view::<3, 3>(0, 0).into_owned();
    let error = (r.transpose() * r - nalgebra::Matrix3::identity()).amax();
    assert!(error > 1e-5 && error < 2e-4, "{error}");
    let rigid = unsafe { read_transform(rounded.as_ptr(), "init") }
        .unwrap()
        .unwrap();
    let exact = rigid.transform.fixed_view::<3, 3>(0, 0).into_owned();
    assert!((exact.transpose() * exact - nalgebra::Matrix3::identity()).amax() < 1e-15);
    assert!(
        rigid.correction > 1e-6 && rigid.correction < 1e-4,
        "{}",
        rigid.correction
    );
    assert!((rigid.transform - t).amax() < 1e-4);

    // Through a registration: the summary carries the correction.
    let ctx = Context::new();
    let points: Vec<f32> = (0..300)
        .flat_map(|i| [(i % 7) as f32, (i % 11) as f32 * 0.5, (i % 13) as f32 * 0.3])
        .collect();
    let mut out = [0.0; 16];
    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            points.as_ptr(),
            0,
            points.as_ptr(),
            0,
            100,
            rounded.as_ptr(),
            out.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::Ok, "{}", ctx.last_error());
    let mut summary = sie_summary::default();
    assert_eq!(
        unsafe { sie_context_get_summary(ctx.0, &mut summary) },
        sie_status::Ok
    );
    assert_eq!(summary.init_correction, rigid.correction);
    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            points.as_ptr(),
            0,
            points.as_ptr(),
            0,
            100,
            null(),
            out.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::Ok);
    assert_eq!(
        unsafe { sie_context_get_summary(ctx.0, &mut summary) },
        sie_status::Ok
    );
    assert_eq!(summary.init_correction, 0.0);

    // Beyond 1e-3 it is not a rotation; transposing would not help, so no hint.
    let mut skewed = row_major(&t);
    skewed[1] += 2e-3;
    let error = unsafe { read_transform(skewed.as_ptr(), "init") }.unwrap_err();
    assert!(
        error.message.contains("orthonormal") && !error.message.contains("column-major"),
        "{}",
        error.message
    );
    // A rigid transform stored column-major: its transpose is valid, so the hint is given.
    let column_major: Vec<f64> = (0..16).map(|k| t[(k % 4, k / 4)]).collect();
    let error = unsafe { read_transform(column_major.as_ptr(), "init") }.unwrap_err();
    assert!(
        error.message.contains("last row") && error.message.contains("column-major"),
        "{}",
        error.message
    );
    // Scaled: neither it nor its transpose is rigid.
    let scaled = row_major(&(t * 2.0));
    let error = unsafe { read_transform(scaled.as_ptr(), "init") }.unwrap_err();
    assert!(!error.message.contains("column-major"), "{}", error.message);
}

#[test]
fn failed_registration_keeps_outputs_and_drops_the_previous_result() {
    let ctx = Context::new();
    ctx.inject_result(sample_result());
    let mut xyz = vec![0.0f32; 3 * 30];
    xyz[3 * 17] = f32::NAN;
    let mut out_t = [-1.0; 16];
    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            xyz.as_ptr(),
            0,
            xyz.as_ptr(),
            0,
            30,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::NonFiniteInput);
    assert!(
        ctx.last_error().contains("source_xyz[17]"),
        "{}",
        ctx.last_error()
    );
    assert_eq!(out_t, [-1.0; 16]);
    assert!(!ctx.has_result());

    let status = unsafe {
        sie_context_register_correspondences(
            ctx.0,
            xyz.as_ptr(),
            0,
            xyz.as_ptr(),
            0,
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::TooFewPoints);
    assert_eq!(ctx.last_error(), "count is 0");

    let mut normals = vec![0.0f32; 3 * 30];
    xyz[3 * 17] = 0.0;
    let register_with = |normals: &[f32], out_t: &mut [f64; 16]| unsafe {
        sie_context_register_with_normals(
            ctx.0,
            xyz.as_ptr(),
            30,
            0,
            xyz.as_ptr(),
            30,
            0,
            normals.as_ptr(),
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(register_with(&normals, &mut out_t), sie_status::InvalidArgument);
    assert!(
        ctx.last_error().contains("every target normal is 0 0 0"),
        "{}",
        ctx.last_error()
    );
    normals[2] = 0.5;
    let status = unsafe {
        sie_context_register_with_normals(
            ctx.0,
            xyz.as_ptr(),
            30,
            0,
            xyz.as_ptr(),
            30,
            0,
            normals.as_ptr(),
            0,
            null(),
            out_t.as_mut_ptr(),
        )
    };
    assert_eq!(status, sie_status::InvalidArgument);
    assert!(
        ctx.last_error().contains("target normals[0] has length 0.5"),
        "{}",
        ctx.last_error()
    );
}
