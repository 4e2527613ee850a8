//! Registers a large synthetic room pair and reports time and peak memory (issue: load).
//!
//! `cargo run --release --example large_pair -- [points per cloud] [max correspondences] [plane|point] [noise sigma]`
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
        ..RegistrationConfig::default()
    };
    // The target prepared first (the same result as register_clouds, bit for bit), so that the
    // peak of preparing it shows apart from the registration's.
    let start = Instant::now();
    let target =
        PreparedTarget::new(&scene.target, None, &PrepareOptions::from_config(&config)).expect("target");
    println!(
        "target prepared (kd-tree) in {:.1} s, peak RSS {:.0} MiB, current {:.0} MiB",
        start.elapsed().as_secs_f64(),
        peak_rss_mib(),
        current_rss_mib()
    );
    let result =
        register_clouds_to(&scene.source, &target, None, &config, Hooks::default()).expect("registration");
    let seconds = start.elapsed().as_secs_f64();
    let error = scene.t_target_source.try_inverse().unwrap() * result.transform;
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
