//! The paper's correspondence simulation (§6 and its footnote; appendix for Laplacian noise):
//! instances, initial transforms, the compared methods, the error against T_MLE, and a cell
//! runner that spreads instances over worker threads.
//!
//! Shared by `examples/experiments.rs` (the full grid) and `tests/paper_grid.rs` (the reduced
//! grid in CI), so both measure exactly the same thing. Depends only on the library and its
//! own dependencies.
#![allow(dead_code)] // each includer uses a different part

use std::f64::consts::PI;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use nalgebra::{Matrix4, Rotation3, Translation3, Vector3};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use sie::geometry::{transform_point, weighted_rigid_fit};
use sie::synthetic::{Correspondences, paper_simulation};
use sie::{CostFunction, Hooks, NoiseShape, Point, RegistrationConfig, SieOptions, register_correspondences};

/// Inlier noise standard deviation per axis (the footnote's 0.01), and the true σ the
/// baselines are handed.
pub const NOISE_SIGMA: f64 = 0.01;
/// Inliers per instance.
pub const INLIERS: usize = 1000;
/// The three outlier levels of §6 (easy, medium, hard).
pub const OUTLIER_LEVELS: [usize; 3] = [100, 1000, 10_000];
/// "We consider a tested transform with an error greater than the measurement noise a
/// complete failure."
pub const FAILURE_THRESHOLD: f64 = NOISE_SIGMA;
/// Initial-transform steps per axis: 0, 0.1, …, 1.0 of the full range.
pub const STEPS: usize = 11;
/// IRLS update cap for every method. SIE's β schedule needs ~60–120 updates; the IRLS baselines
/// (L0.1 in particular) converge linearly and get the same budget.
pub const MAX_ITERATIONS: u32 = 300;

/// Which way T0 moves the inliers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    /// Translation along x by 0 … 1.
    Translation,
    /// Rotation about the x axis by 0 … π (the paper's axis; the authors' code used z).
    Rotation,
}

impl Motion {
    pub fn name(self) -> &'static str {
        match self {
            Motion::Translation => "translation",
            Motion::Rotation => "rotation",
        }
    }

    /// T0 at grid step `step` (0 ..= STEPS-1).
    pub fn magnitude(self, step: usize) -> f64 {
        let fraction = step as f64 / (STEPS - 1) as f64;
        match self {
            Motion::Translation => fraction,
            Motion::Rotation => fraction * PI,
        }
    }

    /// "0.5" for translations, "π/2"-style labels for rotations.
    pub fn label(self, step: usize) -> String {
        match self {
            Motion::Translation => format!("{:.1}", self.magnitude(step)),
            Motion::Rotation => pi_label(step),
        }
    }

    pub fn initial_transform(self, step: usize) -> Matrix4<f64> {
        let m = self.magnitude(step);
        match self {
            Motion::Translation => Translation3::new(m, 0.0, 0.0).to_homogeneous(),
            Motion::Rotation => Rotation3::from_axis_angle(&Vector3::x_axis(), m).to_homogeneous(),
        }
    }
}

