//! Scratch: robustness families beyond the paper's grid.
use std::f64::consts::PI;
use std::time::Instant;

use nalgebra::{Matrix4, Rotation3, Translation3, Unit, Vector3};
use rand::rngs::Xoshiro256PlusPlus;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Normal};
use sie::geometry::{transform_point, weighted_rigid_fit};
use sie::{CostFunction, Hooks, Point, RegistrationConfig, register_correspondences};

struct Instance {
    source: Vec<Point>,
    target: Vec<Point>,
    inlier: Vec<bool>,
}

fn random_axis(rng: &mut Xoshiro256PlusPlus) -> Unit<Vector3<f64>> {
    let n = Normal::new(0.0, 1.0).unwrap();
    loop {
        let v = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng));
        if v.norm() > 1e-3 {
            return Unit::new_normalize(v);
        }
    }
}

fn motion(rng: &mut Xoshiro256PlusPlus, angle: f64, shift: f64) -> Matrix4<f64> {
    let mut axis = random_axis(rng);
    let mut dir = random_axis(rng);
    if std::env::var("XAXIS").is_ok() {
        axis = Vector3::x_axis();
        dir = Vector3::x_axis();
    }
    Translation3::from(dir.into_inner() * shift).to_homogeneous()
        * Rotation3::from_axis_angle(&axis, angle).to_homogeneous()
}

/// inliers moved by t0; `structured` outliers follow `other`.
fn make(
    rng: &mut Xoshiro256PlusPlus,
    inliers: usize,
    outliers: usize,
    structured: usize,
    t0: &Matrix4<f64>,
    other: &Matrix4<f64>,
) -> Instance {
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut d = Instance {
        source: vec![],
        target: vec![],
        inlier: vec![],
    };
    for _ in 0..inliers {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        let b = a.map(|c| c + noise.sample(rng));
        d.source.push(transform_point(t0, &a));
        d.target.push(b);
        d.inlier.push(true);
    }
    for i in 0..outliers {
        let a: Point = [0; 3].map(|_| rng.random::<f64>());
        if i < structured {
            let b = a.map(|c| c + noise.sample(rng));
            d.source.push(transform_point(other, &a));
            d.target.push(b);
        } else {
            let b = a.map(|c| c + rng.random_range(-1.0..1.0));
            d.source.push(a);
            d.target.push(b);
        }
        d.inlier.push(false);
    }
    d
}

