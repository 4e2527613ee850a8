//! Faults and load at the C ABI: cancellation, non-finite input, degenerate geometry, SIE edge
//! cases, concurrent contexts and repeated use (issue "Hardening").
mod common;
use common::c_context::Context;
use std::ptr::{null, null_mut};
use std::sync::{Arc, Barrier, mpsc};

use core::ffi::c_void;
use sie::ffi::*;
use sie::synthetic::{paper_simulation, room_scene};

const SENTINEL: f64 = -12345.0;

fn finite_transform(t: &[f64; 16]) -> bool {
    t.iter().all(|v| v.is_finite()) && t[12..] == [0.0, 0.0, 0.0, 1.0]
}

fn shifted_pairs(seed: u64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let t0 = nalgebra::Translation3::new(0.5, 0.0, 0.0).to_homogeneous();
    let data = paper_simulation(1000, 1000, 0.01, &t0, seed);
    (data.source, data.target)
}

// ---------------------------------------------------------------- cancellation

/// user_data = the iteration at which to ask for cancellation.
unsafe extern "C" fn cancel_at(user_data: *mut c_void, entry: *const sie_trace_entry) -> i32 {
    // SAFETY: the test passes a pointer to a live u32; `entry` is valid during the call.
    let (stop_at, iteration) = unsafe { (*(user_data as *const u32), (*entry).iteration) };
    i32::from(iteration >= stop_at)
}

#[test]
fn progress_callback_cancels_with_the_transform_so_far() {
    let ctx = Context::new();
    let (source, target) = shifted_pairs(1);
    let mut stop_at = 3u32;
    // SAFETY: `stop_at` outlives the registration that uses it.
    let status =
        unsafe { sie_context_set_progress_callback(ctx.0, Some(cancel_at), (&raw mut stop_at).cast()) };
    assert_eq!(status, sie_status::Ok);
    let mut out = [SENTINEL; 16];
    assert_eq!(
        ctx.register_pairs(&source, &target, &mut out),
        sie_status::Cancelled
    );
    assert!(
        ctx.last_error().contains("progress callback"),
        "{}",
        ctx.last_error()
    );
    // The transform so far is written and is already close to the answer (x shift of -0.5).
    assert!(finite_transform(&out));
    assert!((out[3] + 0.5).abs() < 0.2, "tx {}", out[3]);
    let summary = ctx.summary();
    assert_eq!(summary.stop_reason, sie_stop_reason::Cancelled as u32);
    assert_eq!(summary.iterations, 3);
    assert!(!summary.converged);
    // Removing the callback lets the next run finish.
    // SAFETY: live context.
    assert_eq!(
        unsafe { sie_context_set_progress_callback(ctx.0, None, null_mut()) },
        sie_status::Ok
    );
    assert_eq!(ctx.register_pairs(&source, &target, &mut out), sie_status::Ok);
    assert_eq!(ctx.summary().stop_reason, sie_stop_reason::Converged as u32);
}

#[test]
fn cancel_request_before_a_run_stops_it_after_one_iteration_and_is_consumed() {
    let ctx = Context::new();
    let (source, target) = shifted_pairs(2);
    // SAFETY: live context.
    assert_eq!(unsafe { sie_context_cancel(ctx.0) }, sie_status::Ok);
    let mut out = [SENTINEL; 16];
    assert_eq!(
        ctx.register_pairs(&source, &target, &mut out),
        sie_status::Cancelled
    );
    assert!(
        ctx.last_error().contains("sie_context_cancel"),
        "{}",
        ctx.last_error()
    );
    assert_eq!(ctx.summary().iterations, 1);
    assert_eq!(ctx.register_pairs(&source, &target, &mut out), sie_status::Ok);
    // SAFETY: NULL is allowed and reported.
    assert_eq!(unsafe { sie_context_cancel(null()) }, sie_status::NullArgument);
}

struct Handshake {
    started: mpsc::Sender<()>,
    cancelled: Arc<Barrier>,
}