/// step/10 · π as a reduced fraction: 0, π/10, π/5, 3π/10, …, π.
fn pi_label(step: usize) -> String {
    // gcd(step, STEPS - 1) ≥ 1 because STEPS - 1 > 0.
    let g = gcd(step, STEPS - 1);
    match (step / g, (STEPS - 1) / g) {
        (0, _) => "0".into(),
        (1, 1) => "π".into(),
        (n, 1) => format!("{n}π"),
        (1, d) => format!("π/{d}"),
        (n, d) => format!("{n}π/{d}"),
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Distribution of the inlier noise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Noise {
    /// N(0, σ²) per axis: the footnote, via `sie::synthetic::paper_simulation`.
    Gaussian,
    /// Laplacian per axis with the same standard deviation σ (scale b = σ/√2), appendix.
    Laplacian,
}

impl Noise {
    pub fn name(self) -> &'static str {
        match self {
            Noise::Gaussian => "gaussian",
            Noise::Laplacian => "laplacian",
        }
    }

    /// The error metric the paper pairs with this noise: RMS for Gaussian, mean absolute error
    /// for Laplacian (appendix).
    pub fn metric(self) -> ErrorMetric {
        match self {
            Noise::Gaussian => ErrorMetric::Rms,
            Noise::Laplacian => ErrorMetric::MeanAbsolute,
        }
    }
}

/// Seed of instance `index` at an outlier level: the same 100 instances are reused for every
/// T0 of that level (as in the paper), and differ between levels and noise types.
pub fn instance_seed(noise: Noise, outliers: usize, index: usize) -> u64 {
    let noise_part = match noise {
        Noise::Gaussian => 0u64,
        Noise::Laplacian => 1,
    };
    1_000_000 * noise_part + 100 * outliers as u64 + index as u64 + 17
}

/// One test instance with T0 applied to the inliers' A.
pub fn instance(noise: Noise, outliers: usize, t0: &Matrix4<f64>, seed: u64) -> Correspondences {
    match noise {
        Noise::Gaussian => paper_simulation(INLIERS, outliers, NOISE_SIGMA, t0, seed),
        Noise::Laplacian => laplacian_simulation(INLIERS, outliers, NOISE_SIGMA, t0, seed),
    }
}

/// The footnote's construction with Laplacian inlier noise of standard deviation `sigma` per
/// axis: inliers A uniform in [0,1]³, B = A + noise; outliers A uniform, B uniform in
/// A + [-1,1]³; the inliers' A moved by T0.
fn laplacian_simulation(
    inliers: usize,
    outliers: usize,
    sigma: f64,
    t0: &Matrix4<f64>,
    seed: u64,
) -> Correspondences {
    let scale = sigma / 2f64.sqrt();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let laplace = |rng: &mut Xoshiro256PlusPlus| {
        // Inverse CDF: u uniform in (-½, ½) ↦ -b·sign(u)·ln(1 − 2|u|).
        let u: f64 = rng.random::<f64>() - 0.5;
        -scale * u.signum() * (1.0 - 2.0 * u.abs()).max(f64::MIN_POSITIVE).ln()
    };
    let total = inliers + outliers;
    let mut data = Correspondences {
        source: Vec::with_capacity(total),
        target: Vec::with_capacity(total),
        is_inlier: Vec::with_capacity(total),
    };
    for _ in 0..inliers {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        let b = a.map(|c| c + laplace(&mut rng));
        data.source.push(transform_point(t0, &a));
        data.target.push(b);
        data.is_inlier.push(true);
    }
    for _ in 0..outliers {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        let b = a.map(|c| c + rng.random_range(-1.0..1.0));
        data.source.push(a);
        data.target.push(b);
        data.is_inlier.push(false);
    }
    data
}

/// How an estimate is scored against the best possible one on the true inliers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorMetric {
    /// sqrt(mean ‖T·a − b‖²); T_MLE is the least-squares fit (Gaussian noise).
    Rms,
    /// mean ‖T·a − b‖; T_MLE minimises Σ‖r‖ (Laplacian noise, eq. regprobGGD with p = 1).
    MeanAbsolute,
}

/// The true inlier pairs and the score of T_MLE on them.
pub struct Reference {
    pairs: Vec<(Point, Point)>,
    metric: ErrorMetric,
    pub mle: Matrix4<f64>,
    pub mle_score: f64,
}

impl Reference {
    pub fn new(data: &Correspondences, metric: ErrorMetric) -> Self {
        let pairs: Vec<(Point, Point)> = data
            .source
            .iter()
            .zip(&data.target)
            .zip(&data.is_inlier)
            .filter(|(_, inlier)| **inlier)
            .map(|((a, b), _)| (*a, *b))
            .collect();
        let least_squares = weighted_rigid_fit(&pairs, &vec![1.0; pairs.len()])
            .expect("inliers span 3-D")
            .transform;
        let mle = match metric {
            ErrorMetric::Rms => least_squares,
            ErrorMetric::MeanAbsolute => least_absolute_fit(&pairs, least_squares),
        };
        let mut reference = Reference {
            pairs,
            metric,
            mle,
            mle_score: 0.0,
        };
        reference.mle_score = reference.score(&mle);
        reference
    }

