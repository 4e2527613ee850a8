//! Every C entry point against every bad input: the documented status, a message, and output
//! buffers left exactly as they were. Backs the table in docs/reliability.md.
use std::ffi::CStr;
use std::ptr::{null, null_mut};

use sie::ffi::*;

const SENTINEL: f64 = -4242.0;

struct Context(*mut sie_context);

impl Context {
    fn new() -> Self {
        Context(sie_context_new())
    }
    fn last_error(&self) -> String {
        // SAFETY: live context.
        unsafe { CStr::from_ptr(sie_context_last_error(self.0)) }
            .to_string_lossy()
            .into_owned()
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: from sie_context_new, freed once.
        unsafe { sie_context_free(self.0) };
    }
}

/// A float cloud of `n` points in a 16-byte-stride buffer (like pcl::PointXYZ) on a tilted
/// grid, so that normals and registration are well defined.
fn cloud(n: usize, shift: f32) -> Vec<[f32; 4]> {
    (0..n)
        .map(|i| {
            let (u, v) = ((i % 50) as f32 * 0.02, (i / 50) as f32 * 0.02);
            [
                u + shift,
                v,
                0.3 * u + 0.2 * (v * 3.0).sin() + (u * 5.0).cos() * 0.1,
                0.0,
            ]
        })
        .collect()
}

/// The five registration entry points behind one signature: (ctx, source, n_source, stride,
/// target, n_target, stride, out). Correspondence variants use n_source as the pair count.
#[derive(Clone, Copy, Debug)]
enum Entry {
    Clouds,
    CloudsDouble,
    CloudsWithNormals,
    Pairs,
    PairsDouble,
}

const ENTRIES: [Entry; 5] = [
    Entry::Clouds,
    Entry::CloudsDouble,
    Entry::CloudsWithNormals,
    Entry::Pairs,
    Entry::PairsDouble,
];

struct Call<'a> {
    ctx: *mut sie_context,
    source: Option<&'a [[f32; 4]]>,
    source_count: usize,
    source_stride: usize,
    target: Option<&'a [[f32; 4]]>,
    target_count: usize,
    target_stride: usize,
    /// Byte offset added to the source pointer (misalignment).
    source_offset: usize,
    out: Option<&'a mut [f64; 16]>,
}

fn as_f64(points: &[[f32; 4]]) -> Vec<[f64; 4]> {
    points.iter().map(|p| p.map(f64::from)).collect()
}

fn call(entry: Entry, c: Call) -> sie_status {
    let out = c.out.map_or(null_mut(), |o| o.as_mut_ptr());
    let f32_ptr = |p: Option<&[[f32; 4]]>, offset: usize| {
        p.map_or(null(), |p| {
            (p.as_ptr() as *const u8).wrapping_add(offset) as *const f32
        })
    };
    let (src64, tgt64) = (c.source.map(as_f64), c.target.map(as_f64));
    let f64_ptr = |p: &Option<Vec<[f64; 4]>>, offset: usize| {
        p.as_ref().map_or(null(), |p| {
            (p.as_ptr() as *const u8).wrapping_add(offset) as *const f64
        })
    };
    // Double arrays have twice the stride of the float ones.
    let double = |stride: usize| stride * 2;
    let normals: Vec<[f32; 4]> = vec![[0.0, 0.0, 1.0, 0.0]; c.target_count.max(1)];
    // SAFETY: every non-NULL pointer covers its count at its stride (the test's own faults
    // are stride and alignment values the library must reject before reading).
    unsafe {
        match entry {
            Entry::Clouds => sie_context_register(
                c.ctx,
                f32_ptr(c.source, c.source_offset),
                c.source_count,
                c.source_stride,
                f32_ptr(c.target, 0),
                c.target_count,
                c.target_stride,
                null(),
                out,
            ),
            Entry::CloudsDouble => sie_context_register_d(
                c.ctx,
                f64_ptr(&src64, c.source_offset),
                c.source_count,
                double(c.source_stride),
                f64_ptr(&tgt64, 0),
                c.target_count,
                double(c.target_stride),
                null(),
                out,
            ),
            Entry::CloudsWithNormals => sie_context_register_with_normals(
                c.ctx,
                f32_ptr(c.source, c.source_offset),
                c.source_count,
                c.source_stride,
                f32_ptr(c.target, 0),
                c.target_count,
                c.target_stride,
                normals.as_ptr().cast(),
                16,
                null(),
                out,
            ),
            Entry::Pairs => sie_context_register_correspondences(
                c.ctx,
                f32_ptr(c.source, c.source_offset),
                c.source_stride,
                f32_ptr(c.target, 0),
                c.target_stride,
                c.source_count,
                null(),
                out,
            ),
            Entry::PairsDouble => sie_context_register_correspondences_d(
                c.ctx,
                f64_ptr(&src64, c.source_offset),
                double(c.source_stride),
                f64_ptr(&tgt64, 0),
                double(c.target_stride),
                c.source_count,
                null(),
                out,
            ),
        }
    }
}