/// At iteration 2, tells the other thread to cancel and waits until it has.
unsafe extern "C" fn wait_for_cancel(user_data: *mut c_void, entry: *const sie_trace_entry) -> i32 {
    // SAFETY: the test passes a live Handshake; `entry` is valid during the call.
    let (handshake, iteration) = unsafe { (&*(user_data as *const Handshake), (*entry).iteration) };
    if iteration == 2 {
        handshake.started.send(()).unwrap();
        handshake.cancelled.wait();
    }
    0
}

#[derive(Clone, Copy)]
struct SendPointer(*const sie_context);
// SAFETY: only `sie_context_cancel`, documented as callable from any thread, uses it.
unsafe impl Send for SendPointer {}

#[test]
fn cancel_from_another_thread_stops_a_running_registration() {
    let ctx = Context::new();
    let (source, target) = shifted_pairs(3);
    let (started, wait_started) = mpsc::channel();
    let cancelled = Arc::new(Barrier::new(2));
    let mut handshake = Handshake {
        started,
        cancelled: Arc::clone(&cancelled),
    };
    // SAFETY: `handshake` outlives the registration.
    unsafe { sie_context_set_progress_callback(ctx.0, Some(wait_for_cancel), (&raw mut handshake).cast()) };
    let pointer = SendPointer(ctx.0);
    let canceller = std::thread::spawn(move || {
        let pointer = pointer;
        wait_started.recv().unwrap();
        // SAFETY: the context lives until the registration on the other thread returns.
        let status = unsafe { sie_context_cancel(pointer.0) };
        cancelled.wait();
        status
    });
    let mut out = [SENTINEL; 16];
    assert_eq!(
        ctx.register_pairs(&source, &target, &mut out),
        sie_status::Cancelled
    );
    assert_eq!(canceller.join().unwrap(), sie_status::Ok);
    // Requested during iteration 2, seen at the end of iteration 3.
    assert_eq!(ctx.summary().iterations, 3);
    assert!(finite_transform(&out));
}

// ---------------------------------------------------------------- non-finite input

#[test]
fn non_finite_points_are_rejected_by_index_or_skipped_on_request() {
    let scene = room_scene(3000, 0.01, 5);
    let (mut source, mut target) = (scene.source.clone(), scene.target.clone());
    source[17] = [f64::NAN, 0.0, 0.0];
    source[400][2] = f64::INFINITY;
    target[5] = [f64::NAN; 3];
    let ctx = Context::new();
    let mut out = [SENTINEL; 16];
    assert_eq!(
        ctx.register(&source, &target, &mut out),
        sie_status::NonFiniteInput
    );
    assert!(
        ctx.last_error().contains("source_xyz[17]"),
        "{}",
        ctx.last_error()
    );
    assert!(
        out.iter().all(|v| *v == SENTINEL),
        "outputs must stay untouched on error"
    );

    // SAFETY: live context.
    assert_eq!(
        unsafe { sie_context_set_skip_non_finite(ctx.0, true) },
        sie_status::Ok
    );
    assert_eq!(ctx.register(&source, &target, &mut out), sie_status::Ok);
    assert!(finite_transform(&out));
    let truth = scene.t_target_source;
    let translation_error = ((out[3] - truth[(0, 3)]).powi(2) + (out[7] - truth[(1, 3)]).powi(2)).sqrt();
    assert!(translation_error < 0.01, "{translation_error}");
    let p = ctx.probabilities(source.len());
    let c = ctx.correspondences(source.len());
    assert_eq!((p[17], c[17]), (0.0, -1));
    assert_eq!((p[400], c[400]), (0.0, -1));
    // Target indices refer to the caller's array, so the NaN target point is never matched.
    assert!(c.iter().all(|&t| t != 5 && t < target.len() as i64));
    assert_eq!(ctx.summary().source_count, source.len() as u64);

    // Correspondences: a pair with a non-finite side is dropped.
    let (mut a, mut b) = shifted_pairs(4);
    b[10][1] = f64::NAN;
    assert_eq!(ctx.register_pairs(&a, &b, &mut out), sie_status::Ok);
    assert_eq!(ctx.probabilities(a.len())[10], 0.0);
    a[11] = [f64::NEG_INFINITY; 3];
    assert_eq!(ctx.register_pairs(&a, &b, &mut out), sie_status::Ok);
    assert_eq!(ctx.correspondences(a.len())[11], -1);
}

