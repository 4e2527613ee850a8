//! Beyond the paper's grid: the §6 correspondence protocol with motions and outliers the
//! one-axis grid does not contain (rotations about any axis, translations in any direction,
//! both combined, outliers that follow a second rigid motion, ten outliers per inlier).
//!
//! Shared by `examples/experiments.rs` (part `beyond`, every method, 100 instances per cell)
//! and `tests/robustness.rs` (SIE on a fixed set of instances per family in CI).
#![allow(dead_code)] // each includer uses a different part

use std::f64::consts::PI;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use sie::synthetic::{Correspondences, random_motion, structured_simulation};

use crate::simulation::{CellStats, ErrorMetric, INLIERS, Method, NOISE_SIGMA, Reference, Trial, run_trial};

/// How the inliers move, per instance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Draw {
    /// Rotation by this angle about a uniformly random axis (no translation).
    Rotation(f64),
    /// Translation by this length in a uniformly random direction.
    Translation(f64),
    /// Rotation uniform in [0, π] about a random axis and translation uniform in [0, 1].
    Combined,
}

/// One cell of the table: a motion family with an outlier mix.
#[derive(Clone, Copy, Debug)]
pub struct Family {
    pub draw: Draw,
    pub outliers: usize,
    /// How many of the outliers follow a second rigid motion (rotation 0.3–π about a random
    /// axis, translation 0.3–1 in a random direction); the rest are the paper's.
    pub structured: usize,
}

impl Family {
    pub fn label(&self) -> String {
        let motion = match self.draw {
            Draw::Rotation(angle) => format!("rotation {} about any axis", angle_label(angle)),
            Draw::Translation(shift) => format!("translation {shift:.1} in any direction"),
            Draw::Combined => "rotation ≤ π and translation ≤ 1, any axis and direction".into(),
        };
        if self.structured > 0 {
            format!(
                "{} outliers ({} on a second rigid motion), {motion}",
                self.outliers, self.structured
            )
        } else {
            format!("{} outliers, {motion}", self.outliers)
        }
    }

    /// Seed of instance `index` (the same instances in the table and in CI).
    pub fn seed(&self, index: usize) -> u64 {
        let draw = match self.draw {
            Draw::Rotation(angle) => (angle * 1000.0) as u64,
            Draw::Translation(shift) => 10_000 + (shift * 1000.0) as u64,
            Draw::Combined => 20_000,
        };
        0xBE70_0000_0000
            + (draw << 32)
            + ((self.outliers as u64) << 12)
            + ((self.structured as u64) << 24)
            + index as u64
    }

    /// Instance `index` of this family.
    pub fn instance(&self, index: usize) -> Correspondences {
        let seed = self.seed(index);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let t0 = match self.draw {
            Draw::Rotation(angle) => random_motion(&mut rng, angle, 0.0),
            Draw::Translation(shift) => random_motion(&mut rng, 0.0, shift),
            Draw::Combined => {
                let (angle, shift) = (rng.random_range(0.0..PI), rng.random_range(0.0..1.0));
                random_motion(&mut rng, angle, shift)
            }
        };
        let other = {
            let (angle, shift) = (rng.random_range(0.3..PI), rng.random_range(0.3..1.0));
            random_motion(&mut rng, angle, shift)
        };
        structured_simulation(
            INLIERS,
            self.outliers,
            self.structured,
            NOISE_SIGMA,
            &t0,
            &other,
            seed,
        )
    }
}

fn angle_label(angle: f64) -> String {
    match (angle / PI * 4.0).round() as u32 {
        2 => "π/2".into(),
        3 => "3π/4".into(),
        4 => "π".into(),
        _ => format!("{angle:.2} rad"),
    }
}

/// The families of the issue, in table order.
pub fn families() -> Vec<Family> {
    let mut out = Vec::new();
    for outliers in [100, 1000] {
        for draw in [
            Draw::Rotation(PI / 2.0),
            Draw::Rotation(PI),
            Draw::Translation(1.0),
            Draw::Combined,
        ] {
            out.push(Family {
                draw,
                outliers,
                structured: 0,
            });
        }
    }
    out.push(Family {
        draw: Draw::Translation(0.5),
        outliers: 1000,
        structured: 400,
    });
    out.push(Family {
        draw: Draw::Combined,
        outliers: 1000,
        structured: 500,
    });
    for draw in [
        Draw::Rotation(PI / 2.0),
        Draw::Rotation(PI),
        Draw::Translation(1.0),
        Draw::Combined,
    ] {
        out.push(Family {
            draw,
            outliers: 10_000,
            structured: 0,
        });
    }
    out
}

/// Runs every method on `instances` instances of `family` on `threads` workers: one
/// `CellStats` per method.
pub fn run_family(
    family: &Family,
    methods: &[Method],
    instances: usize,
    threads: usize,
    progress: &(dyn Fn() + Sync),
) -> Vec<CellStats> {
    let next = AtomicUsize::new(0);
    let trials: Mutex<Vec<Option<Vec<Trial>>>> = Mutex::new(vec![None; instances]);
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    if index >= instances {
                        break;
                    }
                    let data = family.instance(index);
                    let reference = Reference::new(&data, ErrorMetric::Rms);
                    let row = methods.iter().map(|m| run_trial(&data, &reference, m)).collect();
                    trials.lock().expect("no worker panicked")[index] = Some(row);
                    progress();
                }
            });
        }
    });
    let trials: Vec<Vec<Trial>> = trials
        .into_inner()
        .expect("no worker panicked")
        .into_iter()
        .map(|row| row.expect("every instance ran"))
        .collect();
    (0..methods.len())
        .map(|m| CellStats::from_trials(&trials.iter().map(|row| row[m]).collect::<Vec<_>>()))
        .collect()
}
