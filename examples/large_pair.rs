//! Registers a large synthetic room pair and reports time and peak memory (issue: load).
//!
//! `cargo run --release --example large_pair -- [points per cloud] [max correspondences] [plane|point] [noise sigma] [f64|f32] [max iterations]`
//!
//! `max iterations` (default 200) caps the updates: peak RSS is reached by the first iteration and
//! the final evaluation, so a capped run measures it in a fraction of the time.
//!
//! `f32`: the clouds are held as float32 (0.24 GB at 10 M points per cloud), as a C caller
//! holds them, and registered through the C ABI (`sie_context_prepare_target`, then
//! `sie_context_register_to`). Peak RSS (VmHWM) then is what such a caller sees.
use std::time::Instant;

use nalgebra::Matrix4;
use sie::geometry::{rotation_angle, rotation_part, translation_part};
use sie::synthetic::room_scene;
use sie::{Hooks, Metric, PrepareOptions, PreparedTarget, RegistrationConfig, register_clouds_to};

/// Peak resident set size of this process (VmHWM), in MiB.
fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

/// Current resident set size (VmRSS), in MiB.
fn current_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kib| kib / 1024.0)
}

fn main() {
    let mut args = std::env::args().skip(1);
    let points: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(10_000_000);
    let sample: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(0);
    let metric = match args.next().as_deref() {
        Some("point") => Metric::PointToPoint,
        _ => Metric::PointToPlane,
    };
    let noise: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(0.01);
    let float_input = args.next().as_deref() == Some("f32");
    let max_iterations: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(200);
    let start = Instant::now();
    let scene = room_scene(points, noise, 1);
    println!(
        "scene: {} + {} points, noise {noise} m, in {:.1} s, peak RSS {:.0} MiB, current {:.0} MiB",
        scene.source.len(),
        scene.target.len(),
        start.elapsed().as_secs_f64(),
        peak_rss_mib(),
        current_rss_mib()
    );
    let t_target_source = scene.t_target_source;
    let start = Instant::now();
    let (transform, stop, iterations) = if float_input {
        let narrow =
            |cloud: &[sie::Point]| -> Vec<[f32; 3]> { cloud.iter().map(|p| p.map(|c| c as f32)).collect() };
        let caller = (narrow(&scene.source), narrow(&scene.target));
        drop(scene);
        println!("float32 clouds: current RSS {:.0} MiB", current_rss_mib());
        through_c_abi(&caller.0, &caller.1, sample, metric, max_iterations)
    } else {
        let config = RegistrationConfig {
            max_correspondences: sample,
            metric,
            max_iterations,
            ..RegistrationConfig::default()
        };
        // The target prepared first (the same result as register_clouds, bit for bit), so that
        // the peak of preparing it shows apart from the registration's.
        let prepared =
            PreparedTarget::new(&scene.target, None, &PrepareOptions::from_config(&config)).expect("target");
        report_prepared(start);
        let result = register_clouds_to(&scene.source, &prepared, None, &config, Hooks::default())
            .expect("registration");
        (
            result.transform,
            format!("{:?}", result.stop_reason),
            result.iterations,
        )
    };
    let seconds = start.elapsed().as_secs_f64();
    let error = t_target_source.try_inverse().unwrap() * transform;
    println!(
        "registered ({metric:?}, max correspondences {sample}): {stop} after {iterations} iterations in {seconds:.1} s; \
         error {:.4} deg / {:.2} mm; peak RSS {:.0} MiB",
        rotation_angle(&rotation_part(&error)).to_degrees(),
        translation_part(&error).norm() * 1e3,
        peak_rss_mib()
    );
}

fn report_prepared(start: Instant) {
    println!(
        "target prepared (kd-tree) in {:.1} s, peak RSS {:.0} MiB, current {:.0} MiB",
        start.elapsed().as_secs_f64(),
        peak_rss_mib(),
        current_rss_mib()
    );
}

/// Registers float32 clouds through the C ABI, as a C caller does: the target prepared
/// (`sie_context_prepare_target`), then the source registered onto it
/// (`sie_context_register_to`). Returns the transform, the stop reason and the iterations.
fn through_c_abi(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    sample: usize,
    metric: Metric,
    max_iterations: u32,
) -> (Matrix4<f64>, String, u32) {
    use sie::ffi::*;
    let check = |status: sie_status, what: &str| assert_eq!(status, sie_status::Ok, "{what}");
    let stride = std::mem::size_of::<[f32; 3]>();
    let started = Instant::now();
    let ctx = sie_context_new();
    assert!(!ctx.is_null(), "sie_context_new");
    let metric = match metric {
        Metric::PointToPoint => sie_metric::PointToPoint as u32,
        Metric::PointToPlane => sie_metric::PointToPlane as u32,
    };
    let mut out = [0.0f64; 16];
    let mut summary = sie_summary::default();
    // SAFETY: `ctx` is live until freed below; the arrays are readable for their counts at
    // their stride; the outputs are writable (16 doubles, one pointer, one summary).
    unsafe {
        check(sie_context_set_metric(ctx, metric), "metric");
        check(
            sie_context_set_max_correspondences(ctx, sample),
            "max correspondences",
        );
        check(
            sie_context_set_max_iterations(ctx, max_iterations),
            "max iterations",
        );
        let mut prepared: *mut sie_target = std::ptr::null_mut();
        let status = sie_context_prepare_target(
            ctx,
            target.as_ptr().cast(),
            target.len(),
            stride,
            std::ptr::null(),
            0,
            &mut prepared,
        );
        check(status, "prepare target");
        report_prepared(started);
        let status = sie_context_register_to(
            ctx,
            source.as_ptr().cast(),
            source.len(),
            stride,
            prepared,
            std::ptr::null(),
            out.as_mut_ptr(),
        );
        check(status, "register");
        check(sie_context_get_summary(ctx, &mut summary), "summary");
        sie_target_free(prepared);
        sie_context_free(ctx);
    }
    let stop = match summary.stop_reason {
        r if r == sie_stop_reason::Converged as u32 => "Converged".to_string(),
        r if r == sie_stop_reason::IterationLimit as u32 => "IterationLimit".to_string(),
        other => format!("stop reason {other}"),
    };
    (Matrix4::from_row_slice(&out), stop, summary.iterations)
}
