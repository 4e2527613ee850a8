//! Correspondence registration time with and without the hypothesis stage, side by side.
//!
//! `cargo run --release --example bench_correspondences -- [INSTANCES]` registers the paper's
//! simulation (1000 inliers with 100, 1000 and 10 000 outliers, i.e. up to 11 000 pairs) from
//! the identity, alternating `Starts::InitialGuess` (the paper's method, as before the
//! hypothesis stage) and `Starts::Automatic` on the same instances, one thread, and prints the
//! median time of each, their ratio, and the failures (error above the noise) of each.
use std::f64::consts::PI;
use std::time::Instant;

use nalgebra::{Matrix4, Rotation3, Translation3, Vector3};
use sie::synthetic::paper_simulation;
use sie::{Hooks, RegistrationConfig, Starts, register_correspondences};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let instances: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(20);
    let cells: [(&str, Matrix4<f64>); 3] = [
        (
            "translation 1.0 along x",
            Translation3::new(1.0, 0.0, 0.0).to_homogeneous(),
        ),
        (
            "rotation π/2 about x",
            Rotation3::from_axis_angle(&Vector3::x_axis(), PI / 2.0).to_homogeneous(),
        ),
        (
            "rotation 2π/5 about x",
            Rotation3::from_axis_angle(&Vector3::x_axis(), 0.4 * PI).to_homogeneous(),
        ),
    ];
    println!(
        "| outliers | T0 | paper's method (initial guess only) | with hypothesis stage | ratio | failures before → after |"
    );
    println!("|---|---|---|---|---|---|");
    for outliers in [100, 1000, 10_000] {
        for (name, t0) in &cells {
            let mut times = [Vec::new(), Vec::new()];
            let mut failures = [0, 0];
            for i in 0..instances {
                let data = paper_simulation(1000, outliers, 0.01, t0, 7_000 + i as u64);
                let truth = t0.try_inverse().expect("rigid");
                for (k, starts) in [Starts::InitialGuess, Starts::Automatic].into_iter().enumerate() {
                    let config = RegistrationConfig {
                        starts,
                        threads: 1,
                        max_iterations: 300,
                        ..RegistrationConfig::default()
                    };
                    let began = Instant::now();
                    let result =
                        register_correspondences(&data.source, &data.target, None, &config, Hooks::default())
                            .expect("valid input");
                    times[k].push(began.elapsed().as_secs_f64());
                    // Far from T0⁻¹ (the inliers' motion) by more than the noise: a failure.
                    let moved = (result.transform - truth).abs().max();
                    if moved > 0.05 {
                        failures[k] += 1;
                    }
                }
            }
            let (before, after) = (median(times[0].clone()), median(times[1].clone()));
            println!(
                "| {outliers} | {name} | {:.1} ms | {:.1} ms | {:.2} | {}/{instances} → {}/{instances} |",
                1e3 * before,
                1e3 * after,
                after / before,
                failures[0],
                failures[1]
            );
        }
    }
}
