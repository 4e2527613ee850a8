//! Part `variants`: SIE settings and the minimal driver of `variants.rs` on chosen cells.
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use sie::GammaRule;

use crate::options::Options;
use crate::progress::Progress;
use crate::report::{cell_text, table};
use crate::simulation::{
    self, Cell, CellStats, Motion, NOISE_SIGMA, Noise, instance, instance_seed, paper_methods, run_cell,
};
use crate::variants;

/// SIE settings compared on the cells where the default fails (10 000 outliers, rotations
/// around π/2) and on cells it passes, to see whether a change helps and what it costs: two
/// library settings, and the annealing change of `variants.rs` next to the same minimal driver
/// without it.
pub fn variants(options: &Options) -> Result<String, String> {
    let base = paper_methods(NOISE_SIGMA).remove(0);
    let variant = |key: &'static str, label: &'static str, change: &dyn Fn(&mut sie::RegistrationConfig)| {
        let mut m = base.clone();
        m.key = key;
        m.label = label;
        change(&mut m.config);
        m
    };
    let methods = vec![
        variant("default", "library SIE (γ from P(I), β × 0.5)", &|_| {}),
        variant("gamma_one", "library, γ = 1", &|c| c.sie.gamma = GammaRule::One),
        variant("shrink_0.8", "library, β × 0.8", &|c| c.beta_shrink = 0.8),
    ];
    let custom: [(&str, bool); 2] = [
        ("minimal driver", false),
        ("minimal driver + hold σ jumps above σ+β", true),
    ];
    let mut cells = Vec::new();
    for step in [5, 6, 7] {
        cells.push(Cell {
            noise: Noise::Gaussian,
            outliers: 10_000,
            motion: Motion::Rotation,
            step,
        });
    }
    cells.push(Cell {
        noise: Noise::Gaussian,
        outliers: 10_000,
        motion: Motion::Translation,
        step: 10,
    });
    cells.push(Cell {
        noise: Noise::Gaussian,
        outliers: 1000,
        motion: Motion::Rotation,
        step: 10,
    });
    cells.push(Cell {
        noise: Noise::Gaussian,
        outliers: 100,
        motion: Motion::Translation,
        step: 10,
    });
    let progress = Progress::new("variants", cells.len());
    let mut rows: Vec<Vec<String>> = methods.iter().map(|m| vec![m.label.to_string()]).collect();
    rows.extend(custom.iter().map(|(label, _)| vec![label.to_string()]));
    for cell in &cells {
        let mut texts: Vec<String> = run_cell(cell, &methods, options.instances, options.threads, &|| {})
            .iter()
            .map(cell_text)
            .collect();
        for (_, hold) in custom {
            let stats = run_custom(cell, options.instances, options.threads, &|data| {
                variants::register(data, hold)
            });
            texts.push(cell_text(&stats));
        }
        progress.step(&format!(
            "{} outliers {} {}: {}",
            cell.outliers,
            cell.motion.name(),
            cell.motion.label(cell.step),
            texts.join(" | ")
        ));
        for (row, text) in rows.iter_mut().zip(texts) {
            row.push(text);
        }
    }
    let mut header = vec!["SIE setting".to_string()];
    header.extend(
        cells
            .iter()
            .map(|c| format!("{}, {} {}", c.outliers, c.motion.name(), c.motion.label(c.step))),
    );
    Ok(format!(
        "Failures (%) · mean error of the non-failures, {} instances per cell (the first {} of the grid's).\n\n{}",
        options.instances,
        options.instances,
        table(&header, &rows)
    ))
}

/// `register` on the first `instances` instances of `cell`, on `threads` threads.
fn run_custom(
    cell: &Cell,
    instances: usize,
    threads: usize,
    register: &(dyn Fn(&sie::synthetic::Correspondences) -> nalgebra::Matrix4<f64> + Sync),
) -> CellStats {
    let t0 = cell.motion.initial_transform(cell.step);
    let next = AtomicUsize::new(0);
    let trials = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    if index >= instances {
                        break;
                    }
                    let data = instance(
                        cell.noise,
                        cell.outliers,
                        &t0,
                        instance_seed(cell.noise, cell.outliers, index),
                    );
                    let reference = simulation::Reference::new(&data, cell.noise.metric());
                    let began = Instant::now();
                    let t = register(&data);
                    let trial = simulation::Trial {
                        error: reference.error(&t),
                        called_good: false,
                        converged: true,
                        iterations: 0,
                        seconds: began.elapsed().as_secs_f64(),
                    };
                    trials.lock().expect("no worker panicked").push(trial);
                }
            });
        }
    });
    CellStats::from_trials(&trials.into_inner().expect("no worker panicked"))
}