    /// RMS or mean absolute residual of `t` over the true inliers.
    pub fn score(&self, t: &Matrix4<f64>) -> f64 {
        let norms = self.pairs.iter().map(|(a, b)| {
            let p = transform_point(t, a);
            ((p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2)).sqrt()
        });
        let n = self.pairs.len() as f64;
        match self.metric {
            ErrorMetric::Rms => (norms.map(|d| d * d).sum::<f64>() / n).sqrt(),
            ErrorMetric::MeanAbsolute => norms.sum::<f64>() / n,
        }
    }

    /// The paper's test error: score(T) − score(T_MLE).
    pub fn error(&self, t: &Matrix4<f64>) -> f64 {
        self.score(t) - self.mle_score
    }
}

/// argmin_T Σ‖T·a − b‖ by IRLS (weights 1/‖r‖) from the least-squares fit, run until the
/// update is below 1e-13: far below the 1e-5 errors the comparison cares about.
fn least_absolute_fit(pairs: &[(Point, Point)], start: Matrix4<f64>) -> Matrix4<f64> {
    let mut t = start;
    let mut weights = vec![1.0; pairs.len()];
    for _ in 0..500 {
        for (w, (a, b)) in weights.iter_mut().zip(pairs) {
            let p = transform_point(&t, a);
            let d = ((p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2)).sqrt();
            *w = 1.0 / d.max(1e-12);
        }
        let next = weighted_rigid_fit(pairs, &weights)
            .expect("inliers span 3-D")
            .transform;
        let change = (next - t).abs().max();
        t = next;
        if change < 1e-13 {
            break;
        }
    }
    t
}

/// A compared cost function with its settings.
#[derive(Clone, Debug)]
pub struct Method {
    /// Column key in the CSV files.
    pub key: &'static str,
    /// Label in tables and legends.
    pub label: &'static str,
    pub config: RegistrationConfig,
}

fn method(key: &'static str, label: &'static str, cost: CostFunction) -> Method {
    Method {
        key,
        label,
        config: RegistrationConfig {
            cost,
            max_iterations: MAX_ITERATIONS,
            threads: 1,
            ..RegistrationConfig::default()
        },
    }
}

/// Multiples of the true σ used as the scale of each fixed-scale kernel: the truncation of
/// §5 (3.5σ) and the usual 95 %-efficiency constants of the M-estimators (Huber 1.345,
/// Cauchy 2.385, Tukey 4.685; Geman-McClure at σ).
pub const TRUNCATION_MULTIPLE: f64 = 3.5;
pub const HUBER_MULTIPLE: f64 = 1.345;
pub const CAUCHY_MULTIPLE: f64 = 2.385;
pub const GEMAN_MCCLURE_MULTIPLE: f64 = 1.0;
pub const TUKEY_MULTIPLE: f64 = 4.685;
/// Student-t degrees of freedom (Kerl et al.).
pub const STUDENT_T_DOF: f64 = 5.0;