fn is_pairs(entry: Entry) -> bool {
    matches!(entry, Entry::Pairs | Entry::PairsDouble)
}

/// One fault: how to break a good call, the status it must give, and a word the message
/// must contain.
struct Fault {
    name: &'static str,
    status: sie_status,
    message: &'static str,
    apply: fn(&mut Setup),
}

struct Setup {
    null_ctx: bool,
    null_source: bool,
    null_target: bool,
    null_out: bool,
    source_count: usize,
    target_count: usize,
    source_stride: usize,
    source_offset: usize,
    nan_at: Option<usize>,
    inf_in_target_at: Option<usize>,
}

const N: usize = 2000;

fn faults() -> Vec<Fault> {
    vec![
        Fault {
            name: "NULL context",
            status: sie_status::NullArgument,
            message: "",
            apply: |s| s.null_ctx = true,
        },
        Fault {
            name: "NULL source array",
            status: sie_status::NullArgument,
            message: "source_xyz",
            apply: |s| s.null_source = true,
        },
        Fault {
            name: "NULL target array",
            status: sie_status::NullArgument,
            message: "target_xyz",
            apply: |s| s.null_target = true,
        },
        Fault {
            name: "NULL output",
            status: sie_status::NullArgument,
            message: "out_T_target_source",
            apply: |s| s.null_out = true,
        },
        Fault {
            name: "n = 0",
            status: sie_status::TooFewPoints,
            message: "0",
            apply: |s| s.source_count = 0,
        },
        Fault {
            name: "n = 1",
            status: sie_status::TooFewPoints,
            message: "1",
            apply: |s| s.source_count = 1,
        },
        Fault {
            name: "n = 2",
            status: sie_status::TooFewPoints,
            message: "2",
            apply: |s| s.source_count = 2,
        },
        Fault {
            name: "stride 8 (< 12 bytes)",
            status: sie_status::InvalidArgument,
            message: "stride",
            apply: |s| s.source_stride = 8,
        },
        Fault {
            name: "stride 14 (not a multiple of 4)",
            status: sie_status::InvalidArgument,
            message: "stride",
            apply: |s| s.source_stride = 14,
        },
        Fault {
            name: "misaligned pointer",
            status: sie_status::InvalidArgument,
            message: "align",
            apply: |s| s.source_offset = 2,
        },
        Fault {
            name: "NaN coordinate",
            status: sie_status::NonFiniteInput,
            message: "source_xyz[1234]",
            apply: |s| s.nan_at = Some(1234),
        },
        Fault {
            name: "infinite coordinate",
            status: sie_status::NonFiniteInput,
            message: "target_xyz[77]",
            apply: |s| s.inf_in_target_at = Some(77),
        },
    ]
}

#[test]
fn every_registration_entry_point_rejects_every_fault_without_writing() {
    let ctx = Context::new();
    let mut rows = Vec::new();
    for entry in ENTRIES {
        for fault in faults() {
            let mut setup = Setup {
                null_ctx: false,
                null_source: false,
                null_target: false,
                null_out: false,
                source_count: N,
                target_count: N,
                source_stride: 16,
                source_offset: 0,
                nan_at: None,
                inf_in_target_at: None,
            };
            (fault.apply)(&mut setup);
            let mut source = cloud(N, 0.01);
            let mut target = cloud(N, 0.0);
            if let Some(i) = setup.nan_at {
                source[i][1] = f32::NAN;
            }
            if let Some(i) = setup.inf_in_target_at {
                target[i][0] = f32::INFINITY;
            }
            if is_pairs(entry) {
                setup.target_count = setup.source_count;
            }
            let mut out = [SENTINEL; 16];
            let status = call(
                entry,
                Call {
                    ctx: if setup.null_ctx { null_mut() } else { ctx.0 },
                    source: (!setup.null_source).then_some(&source[..]),
                    source_count: setup.source_count,
                    source_stride: setup.source_stride,
                    target: (!setup.null_target).then_some(&target[..]),
                    target_count: setup.target_count,
                    target_stride: 16,
                    source_offset: setup.source_offset,
                    out: (!setup.null_out).then_some(&mut out),
                },
            );
            let message = if setup.null_ctx {
                String::new()
            } else {
                ctx.last_error()
            };
            assert_eq!(status, fault.status, "{entry:?} / {}: {message}", fault.name);
            assert!(
                message.contains(fault.message),
                "{entry:?} / {}: message {message:?}",
                fault.name
            );
            assert!(
                out.iter().all(|&v| v == SENTINEL),
                "{entry:?} / {}: output written",
                fault.name
            );
            rows.push(format!("{entry:?} | {} | {status:?} | {message}", fault.name));
        }
    }
    println!("{}", rows.join("\n"));
}