fn error(d: &Instance, t: &Matrix4<f64>) -> f64 {
    let pairs: Vec<(Point, Point)> = d
        .source
        .iter()
        .zip(&d.target)
        .zip(&d.inlier)
        .filter(|(_, i)| **i)
        .map(|((a, b), _)| (*a, *b))
        .collect();
    let mle = weighted_rigid_fit(&pairs, &vec![1.0; pairs.len()]).unwrap().transform;
    let score = |t: &Matrix4<f64>| {
        (pairs
            .iter()
            .map(|(a, b)| {
                let p = transform_point(t, a);
                (p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2)
            })
            .sum::<f64>()
            / pairs.len() as f64)
            .sqrt()
    };
    score(t) - score(&mle)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(30);
    let which: String = args.get(2).cloned().unwrap_or("all".into());
    let method: String = args.get(3).cloned().unwrap_or("sie".into());
    let config = match method.as_str() {
        "cauchy" => RegistrationConfig {
            cost: CostFunction::Cauchy { scale: 2.385 * 0.01 },
            max_iterations: 300,
            threads: 1,
            ..RegistrationConfig::default()
        },
        _ => RegistrationConfig {
            max_iterations: 300,
            threads: 1,
            ..RegistrationConfig::default()
        },
    };
    // (name, outliers, structured fraction, angle, shift) ; angle<0: uniform [0,π]; shift<0 uniform [0,1]
    let families: Vec<(&str, usize, f64, f64, f64)> = vec![
        ("axis pi/2 o100", 100, 0.0, PI / 2.0, 0.0),
        ("axis pi o100", 100, 0.0, PI, 0.0),
        ("axis pi/2 o1000", 1000, 0.0, PI / 2.0, 0.0),
        ("axis 3pi/4 o1000", 1000, 0.0, 0.75 * PI, 0.0),
        ("axis pi o1000", 1000, 0.0, PI, 0.0),
        ("shift 1 o1000", 1000, 0.0, 0.0, 1.0),
        ("comb 1rad+1 o1000", 1000, 0.0, 1.0, 1.0),
        ("comb rand o1000", 1000, 0.0, -1.0, -1.0),
        ("comb rand o100", 100, 0.0, -1.0, -1.0),
        ("struct 40% t0.5", 1000, 0.4, 0.0, 0.5),
        ("struct 50% rand", 1000, 0.5, -1.0, -1.0),
        ("axis pi/2 o10000", 10000, 0.0, PI / 2.0, 0.0),
        ("axis pi o10000", 10000, 0.0, PI, 0.0),
    ];
    for (name, outliers, structured, angle, shift) in families {
        if which != "all" && !name.contains(which.as_str()) {
            continue;
        }
        let mut failures = 0;
        let mut errors = vec![];
        let mut seconds = 0.0;
        let mut iterations = 0;
        let mut hyps = 0;
        let mut starts = 0;
        let mut from_hyp = 0;
        for i in 0..n {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(9_000_000 + 1000 * outliers as u64 + i as u64);
            let a = if angle < 0.0 { rng.random_range(0.0..PI) } else { angle };
            let s = if shift < 0.0 { rng.random_range(0.0..1.0) } else { shift };
            let t0 = motion(&mut rng, a, s);
            let other = if structured > 0.0 {
                let oa = rng.random_range(0.3..PI);
                let os = rng.random_range(0.3..1.0);
                motion(&mut rng, oa, os)
            } else {
                Matrix4::identity()
            };
            let d = make(&mut rng, 1000, outliers, (structured * outliers as f64) as usize, &t0, &other);
            let start = Instant::now();
            let r = if method.starts_with("hyp") {
                let (t, rho, _score, h) = hypotheses(&d.source, &d.target, i as u64);
                hyps += h;
                let c = RegistrationConfig { initial_beta: Some(rho / 3f64.sqrt()), ..config.clone() };
                let a = register_correspondences(&d.source, &d.target, Some(&t), &c, Hooks::default()).unwrap();
                if method == "hypinit" {
                    let b = register_correspondences(&d.source, &d.target, None, &config, Hooks::default()).unwrap();
                    let (la, lb) = (likelihood(&d, &a), likelihood(&d, &b));
                    let (ea, eb) = (error(&d, &a.transform), error(&d, &b.transform));
                    if (la > lb) != (ea <= eb) && (ea > 0.01 || eb > 0.01) {
                        println!("  selection wrong: LL hyp {la:.1} init {lb:.1}; err hyp {ea:.2e} init {eb:.2e}; sigma {:.4} {:.4} P {:.3} {:.3}", a.sigma[0], b.sigma[0], a.inlier_fraction, b.inlier_fraction);
                    }
                    if la >= lb { a } else { b }
                } else { a }
            } else {
                register_correspondences(&d.source, &d.target, None, &config, Hooks::default()).unwrap()
            };
            seconds += start.elapsed().as_secs_f64();
            iterations += r.iterations;
            hyps += r.search.hypotheses as usize;
            starts += r.search.starts_run as usize;
            if r.search.start == sie::StartKind::Hypothesis { from_hyp += 1; }
            let e = error(&d, &r.transform);
            if e > 0.01 && std::env::var("DEBUG").is_ok() {
                let pairs = sie::sie::hypotheses::Pairs { source: &d.source, target: &d.target, scales: &vec![1.0; d.source.len()] };
                let search = sie::sie::hypotheses::search(&pairs, &Matrix4::identity(), config.seed);
                println!("  fail {i}: err {e:.2e} samples {} start {:?} sig {:.1} starts {}", search.samples, r.search.start, r.search.significance, r.search.starts_run);
                for c in &search.candidates { println!("     cand sig {:.1} r {:.4} k {} hits {} init {} err {:.2e}", c.cluster.significance, c.cluster.radius, c.cluster.count, c.hits, c.is_initial_guess, error(&d, &c.transform)); }
            }
            if e > 0.01 {
                failures += 1;
            } else {
                errors.push(e);
            }
        }
        let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
            println!(
            "{name:22} fail {failures:3}/{n}  mean err {mean:.1e}  {:.1} ms/run  {:.0} it",
            1000.0 * seconds / n as f64,
            iterations as f64 / n as f64
        );
        if hyps > 0 { println!("   samples {:.0} starts {:.2} from hypothesis {from_hyp}", hyps as f64 / n as f64, starts as f64 / n as f64); }
    }
}