/// Depth frames mark invalid pixels 0 0 0 (30 % here, in both clouds). Those points are
/// exact duplicates (each location is indexed once, so they cost no more than any other
/// point) and, kept, they match each other with zero residual. `sie_context_set_skip_origin`
/// drops them like non-finite points: probability 0, no match, target indices unchanged.
#[test]
fn invalid_depth_pixels_at_the_origin_are_dropped_on_request() {
    let scene = room_scene(6000, 0.01, 21);
    let (mut source, mut target) = (scene.source.clone(), scene.target.clone());
    let invalid = |i: usize| (i * 7919) % 10 < 3;
    for (i, p) in source.iter_mut().enumerate().filter(|(i, _)| invalid(*i)) {
        *p = [0.0, if i % 2 == 0 { 0.0 } else { -0.0 }, 0.0];
    }
    for (_, p) in target.iter_mut().enumerate().filter(|(i, _)| invalid(*i + 1)) {
        *p = [0.0; 3];
    }
    let ctx = Context::new();
    let mut out = [SENTINEL; 16];
    // SAFETY: live context.
    assert_eq!(
        unsafe { sie_context_set_skip_origin(ctx.0, true) },
        sie_status::Ok
    );
    assert_eq!(
        ctx.register(&source, &target, &mut out),
        sie_status::Ok,
        "{}",
        ctx.last_error()
    );
    let truth = scene.t_target_source;
    let translation_error = ((0..3)
        .map(|r| (out[4 * r + 3] - truth[(r, 3)]).powi(2))
        .sum::<f64>())
    .sqrt();
    assert!(translation_error < 0.01, "{translation_error}");
    let (p, c) = (ctx.probabilities(source.len()), ctx.correspondences(source.len()));
    for i in (0..source.len()).filter(|&i| invalid(i)) {
        assert_eq!((p[i], c[i]), (0.0, -1), "source {i}");
    }
    assert!(c.iter().all(|&t| t < 0 || target[t as usize] != [0.0; 3]));
    assert_eq!(ctx.summary().source_count, source.len() as u64);
    // Kept (the default), point-to-point matches the invalid pixels to each other (point-to-
    // plane finds no normal at a location of identical points, so it never matches them).
    for (skip, metric) in [
        (false, sie_metric::PointToPoint),
        (true, sie_metric::PointToPoint),
    ] {
        // SAFETY: live context.
        unsafe {
            assert_eq!(sie_context_set_skip_origin(ctx.0, skip), sie_status::Ok);
            assert_eq!(sie_context_set_metric(ctx.0, metric as u32), sie_status::Ok);
        }
        assert_eq!(ctx.register(&source, &target, &mut out), sie_status::Ok);
        let c = ctx.correspondences(source.len());
        let origin_matched = (0..source.len())
            .filter(|&i| invalid(i) && c[i] >= 0 && target[c[i] as usize] == [0.0; 3])
            .count();
        let error = ((0..3)
            .map(|r| (out[4 * r + 3] - truth[(r, 3)]).powi(2))
            .sum::<f64>())
        .sqrt();
        println!(
            "point-to-point, skip_origin {skip}: {origin_matched} invalid pixels matched, translation error {error}"
        );
        assert_eq!(origin_matched > 0, !skip);
    }
}

// ---------------------------------------------------------------- degenerate geometry

fn assert_no_nan(ctx: &Context, n: usize, out: &[f64; 16]) {
    assert!(finite_transform(out), "{out:?}");
    let s = ctx.summary();
    for v in s
        .sigma
        .iter()
        .chain(&s.beta)
        .chain([&s.penalty, &s.noise_shape, &s.inlier_fraction, &s.rmse])
    {
        assert!(v.is_finite(), "{s:?}");
    }
    assert!(ctx.probabilities(n).iter().all(|p| (0.0..=1.0).contains(p)));
}