#[test]
fn wildly_different_cloud_sizes_register_or_report_degeneracy() {
    let ctx = Context::new();
    let big = cloud(100_000, 0.01);
    let tiny = cloud(3, 0.0);
    for (source, target) in [(&tiny, &big), (&big, &tiny)] {
        let mut out = [SENTINEL; 16];
        let status = call(
            Entry::Clouds,
            Call {
                ctx: ctx.0,
                source: Some(source),
                source_count: source.len(),
                source_stride: 16,
                target: Some(target),
                target_count: target.len(),
                target_stride: 16,
                source_offset: 0,
                out: Some(&mut out),
            },
        );
        assert_eq!(
            status,
            sie_status::Ok,
            "{} -> {}: {}",
            source.len(),
            target.len(),
            ctx.last_error()
        );
        assert!(out.iter().all(|v| v.is_finite()));
        let mut summary = sie_summary::default();
        // SAFETY: live context, valid out pointer.
        assert_eq!(
            unsafe { sie_context_get_summary(ctx.0, &mut summary) },
            sie_status::Ok
        );
        assert!(summary.rmse.is_finite() && summary.inlier_fraction.is_finite());
    }
}

#[test]
fn getters_report_null_no_result_and_small_buffers_without_writing() {
    let ctx = Context::new();
    let mut values = [SENTINEL; 8];
    let mut indices = [-9i64; 8];
    let mut len = 777usize;
    let mut summary = sie_summary::default();
    let mut model = sie_model::default();
    let mut trace = [sie_trace_entry::default(); 2];
    // SAFETY: every pointer is valid for its capacity or NULL on purpose.
    unsafe {
        // Before any registration: NO_RESULT from every getter.
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::NoResult);
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, values.as_mut_ptr(), 8, &mut len),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_correspondences(ctx.0, indices.as_mut_ptr(), 8, &mut len),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                0,
                &mut model,
                null_mut(),
                null_mut(),
                null_mut(),
                null_mut(),
                0
            ),
            sie_status::NoResult
        );
        assert_eq!(
            sie_context_get_trace(ctx.0, trace.as_mut_ptr(), 2, &mut len),
            sie_status::NoResult
        );
        // NULL context.
        assert_eq!(
            sie_context_get_summary(null(), &mut summary),
            sie_status::NullArgument
        );
        assert_eq!(
            sie_context_get_trace(null(), trace.as_mut_ptr(), 2, &mut len),
            sie_status::NullArgument
        );

        // After a registration of N points: capacity < N is BUFFER_TOO_SMALL, nothing written.
        let (source, target) = (cloud(N, 0.01), cloud(N, 0.0));
        let mut out = [SENTINEL; 16];
        let status = sie_context_register(
            ctx.0,
            source.as_ptr().cast(),
            N,
            16,
            target.as_ptr().cast(),
            N,
            16,
            null(),
            out.as_mut_ptr(),
        );
        assert_eq!(status, sie_status::Ok);
        assert_eq!(
            sie_context_get_summary(ctx.0, null_mut()),
            sie_status::NullArgument
        );
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, values.as_mut_ptr(), 8, &mut len),
            sie_status::BufferTooSmall
        );
        assert!(ctx.last_error().contains(&N.to_string()), "{}", ctx.last_error());
        assert_eq!(
            sie_context_get_correspondences(ctx.0, indices.as_mut_ptr(), 8, &mut len),
            sie_status::BufferTooSmall
        );
        assert!(values.iter().all(|&v| v == SENTINEL) && indices.iter().all(|&i| i == -9));
        assert_eq!(len, 777, "out_len must not be written on error");
        // Size query: NULL buffer with capacity 0 reports the length.
        assert_eq!(
            sie_context_get_inlier_probabilities(ctx.0, null_mut(), 0, &mut len),
            sie_status::Ok
        );
        assert_eq!(len, N);
        // Histogram arrays smaller than the bin count, and an index past the last histogram.
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                0,
                &mut model,
                values.as_mut_ptr(),
                null_mut(),
                null_mut(),
                null_mut(),
                8
            ),
            sie_status::BufferTooSmall
        );
        assert_eq!(
            sie_context_get_histogram(
                ctx.0,
                5,
                &mut model,
                null_mut(),
                null_mut(),
                null_mut(),
                null_mut(),
                0
            ),
            sie_status::InvalidArgument
        );
        assert!(values.iter().all(|&v| v == SENTINEL));
    }
}

