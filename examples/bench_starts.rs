//! What SIE's automatic starts cost for ICP (issue "SIE never less robust than a tuned kernel"
//! against issue "peer speed at every size"): one pair of the synthetic room, registered from
//! the identity (7° and 0.2 m off: every start runs) and from a guess 1 cm off (a sequence's
//! constant-velocity guess: the paper's start stays near it and ends the search), with
//! `Starts::InitialGuess` (the paper's single run) and `Starts::Automatic`, side by side in one
//! run. Prints a table: median time of `repeats` runs, iterations, starts run, error, verdict.
//!
//! `cargo run --release --example bench_starts -- [points,points,...] [threads] [repeats]`
use std::time::Instant;

use nalgebra::{Matrix4, Translation3};
use sie::synthetic::room_scene;
use sie::{Hooks, RegistrationConfig, RegistrationResult, Starts, register_clouds};

fn main() {
    let mut args = std::env::args().skip(1);
    let sizes: Vec<usize> = args
        .next()
        .map(|a| a.split(',').filter_map(|v| v.parse().ok()).collect())
        .unwrap_or_else(|| vec![10_000, 100_000]);
    let threads: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(1);
    let repeats: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(5).max(1);
    println!(
        "| points | start | starts setting | median s | iterations | starts run | max entry error | verdict | time ratio |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for points in sizes {
        let scene = room_scene(points, 0.01, 1);
        let near: Matrix4<f64> =
            Translation3::new(0.01, -0.005, 0.0).to_homogeneous() * scene.t_target_source;
        for (label, init) in [("identity", None), ("guess 1 cm off", Some(near))] {
            let mut single = f64::NAN;
            for starts in [Starts::InitialGuess, Starts::Automatic] {
                let config = RegistrationConfig {
                    starts,
                    threads,
                    ..RegistrationConfig::default()
                };
                let mut times = Vec::new();
                let mut last: Option<RegistrationResult> = None;
                for _ in 0..repeats {
                    let began = Instant::now();
                    let result = register_clouds(
                        &scene.source,
                        &scene.target,
                        None,
                        init.as_ref(),
                        &config,
                        Hooks::default(),
                    )
                    .expect("synthetic input is valid");
                    times.push(began.elapsed().as_secs_f64());
                    last = Some(result);
                }
                times.sort_by(f64::total_cmp);
                let median = times[times.len() / 2];
                let result = last.expect("at least one run");
                if starts == Starts::InitialGuess {
                    single = median;
                }
                println!(
                    "| {points} | {label} | {starts:?} | {median:.3} | {} | {} | {:.1e} | {:?} | {:.2} |",
                    result.iterations,
                    result.search.starts_run,
                    (result.transform - scene.t_target_source).abs().max(),
                    result.quality.verdict,
                    median / single
                );
            }
        }
    }
}