#[test]
fn degenerate_geometry_gives_finite_outputs_and_says_so() {
    let identical = vec![[1.0, 2.0, 3.0]; 500];
    let collinear: Vec<[f64; 3]> = (0..500).map(|i| [i as f64 * 0.01, 0.0, 0.0]).collect();
    let plane: Vec<[f64; 3]> = (0..900)
        .map(|i| [(i % 30) as f64 * 0.05, (i / 30) as f64 * 0.05, 1.0])
        .collect();
    let shifted_plane: Vec<[f64; 3]> = plane
        .iter()
        .map(|p| [p[0] + 0.02, p[1] - 0.01, p[2] + 0.03])
        .collect();
    for metric in [sie_metric::PointToPlane, sie_metric::PointToPoint] {
        let ctx = Context::new();
        // SAFETY: live context.
        assert_eq!(
            unsafe { sie_context_set_metric(ctx.0, metric as u32) },
            sie_status::Ok
        );
        for (name, source, target) in [
            ("identical points", &identical, &identical),
            ("collinear points", &collinear, &collinear),
            ("one plane", &shifted_plane, &plane),
        ] {
            let mut out = [SENTINEL; 16];
            let status = ctx.register(source, target, &mut out);
            assert_eq!(status, sie_status::Ok, "{metric:?} {name}: {}", ctx.last_error());
            assert_no_nan(&ctx, source.len(), &out);
            let stop = ctx.summary().stop_reason;
            if name != "one plane" || metric == sie_metric::PointToPlane {
                // Identical and collinear points leave rotations free; point-to-plane on one
                // plane leaves the in-plane motion free.
                assert_eq!(stop, sie_stop_reason::Degenerate as u32, "{metric:?} {name}");
            }
            if name == "one plane" {
                // The constrained direction (the plane's normal) is solved either way.
                assert!((out[11] + 0.03).abs() < 1e-3, "{metric:?}: tz {}", out[11]);
            }
        }
    }
}

#[test]
fn symmetric_shape_registers_without_nan() {
    // Points on a sphere: rotations about its centre are unobservable for point-to-plane.
    let sphere: Vec<[f64; 3]> = (0..2000)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / 2000.0;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f64 * 2.399_963;
            [r * phi.cos(), r * phi.sin(), z]
        })
        .collect();
    let moved: Vec<[f64; 3]> = sphere.iter().map(|p| [p[0] + 0.05, p[1], p[2] - 0.02]).collect();
    let ctx = Context::new();
    let mut out = [SENTINEL; 16];
    assert_eq!(ctx.register(&moved, &sphere, &mut out), sie_status::Ok);
    assert_no_nan(&ctx, moved.len(), &out);
    // The centre (translation) is observable and recovered.
    assert!(
        (out[3] + 0.05).abs() < 2e-3 && (out[11] - 0.02).abs() < 2e-3,
        "{out:?}"
    );
}

/// Cloud registration of a scene expressed at 1e77 or 1e100 (or 1e-100) times its size: the
/// nearest-neighbour search and the point-to-point solve square coordinates, which overflowed
/// (PANIC "index out of bounds" in `src/nn.rs` for point-to-point at 1e77, NaN from the SVD
/// once that was fixed). The answer must be the unit-scale answer, scaled (to 1e-4: a run stops
/// once an update is below a tenth of the pose's standard error, here ~1e-3, so rounding at
/// another scale can end it one update earlier or later).
#[test]
fn clouds_at_extreme_magnitudes_register_like_the_unit_scale_scene() {
    let scene = room_scene(2000, 0.01, 3);
    for metric in [sie_metric::PointToPoint, sie_metric::PointToPlane] {
        let ctx = Context::new();
        // SAFETY: live context.
        assert_eq!(
            unsafe { sie_context_set_metric(ctx.0, metric as u32) },
            sie_status::Ok
        );
        let mut reference = [SENTINEL; 16];
        assert_eq!(
            ctx.register(&scene.source, &scene.target, &mut reference),
            sie_status::Ok
        );
        for scale in [1e77, 1e100, 1e-100] {
            let grow = |points: &[[f64; 3]]| -> Vec<[f64; 3]> {
                points.iter().map(|p| p.map(|c| c * scale)).collect()
            };
            let mut out = [SENTINEL; 16];
            let status = ctx.register(&grow(&scene.source), &grow(&scene.target), &mut out);
            assert_eq!(
                status,
                sie_status::Ok,
                "{metric:?} at {scale:e}: {}",
                ctx.last_error()
            );
            assert!(finite_transform(&out), "{metric:?} at {scale:e}: {out:?}");
            for row in 0..3 {
                for col in 0..3 {
                    let (got, want) = (out[4 * row + col], reference[4 * row + col]);
                    assert!((got - want).abs() < 1e-4, "{metric:?} at {scale:e}: R {out:?}");
                }
                let (got, want) = (out[4 * row + 3] / scale, reference[4 * row + 3]);
                assert!((got - want).abs() < 1e-4, "{metric:?} at {scale:e}: t {out:?}");
            }
        }
    }
}