#[test]
fn setters_reject_unknown_and_out_of_range_values_and_keep_the_old_setting() {
    let ctx = Context::new();
    let rejected = |status: sie_status, word: &str| {
        assert_eq!(status, sie_status::InvalidArgument, "{word}");
        assert!(ctx.last_error().contains(word), "{word}: {}", ctx.last_error());
    };
    // SAFETY: live context and valid buffers.
    unsafe {
        assert_eq!(sie_context_set_max_iterations(ctx.0, 3), sie_status::Ok);
        // One start, so the cap is the whole run's update count.
        assert_eq!(
            sie_context_set_starts(ctx.0, sie_starts::InitialGuess as u32),
            sie_status::Ok
        );
        rejected(sie_context_set_cost_function(ctx.0, 99, 0.0), "99");
        rejected(
            sie_context_set_cost_function(ctx.0, sie_cost_function::Huber as u32, -1.0),
            "Huber",
        );
        rejected(sie_context_set_metric(ctx.0, 7), "7");
        rejected(sie_context_set_max_iterations(ctx.0, 0), "max_iterations");
        rejected(sie_context_set_convergence(ctx.0, f64::NAN, 1e-6), "translation");
        rejected(sie_context_set_noise_model(ctx.0, 3), "3");
        rejected(sie_context_set_noise_shape(ctx.0, -2.0), "-2");
        rejected(sie_context_set_regularizer(ctx.0, 0.0, 1.5), "shrink");
        rejected(sie_context_set_normal_neighbours(ctx.0, 1), "normal_neighbours");
        rejected(sie_context_set_histogram_mode(ctx.0, 2), "2");
        rejected(sie_context_set_starts(ctx.0, 9), "starts = 9");
        assert_eq!(sie_context_set_threads(null_mut(), 1), sie_status::NullArgument);
        assert_eq!(sie_context_set_starts(null_mut(), 0), sie_status::NullArgument);
        // The rejected max_iterations = 0 left the earlier 3 in place, the rejected starts = 9
        // the single start.
        let (source, target) = (cloud(N, 0.05), cloud(N, 0.0));
        let mut out = [SENTINEL; 16];
        let status = sie_context_register(
            ctx.0,
            source.as_ptr().cast(),
            N,
            16,
            target.as_ptr().cast(),
            N,
            16,
            null(),
            out.as_mut_ptr(),
        );
        assert_eq!(status, sie_status::Ok);
        let mut summary = sie_summary::default();
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::Ok);
        assert_eq!(summary.iterations, 3);
        assert_eq!(summary.starts_run, 1);
        assert_eq!(summary.stop_reason, sie_stop_reason::IterationLimit as u32);
        // Automatic starts: the cap holds for each start (three SIE runs and the scale-free
        // lead's), and iterations counts the updates of all of them.
        assert_eq!(
            sie_context_set_starts(ctx.0, sie_starts::Automatic as u32),
            sie_status::Ok
        );
        let status = sie_context_register(
            ctx.0,
            source.as_ptr().cast(),
            N,
            16,
            target.as_ptr().cast(),
            N,
            16,
            null(),
            out.as_mut_ptr(),
        );
        assert_eq!(status, sie_status::Ok);
        assert_eq!(sie_context_get_summary(ctx.0, &mut summary), sie_status::Ok);
        assert_eq!(summary.starts_run, 3);
        assert!(
            (9..=12).contains(&summary.iterations),
            "{} updates from 3 SIE starts and a lead, each capped at 3",
            summary.iterations
        );
    }
}