/// The ten methods of the grid: the paper's five, then plain L2 and four M-estimators. Every
/// scale is derived from `sigma`, the true noise (SIE gets nothing).
pub fn paper_methods(sigma: f64) -> Vec<Method> {
    vec![
        method("sie", "SIE", CostFunction::Sie),
        method(
            "truncated_l2",
            "truncated L2 (3.5σ)",
            CostFunction::TruncatedL2 {
                threshold: TRUNCATION_MULTIPLE * sigma,
            },
        ),
        method("l1", "L1", CostFunction::Lp { p: 1.0 }),
        method("l0.1", "L0.1", CostFunction::Lp { p: 0.1 }),
        method(
            "student_t",
            "Student-t (ν=5)",
            CostFunction::StudentT { dof: STUDENT_T_DOF },
        ),
        method("l2", "L2", CostFunction::L2),
        method(
            "huber",
            "Huber (1.345σ)",
            CostFunction::Huber {
                scale: HUBER_MULTIPLE * sigma,
            },
        ),
        method(
            "cauchy",
            "Cauchy (2.385σ)",
            CostFunction::Cauchy {
                scale: CAUCHY_MULTIPLE * sigma,
            },
        ),
        method(
            "geman_mcclure",
            "Geman-McClure (σ)",
            CostFunction::GemanMcClure {
                scale: GEMAN_MCCLURE_MULTIPLE * sigma,
            },
        ),
        method(
            "tukey",
            "Tukey (4.685σ)",
            CostFunction::Tukey {
                scale: TUKEY_MULTIPLE * sigma,
            },
        ),
    ]
}

/// The appendix's three SIE variants: Gaussian model (p = 2), Laplacian model (p = 1) and p
/// estimated from the histogram.
pub fn appendix_methods() -> Vec<Method> {
    let with_shape = |key, label, shape| {
        let mut m = method(key, label, CostFunction::Sie);
        m.config.sie = SieOptions {
            noise_shape: shape,
            ..SieOptions::default()
        };
        m
    };
    vec![
        with_shape("sie_p2", "SIE p = 2", NoiseShape::Fixed(2.0)),
        with_shape("sie_p1", "SIE p = 1", NoiseShape::Fixed(1.0)),
        with_shape("sie_estimated_p", "SIE estimated p", NoiseShape::Estimated),
    ]
}

/// One cell of a grid: noise, outlier level and T0.
#[derive(Clone, Copy, Debug)]
pub struct Cell {
    pub noise: Noise,
    pub outliers: usize,
    pub motion: Motion,
    pub step: usize,
}

/// Every cell of one grid, in the paper's order (per outlier level: the translations, then
/// the rotations).
pub fn grid_cells(noise: Noise) -> Vec<Cell> {
    let mut cells = Vec::new();
    for outliers in OUTLIER_LEVELS {
        for motion in [Motion::Translation, Motion::Rotation] {
            for step in 0..STEPS {
                cells.push(Cell {
                    noise,
                    outliers,
                    motion,
                    step,
                });
            }
        }
    }
    cells
}

/// One method's result on one instance.
#[derive(Clone, Copy, Debug)]
pub struct Trial {
    pub error: f64,
    /// The result's quality verdict was GOOD.
    pub called_good: bool,
    pub converged: bool,
    pub iterations: u32,
    pub seconds: f64,
}

/// Aggregate of one method on one cell.
#[derive(Clone, Debug, Default)]
pub struct CellStats {
    pub instances: usize,
    pub failures: usize,
    /// Mean error over the non-failures (NaN when every instance failed).
    pub mean_error: f64,
    pub max_error: f64,
    /// Instances that stopped on the iteration limit (or as degenerate).
    pub not_converged: usize,
    pub mean_iterations: f64,
    pub seconds: f64,
    pub verdicts: VerdictTally,
}

/// How a method's verdicts match its outcomes (issue: verdicts a user can trust).
#[derive(Clone, Copy, Debug, Default)]
pub struct VerdictTally {
    /// Right (error within the failure bound) and called good.
    pub right_good: usize,
    /// Right but not called good (false "bad").
    pub right_not_good: usize,
    /// Wrong and called good (false "good").
    pub wrong_good: usize,
    /// Wrong by more than 5× the bound and called good.
    pub far_wrong_good: usize,
    /// Wrong and not called good.
    pub wrong_not_good: usize,
}

impl VerdictTally {
    /// Counts one run.
    pub fn add(&mut self, right: bool, far_wrong: bool, called_good: bool) {
        match (right, called_good) {
            (true, true) => self.right_good += 1,
            (true, false) => self.right_not_good += 1,
            (false, true) => {
                self.wrong_good += 1;
                self.far_wrong_good += usize::from(far_wrong);
            }
            (false, false) => self.wrong_not_good += 1,
        }
    }

