//! A source scaled by a few per cent has no rigid answer, so no verdict should be GOOD
//! (project issue 29): the synthetic room (8 000 points, 5 mm noise) with its source scaled
//! about the sensor by each factor, seeds 41–43 unless given, each metric and starts setting
//! from the identity. Prints one row per run (with the scale `Quality::scaled_source` found) and
//! the GOOD count per factor (docs/results.md, "A scaled source").
//!
//! cargo run --release --example scaled_sources [seed,seed,...] [factor,factor,...]

use sie::{Hooks, Metric, Point, RegistrationConfig, Starts, Verdict, register_clouds};

const FACTORS: [f64; 4] = [0.95, 1.02, 1.05, 1.1];
const SEEDS: [u64; 3] = [41, 42, 43];

/// The comma-separated list of argument `index`, or `default`.
fn list_arg<T: std::str::FromStr + Clone>(index: usize, default: &[T]) -> Vec<T> {
    std::env::args().nth(index).map_or_else(
        || default.to_vec(),
        |arg| {
            arg.split(',')
                .map(|v| v.parse().ok().expect("a number"))
                .collect()
        },
    )
}

fn main() -> Result<(), sie::Error> {
    println!(
        "| factor | seed | metric | starts | verdict | margin | inlier fraction | translation off (m) | scaled fit |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let (seeds, factors) = (list_arg(1, &SEEDS), list_arg(2, &FACTORS));
    let mut good = vec![0usize; factors.len()];
    for &seed in &seeds {
        let scene = sie::synthetic::room_scene(8_000, 0.005, seed);
        let truth_inverse = scene.t_target_source.try_inverse().expect("a rigid ground truth");
        for (f, &factor) in factors.iter().enumerate() {
            let scaled: Vec<Point> = scene.source.iter().map(|p| p.map(|c| c * factor)).collect();
            for metric in [Metric::PointToPlane, Metric::PointToPoint] {
                for starts in [Starts::Automatic, Starts::InitialGuess] {
                    let config = RegistrationConfig {
                        metric,
                        starts,
                        ..RegistrationConfig::default()
                    };
                    let result =
                        register_clouds(&scaled, &scene.target, None, None, &config, Hooks::default())?;
                    let off = (truth_inverse * result.transform).fixed_view::<3, 1>(0, 3).norm();
                    good[f] += usize::from(result.quality.verdict == Verdict::Good);
                    let scaled = result.quality.scaled_source.map_or("none".to_string(), |s| {
                        format!("{:.4} ({:.2}x)", s.scale, s.significance_ratio)
                    });
                    println!(
                        "| {factor} | {seed} | {metric:?} | {starts:?} | {:?} | {:.2} | {:.3} | {off:.3} | {scaled} |",
                        result.quality.verdict, result.quality.margin, result.inlier_fraction
                    );
                }
            }
        }
    }
    let runs = seeds.len() * 4;
    for (factor, count) in factors.iter().zip(good) {
        println!("scaled by {factor}: {count} of {runs} runs GOOD");
    }
    Ok(())
}