#[test]
fn estimate_inliers_rejects_bad_matrices_without_writing() {
    let ctx = Context::new();
    let residuals = [0.1, -0.2, 0.05, f64::NAN, 0.3, 0.0];
    let mut p = [SENTINEL; 6];
    let mut count = 99usize;
    let run = |residuals: *const f64,
               rows: usize,
               cols: usize,
               scales: *const f64,
               beta: f64,
               p: &mut [f64; 6],
               count: &mut usize| {
        // SAFETY: buffers hold at least rows entries.
        unsafe {
            sie_estimate_inliers(
                ctx.0,
                residuals,
                rows,
                cols,
                scales,
                beta,
                p.as_mut_ptr(),
                null_mut(),
                0,
                count,
            )
        }
    };
    assert_eq!(
        run(residuals.as_ptr(), 6, 1, null(), 0.0, &mut p, &mut count),
        sie_status::NonFiniteInput
    );
    assert!(ctx.last_error().contains("residuals[3]"));
    assert_eq!(
        run(null(), 6, 1, null(), 0.0, &mut p, &mut count),
        sie_status::NullArgument
    );
    assert_eq!(
        run(residuals.as_ptr(), 0, 1, null(), 0.0, &mut p, &mut count),
        sie_status::TooFewPoints
    );
    assert_eq!(
        run(residuals.as_ptr(), 3, 0, null(), 0.0, &mut p, &mut count),
        sie_status::InvalidArgument
    );
    assert_eq!(
        run(residuals.as_ptr(), 3, 1, null(), -1.0, &mut p, &mut count),
        sie_status::InvalidArgument
    );
    let scales = [1.0, 0.0, 1.0];
    assert_eq!(
        run(residuals.as_ptr(), 3, 1, scales.as_ptr(), 0.0, &mut p, &mut count),
        sie_status::InvalidArgument
    );
    assert!(ctx.last_error().contains("row_scales[1]"));
    assert!(p.iter().all(|&v| v == SENTINEL));
    assert_eq!(count, 99);
}