// ---------------------------------------------------------------- SIE edge cases

fn estimate(residuals: &[f64]) -> (sie_status, Vec<f64>, sie_model) {
    let ctx = Context::new();
    let mut p = vec![-1.0; residuals.len()];
    let mut model = sie_model::default();
    let mut count = 0;
    // SAFETY: buffers sized for the inputs.
    let status = unsafe {
        sie_estimate_inliers(
            ctx.0,
            residuals.as_ptr(),
            residuals.len(),
            1,
            null(),
            0.0,
            p.as_mut_ptr(),
            &mut model,
            1,
            &mut count,
        )
    };
    (status, p, model)
}

#[test]
fn sie_handles_identical_flat_clean_and_overwhelmed_residuals() {
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};
    let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(21);
    let noise = Normal::new(0.0, 0.02).unwrap();
    let mut mixture = |outlier_share: f64| -> Vec<f64> {
        (0..10_000)
            .map(|_| {
                if rng.random::<f64>() < outlier_share {
                    rng.random_range(-1.0..1.0)
                } else {
                    noise.sample(&mut rng)
                }
            })
            .collect()
    };
    let cases: Vec<(&str, Vec<f64>, bool)> = vec![
        ("all identical (one bin)", vec![0.25; 5000], false),
        ("all zero", vec![0.0; 5000], false),
        ("only outliers (no peak)", mixture(1.0), false),
        ("0 % outliers", mixture(0.0), true),
        ("30 % outliers", mixture(0.3), true),
        ("99 % outliers", mixture(0.99), false),
    ];
    for (name, residuals, peak) in cases {
        let (status, p, model) = estimate(&residuals);
        assert_eq!(status, sie_status::Ok, "{name}");
        assert!(p.iter().all(|v| (0.0..=1.0).contains(v)), "{name}");
        for v in [
            model.mu,
            model.sigma,
            model.alpha,
            model.noise_shape,
            model.range_lo,
            model.range_hi,
        ] {
            assert!(v.is_finite(), "{name}: {model:?}");
        }
        assert_eq!(model.peak_found, peak, "{name}: {model:?}");
        if peak {
            assert!(
                (model.sigma - 0.02).abs() < 0.002,
                "{name}: sigma {}",
                model.sigma
            );
        }
    }
}

// ---------------------------------------------------------------- threads and load

fn register_scene(seed: u64) -> ([f64; 16], Vec<f64>) {
    let scene = room_scene(2500, 0.01, seed);
    let ctx = Context::new();
    let mut out = [SENTINEL; 16];
    assert_eq!(
        ctx.register(&scene.source, &scene.target, &mut out),
        sie_status::Ok
    );
    (out, ctx.probabilities(scene.source.len()))
}

#[test]
fn eight_threads_with_their_own_contexts_match_serial_results() {
    let seeds: Vec<u64> = (100..108).collect();
    let serial: Vec<_> = seeds.iter().map(|&s| register_scene(s)).collect();
    let parallel: Vec<_> = seeds
        .iter()
        .map(|&s| std::thread::spawn(move || register_scene(s)))
        .collect::<Vec<_>>()
        .into_iter()
        .map(|h| h.join().unwrap())
        .collect();
    assert_eq!(serial, parallel);
}