/// Prototype hypothesis stage. Returns (transform, rho, score, hypotheses).
pub fn hypotheses(source: &[Point], target: &[Point], seed: u64) -> (Matrix4<f64>, f64, f64, usize) {
    let n = source.len();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let subset: Vec<usize> = if n <= 256 {
        (0..n).collect()
    } else {
        rand::seq::index::sample(&mut rng, n, 256).into_iter().collect()
    };
    let c = sie::geometry::centroid(target);
    let spread2 = target
        .iter()
        .map(|b| (b[0] - c[0]).powi(2) + (b[1] - c[1]).powi(2) + (b[2] - c[2]).powi(2))
        .sum::<f64>()
        / n as f64;
    let m = 3.0;
    let s = subset.len() as f64;
    let guided: usize = std::env::var("GUIDED").ok().and_then(|v| v.parse().ok()).unwrap_or(16);
    let cap: usize = std::env::var("CAP").ok().and_then(|v| v.parse().ok()).unwrap_or(2000);
    let dist = |p: &Point, q: &Point| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
    let distortion = |i: usize, j: usize| (dist(&source[i], &source[j]) - dist(&target[i], &target[j])).abs();
    let mut best = (Matrix4::identity(), 0.0, f64::NEG_INFINITY);
    let mut d2 = vec![0.0; subset.len()];
    let mut needed = cap;
    let mut h = 0;
    while h < needed.min(cap) {
        h += 1;
        let i = rng.random_range(0..n);
        let pick = |rng: &mut Xoshiro256PlusPlus, cost: &dyn Fn(usize) -> f64| -> usize {
            let mut bestj = usize::MAX;
            let mut bestc = f64::INFINITY;
            for _ in 0..guided.max(1) {
                let j = rng.random_range(0..n);
                let cj = cost(j);
                if cj < bestc {
                    bestc = cj;
                    bestj = j;
                }
            }
            bestj
        };
        let j = pick(&mut rng, &|j| if j == i { f64::INFINITY } else { distortion(i, j) });
        let k = pick(&mut rng, &|k| {
            if k == i || k == j {
                f64::INFINITY
            } else {
                distortion(i, k) + distortion(j, k)
            }
        });
        let pairs = [(source[i], target[i]), (source[j], target[j]), (source[k], target[k])];
        let Some(solve) = weighted_rigid_fit(&pairs, &[1.0; 3]) else { continue };
        if solve.rank_deficient {
            continue;
        }
        let t = solve.transform;
        for (slot, &q) in d2.iter_mut().zip(&subset) {
            let p = transform_point(&t, &source[q]);
            let b = target[q];
            *slot = (p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2);
        }
        d2.sort_unstable_by(f64::total_cmp);
        let mut score = 0.0;
        let mut rho = 0.0;
        for (idx, &v) in d2.iter().enumerate().skip(3) {
            let k = (idx + 1) as f64;
            let p = (v / spread2).powf(m / 2.0).min(1.0 - 1e-12).max(1e-300);
            let q = k / s;
            if q <= p {
                continue;
            }
            let kl = q * (q / p).ln() + if q < 1.0 { (1.0 - q) * ((1.0 - q) / (1.0 - p)).ln() } else { 0.0 };
            let sc = s * kl;
            if sc > score {
                score = sc;
                rho = v.sqrt();
            }
        }
        if score > best.2 {
            // inlier fraction estimate: count below rho
            let count = d2.iter().filter(|&&v| v <= rho * rho).count() as f64;
            let w = (count / s).clamp(1e-3, 1.0);
            let adaptive = ((1e-3f64).ln() / (1.0 - w.powi(3)).ln()).ceil();
            needed = if adaptive.is_finite() { adaptive as usize } else { cap }.max(50);
            best = (t, rho, score);
        }
    }
    (best.0, best.1, best.2, h)
}

fn likelihood(d: &Instance, r: &sie::RegistrationResult) -> f64 {
    let n = d.target.len();
    let c = sie::geometry::centroid(&d.target);
    let spread2 = d.target.iter().map(|b| (b[0] - c[0]).powi(2) + (b[1] - c[1]).powi(2) + (b[2] - c[2]).powi(2)).sum::<f64>() / n as f64;
    let bg_var = 2.0 * spread2 / 3.0;
    let sigma = r.sigma[0];
    let pi = r.inlier_fraction.clamp(1e-9, 1.0 - 1e-9);
    let ln2pi = (2.0 * PI).ln();
    let mut ll = 0.0;
    for (a, b) in d.source.iter().zip(&d.target) {
        let p = transform_point(&r.transform, a);
        let r2 = (p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2) + (p[2] - b[2]).powi(2);
        let lg = -1.5 * (ln2pi + 2.0 * sigma.ln()) - 0.5 * r2 / (sigma * sigma);
        let lu = -1.5 * (ln2pi + bg_var.ln()) - 0.5 * r2 / bg_var;
        let (x, y) = (pi.ln() + lg, (1.0 - pi).ln() + lu);
        let mx = x.max(y);
        ll += mx + ((x - mx).exp() + (y - mx).exp()).ln();
    }
    ll
}