/// A bumpy 1 × 0.8 m surface (curved both ways, so it fixes every direction) sampled on a 2 cm
/// grid moved by (du, dv), with up to 2 mm of noise along z (a hash of the index and `seed`):
/// two samplings of one surface, as two scans see it.
fn noisy_surface(du: f32, dv: f32, seed: u32) -> Vec<[f32; 4]> {
    (0..N as u32)
        .map(|i| {
            let (u, v) = ((i % 50) as f32 * 0.02 + du, (i / 50) as f32 * 0.02 + dv);
            let hash =
                (i.wrapping_mul(2_654_435_761) ^ seed.wrapping_mul(40_503)).wrapping_mul(2_246_822_519);
            let noise = 0.002 * ((hash >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 2.0;
            [
                u,
                v,
                0.3 * u + 0.1 * (u * 9.0).sin() + 0.1 * (v * 7.0).cos() + noise,
                0.0,
            ]
        })
        .collect()
}

/// Odometry frames against every bad input: the documented status, a message, both outputs and
/// the trajectory untouched; a good frame afterwards is registered as if none had come.
#[test]
fn odometry_rejects_every_frame_fault_without_writing_or_moving() {
    let ctx = Context::new();
    let mut odometry = null_mut();
    let pose_of = |odometry| {
        let mut pose = [0.0; 16];
        // SAFETY: live odometry, 16 writable doubles.
        assert_eq!(
            unsafe { sie_odometry_pose(odometry, pose.as_mut_ptr()) },
            sie_status::Ok
        );
        pose
    };
    let first = noisy_surface(0.0, 0.0, 1);
    let (mut pose, mut status) = ([SENTINEL; 16], 99u32);
    // SAFETY (all calls): arrays cover their counts at their strides, or are NULL.
    unsafe {
        assert_eq!(sie_context_odometry_new(ctx.0, &mut odometry), sie_status::Ok);
        assert_eq!(
            sie_context_odometry_register_frame(
                ctx.0,
                odometry,
                first.as_ptr().cast(),
                N,
                16,
                pose.as_mut_ptr(),
                &mut status
            ),
            sie_status::Ok
        );
    }
    assert_eq!(status, sie_frame_status::First as u32);
    let start = pose_of(odometry);
    type Fault = (&'static str, sie_status, &'static str);
    let faults: [Fault; 11] = [
        ("NULL context", sie_status::NullArgument, ""),
        ("NULL odometry", sie_status::NullArgument, "odometry"),
        ("NULL points", sie_status::NullArgument, "xyz"),
        ("NULL pose output", sie_status::NullArgument, "out_T_world_sensor"),
        ("NULL status output", sie_status::NullArgument, "out_frame_status"),
        ("n = 0", sie_status::TooFewPoints, "0"),
        ("n = 2", sie_status::TooFewPoints, "2"),
        ("stride 8 (< 12 bytes)", sie_status::InvalidArgument, "stride"),
        (
            "stride 14 (not a multiple of 4)",
            sie_status::InvalidArgument,
            "stride",
        ),
        ("misaligned pointer", sie_status::InvalidArgument, "align"),
        ("NaN coordinate", sie_status::NonFiniteInput, "xyz[1234]"),
    ];
    let mut rows = Vec::new();
    for double in [false, true] {
        for (name, expected, word) in faults {
            let mut frame = cloud(N, 0.01);
            if name == "NaN coordinate" {
                frame[1234][1] = f32::NAN;
            }
            let frame_d = as_f64(&frame);
            let (count, stride, offset) = match name {
                "n = 0" => (0, 16, 0),
                "n = 2" => (2, 16, 0),
                "stride 8 (< 12 bytes)" => (N, 8, 0),
                "stride 14 (not a multiple of 4)" => (N, 14, 0),
                "misaligned pointer" => (N, 16, 2),
                _ => (N, 16, 0),
            };
            let (mut pose, mut status) = ([SENTINEL; 16], 99u32);
            let ctx_arg = if name == "NULL context" { null_mut() } else { ctx.0 };
            let odometry_arg = if name == "NULL odometry" {
                null_mut()
            } else {
                odometry
            };
            let pose_arg = if name == "NULL pose output" {
                null_mut()
            } else {
                pose.as_mut_ptr()
            };
            let status_arg: *mut u32 = if name == "NULL status output" {
                null_mut()
            } else {
                &mut status
            };
            // SAFETY: as above; the faults are values the library must reject before reading.
            let got = unsafe {
                if double {
                    let xyz = (frame_d.as_ptr() as *const u8).wrapping_add(offset) as *const f64;
                    let xyz = if name == "NULL points" { null() } else { xyz };
                    sie_context_odometry_register_frame_d(
                        ctx_arg,
                        odometry_arg,
                        xyz,
                        count,
                        stride * 2,
                        pose_arg,
                        status_arg,
                    )
                } else {
                    let xyz = (frame.as_ptr() as *const u8).wrapping_add(offset) as *const f32;
                    let xyz = if name == "NULL points" { null() } else { xyz };
                    sie_context_odometry_register_frame(
                        ctx_arg,
                        odometry_arg,
                        xyz,
                        count,
                        stride,
                        pose_arg,
                        status_arg,
                    )
                }
            };
            let message = if name == "NULL context" {
                String::new()
            } else {
                ctx.last_error()
            };
            assert_eq!(got, expected, "double {double} / {name}: {message}");
            assert!(
                message.contains(word),
                "double {double} / {name}: message {message:?}"
            );
            assert_eq!(
                (pose, status),
                ([SENTINEL; 16], 99),
                "double {double} / {name}: output written"
            );
            assert_eq!(
                pose_of(odometry),
                start,
                "double {double} / {name}: the trajectory moved"
            );
            rows.push(format!(
                "odometry{} | {name} | {got:?} | {message}",
                if double { " (double)" } else { "" }
            ));
        }
    }
    let next = noisy_surface(0.007, 0.013, 2);
    // SAFETY: as above.
    let got = unsafe {
        sie_context_odometry_register_frame(
            ctx.0,
            odometry,
            next.as_ptr().cast(),
            N,
            16,
            pose.as_mut_ptr(),
            &mut status,
        )
    };
    let mut summary = sie_summary::default();
    // SAFETY: live context.
    unsafe { sie_context_get_summary(ctx.0, &mut summary) };
    assert_eq!(
        (got, status),
        (sie_status::Ok, sie_frame_status::Accepted as u32),
        "{} {summary:?}",
        ctx.last_error()
    );
    // SAFETY: from sie_context_odometry_new, freed once.
    unsafe { sie_odometry_free(odometry) };
    println!("{}", rows.join("\n"));
}