    pub fn merge(&mut self, other: &VerdictTally) {
        self.right_good += other.right_good;
        self.right_not_good += other.right_not_good;
        self.wrong_good += other.wrong_good;
        self.far_wrong_good += other.far_wrong_good;
        self.wrong_not_good += other.wrong_not_good;
    }
}

impl CellStats {
    pub fn from_trials(trials: &[Trial]) -> Self {
        let good: Vec<f64> = trials
            .iter()
            .map(|t| t.error)
            .filter(|e| *e <= FAILURE_THRESHOLD)
            .collect();
        let n = trials.len().max(1) as f64;
        CellStats {
            instances: trials.len(),
            failures: trials.len() - good.len(),
            mean_error: if good.is_empty() {
                f64::NAN
            } else {
                good.iter().sum::<f64>() / good.len() as f64
            },
            max_error: good.iter().copied().fold(f64::NAN, f64::max),
            not_converged: trials.iter().filter(|t| !t.converged).count(),
            mean_iterations: trials.iter().map(|t| t.iterations as f64).sum::<f64>() / n,
            seconds: trials.iter().map(|t| t.seconds).sum(),
            verdicts: trials.iter().fold(VerdictTally::default(), |mut tally, t| {
                tally.add(
                    t.error <= FAILURE_THRESHOLD,
                    t.error > 5.0 * FAILURE_THRESHOLD,
                    t.called_good,
                );
                tally
            }),
        }
    }

    pub fn failure_rate(&self) -> f64 {
        self.failures as f64 / self.instances.max(1) as f64
    }
}

/// Runs every method on `instances` instances of `cell` on `threads` worker threads and
/// returns one `CellStats` per method (in `methods` order). `progress` is called after each
/// finished instance (from the worker threads).
pub fn run_cell(
    cell: &Cell,
    methods: &[Method],
    instances: usize,
    threads: usize,
    progress: &(dyn Fn() + Sync),
) -> Vec<CellStats> {
    let trials = run_cell_trials(cell, methods, instances, threads, progress);
    (0..methods.len())
        .map(|m| {
            let per_method: Vec<Trial> = trials.iter().map(|row| row[m]).collect();
            CellStats::from_trials(&per_method)
        })
        .collect()
}

/// Per instance (in order), one `Trial` per method.
pub fn run_cell_trials(
    cell: &Cell,
    methods: &[Method],
    instances: usize,
    threads: usize,
    progress: &(dyn Fn() + Sync),
) -> Vec<Vec<Trial>> {
    let t0 = cell.motion.initial_transform(cell.step);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Vec<Trial>>>> = Mutex::new(vec![None; instances]);
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    if index >= instances {
                        break;
                    }
                    let seed = instance_seed(cell.noise, cell.outliers, index);
                    let data = instance(cell.noise, cell.outliers, &t0, seed);
                    let reference = Reference::new(&data, cell.noise.metric());
                    let row: Vec<Trial> = methods.iter().map(|m| run_trial(&data, &reference, m)).collect();
                    results.lock().expect("no worker panicked")[index] = Some(row);
                    progress();
                }
            });
        }
    });
    results
        .into_inner()
        .expect("no worker panicked")
        .into_iter()
        .map(|row| row.expect("every instance ran"))
        .collect()
}

/// Registers one instance with one method from the identity (T0 is in the data).
pub fn run_trial(data: &Correspondences, reference: &Reference, method: &Method) -> Trial {
    let start = Instant::now();
    let result = register_correspondences(&data.source, &data.target, None, &method.config, Hooks::default())
        .expect("simulation input is valid");
    Trial {
        error: reference.error(&result.transform),
        called_good: result.quality.verdict == sie::Verdict::Good,
        converged: result.converged,
        iterations: result.iterations,
        seconds: start.elapsed().as_secs_f64(),
    }
}
