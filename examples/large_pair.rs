//! Registers a large synthetic room pair and reports time and peak memory (issue: load).
//!
//! `cargo run --release --example large_pair -- [points per cloud] [max correspondences] [plane|point] [noise sigma] [f64|f32] [max iterations]`
//!
//! `max iterations` (default 200) caps the updates: peak RSS is reached by the first iteration and
//! the final evaluation, so a capped run measures it in a fraction of the time.
//!
//! `f32`: the clouds are held as float32 (0.24 GB at 10 M points per cloud), as a C caller of
//! `sie_context_register` holds them, and registered the way the C ABI does: f64 copies, the
//! target's dropped once it is prepared. Peak RSS (VmHWM) then is what such a caller sees.
use std::time::Instant;

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
    let config = RegistrationConfig {
        max_correspondences: sample,
        metric,
        max_iterations,
        ..RegistrationConfig::default()
    };
    let t_target_source = scene.t_target_source;
    let options = PrepareOptions::from_config(&config);
    // The target prepared first (the same result as register_clouds, bit for bit), so that the
    // peak of preparing it shows apart from the registration's.
    let start = Instant::now();
    let (source, target, caller_clouds) = if float_input {
        let narrow =
            |cloud: &[sie::Point]| -> Vec<[f32; 3]> { cloud.iter().map(|p| p.map(|c| c as f32)).collect() };
        let caller = (narrow(&scene.source), narrow(&scene.target));
        drop(scene);
        println!("float32 clouds: current RSS {:.0} MiB", current_rss_mib());
        let widen =
            |cloud: &[[f32; 3]]| -> Vec<sie::Point> { cloud.iter().map(|p| p.map(f64::from)).collect() };
        let (source, target) = (widen(&caller.0), widen(&caller.1));
        let prepared = PreparedTarget::new(&target, None, &options).expect("target");
        drop(target);
        (source, prepared, Some(caller))
    } else {
        let prepared = PreparedTarget::new(&scene.target, None, &options).expect("target");
        (scene.source, prepared, None)
    };
    println!(
        "target prepared (kd-tree) in {:.1} s, peak RSS {:.0} MiB, current {:.0} MiB",
        start.elapsed().as_secs_f64(),
        peak_rss_mib(),
        current_rss_mib()
    );
    let result = register_clouds_to(&source, &target, None, &config, Hooks::default()).expect("registration");
    drop(caller_clouds);
    let seconds = start.elapsed().as_secs_f64();
    let error = t_target_source.try_inverse().unwrap() * result.transform;
    println!(
        "registered ({metric:?}, max correspondences {sample}): {:?} after {} iterations in {seconds:.1} s; \
         error {:.4} deg / {:.2} mm; peak RSS {:.0} MiB",
        result.stop_reason,
        result.iterations,
        rotation_angle(&rotation_part(&error)).to_degrees(),
        translation_part(&error).norm() * 1e3,
        peak_rss_mib()
    );
}
