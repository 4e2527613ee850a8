//! ICP speed and accuracy benchmark on the synthetic room (issue #4, part 2).
//!
//! `cargo run --release --example bench_icp -- scenes DIR [N,N,...]` writes the room pair at
//! each size as binary float32 PCD (`room_N_source.pcd`, `room_N_target.pcd`) with the ground
//! truth `room_N_gt.txt` (T_target_source, row-major 4×4), the input shared by every library.
//!
//! `cargo run --release --example bench_icp -- run DIR [N,N,...]` registers each pair with sie
//! (SIE, point-to-plane, defaults, from the identity) on 1 and 2 threads and prints one CSV row
//! per run with the per-stage times (bench/run.sh collects the peers' rows next to these).
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use sie::Point;
use sie::synthetic::room_scene;

const DEFAULT_SIZES: [usize; 3] = [10_000, 100_000, 1_000_000];
const NOISE_SIGMA: f64 = 0.01;
const SEED: u64 = 1;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: bench_icp scenes|run DIR [N,N,...]";
    let (Some(command), Some(dir)) = (args.first(), args.get(1)) else {
        eprintln!("{usage}");
        std::process::exit(2);
    };
    let sizes: Vec<usize> = match args.get(2) {
        Some(list) => list
            .split(',')
            .map(|n| n.trim().parse().expect("sizes: N,N,..."))
            .collect(),
        None => DEFAULT_SIZES.to_vec(),
    };
    let dir = PathBuf::from(dir);
    match command.as_str() {
        "scenes" => write_scenes(&dir, &sizes),
        "run" => run::all(&dir, &sizes),
        _ => {
            eprintln!("{usage}");
            std::process::exit(2);
        }
    }
}

fn scene_path(dir: &Path, points: usize, part: &str) -> PathBuf {
    dir.join(format!("room_{points}_{part}"))
}

fn write_scenes(dir: &Path, sizes: &[usize]) {
    std::fs::create_dir_all(dir).expect("create the scene directory");
    for &points in sizes {
        let scene = room_scene(points, NOISE_SIGMA, SEED);
        write_pcd_binary(&scene_path(dir, points, "source.pcd"), &scene.source);
        write_pcd_binary(&scene_path(dir, points, "target.pcd"), &scene.target);
        let mut gt = String::new();
        for row in 0..4 {
            let line: Vec<String> = (0..4)
                .map(|c| format!("{:.17e}", scene.t_target_source[(row, c)]))
                .collect();
            gt.push_str(&line.join(" "));
            gt.push('\n');
        }
        std::fs::write(scene_path(dir, points, "gt.txt"), gt).expect("write the ground truth");
        eprintln!(
            "wrote room_{points}_* ({} + {} points)",
            scene.source.len(),
            scene.target.len()
        );
    }
}

/// Binary PCD v0.7, float32 x y z: the one format PCL, Open3D and sie's reader all take.
fn write_pcd_binary(path: &Path, points: &[Point]) {
    let mut out = BufWriter::new(File::create(path).expect("create PCD"));
    let n = points.len();
    write!(
        out,
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n\
         COUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    .expect("write PCD header");
    for p in points {
        for c in p {
            out.write_all(&(*c as f32).to_le_bytes()).expect("write PCD data");
        }
    }
    out.flush().expect("write PCD");
}

mod run {
    use std::path::Path;

    use sie::geometry::{rotation_angle, rotation_part, translation_part};
    use sie::io::{read_cloud, read_transform};
    use std::time::Instant;

    use sie::geometry::point_to_plane_step;
    use sie::nn::NearestNeighbours;
    use sie::normals::estimate_normals;
    use sie::parallel::Workers;
    use sie::{
        Hooks, Metric, Point, PrepareOptions, PreparedTarget, RegistrationConfig, RegistrationResult,
        register_clouds, register_clouds_to,
    };

    use super::scene_path;

    pub const HEADER: &str = "library,method,points,threads,seconds,iterations,rotation_error_deg,translation_error_m,converged,note";

    /// Median of `repeats` runs (accuracy and stages of the median run).
    pub fn all(dir: &Path, sizes: &[usize]) {
        println!("{HEADER}");
        for &points in sizes {
            let read = |part: &str| {
                let path = scene_path(dir, points, part);
                read_cloud(&path).unwrap_or_else(|e| panic!("{e} (run `bench_icp scenes` first)"))
            };
            let (source, target) = (read("source.pcd").points, read("target.pcd").points);
            let truth = read_transform(&scene_path(dir, points, "gt.txt")).expect("ground truth");
            let repeats = if points <= 100_000 { 3 } else { 1 };
            for threads in [1, 2] {
                let config = RegistrationConfig {
                    metric: Metric::PointToPlane,
                    threads,
                    ..RegistrationConfig::default()
                };
                let floor = floor_per_iteration(&source, &target, threads);
                // `repeats` runs of one registration, sorted by total time, as one row.
                let row = |method: &str, register: &dyn Fn() -> RegistrationResult, note: &str| {
                    let mut runs: Vec<RegistrationResult> = (0..repeats).map(|_| register()).collect();
                    runs.sort_by(|a, b| a.times.total.total_cmp(&b.times.total));
                    print_row(method, &runs, &truth, source.len(), threads, repeats, floor, note);
                };
                row(
                    "point-to-plane",
                    &|| {
                        register_clouds(&source, &target, None, None, &config, Hooks::default())
                            .expect("registration")
                    },
                    "",
                );
                // The paper's single run from the guess (`Starts::InitialGuess`): what the default's
                // automatic starts cost from this far guess.
                let one_start = RegistrationConfig {
                    starts: sie::Starts::InitialGuess,
                    ..config.clone()
                };
                row(
                    "point-to-plane one start",
                    &|| {
                        register_clouds(&source, &target, None, None, &one_start, Hooks::default())
                            .expect("registration")
                    },
                    "",
                );
                // The same registration onto a target prepared (kd-tree and every normal) before
                // the clock starts: what each call costs when a sequence reuses its target.
                let started = Instant::now();
                let prepared = PreparedTarget::new(&target, None, &PrepareOptions::from_config(&config))
                    .expect("prepared target");
                let index_seconds = started.elapsed().as_secs_f64();
                // Every normal up front (a prepared target otherwise estimates the ones its first
                // registration reaches, inside that call: the `normals` of the row above).
                let all_normals = prepared.estimate_all_normals(threads).expect("normals");
                row(
                    "point-to-plane prepared target",
                    &|| {
                        register_clouds_to(&source, &prepared, None, &config, Hooks::default())
                            .expect("registration")
                    },
                    &format!(" prepare={index_seconds:.4} all_normals={all_normals:.4}"),
                );
            }
        }
    }

    /// One CSV row for the median of `runs` (sorted by total time).
    #[allow(clippy::too_many_arguments)]
    fn print_row(
        method: &str,
        runs: &[RegistrationResult],
        truth: &nalgebra::Matrix4<f64>,
        points: usize,
        threads: usize,
        repeats: usize,
        floor: f64,
        extra_note: &str,
    ) {
        let median = &runs[runs.len() / 2];
        let error = truth.try_inverse().expect("invertible ground truth") * median.transform;
        let t = &median.times;
        eprintln!(
            "sie {method} {points} points, {threads} thread(s): {:.3} s, {} iterations, {:?}",
            t.total, median.iterations, median.stop_reason
        );
        println!(
            "sie,{method},{points},{threads},{:.6},{},{:.6},{:.6},{},\
                     repeats={repeats} index={:.4} normals={:.4} matching={:.4} weighting={:.4} solve={:.4} \
                     evaluation={:.4} floor={floor:.6}{extra_note}",
            t.total,
            median.iterations,
            rotation_angle(&rotation_part(&error)).to_degrees(),
            translation_part(&error).norm(),
            median.converged,
            t.index,
            t.normals,
            t.matching,
            t.weighting,
            t.solve,
            t.evaluation,
        );
    }

    /// The floor of one ICP iteration: one nearest-neighbour pass over every source point (kd-tree
    /// built before, source in a spatial order, `threads` threads) and one point-to-plane
    /// normal-equation build and 6×6 solve over all pairs. Median of 5, seconds.
    fn floor_per_iteration(source: &[Point], target: &[Point], threads: usize) -> f64 {
        let workers = Workers::new(threads).expect("workers");
        let index = NearestNeighbours::new(target).expect("index");
        let normals = estimate_normals(target, &index, 10, &workers);
        // 10 cm grid cells in lexicographic order: close to the locality sie's curve order gives.
        let mut ordered = source.to_vec();
        ordered.sort_by_key(|p| p.map(|c| (c / 0.1).floor() as i64));
        let mut nearest = vec![0usize; ordered.len()];
        let weights = vec![1.0; ordered.len()];
        let mut times: Vec<f64> = (0..5)
            .map(|_| {
                let started = Instant::now();
                workers.for_each_chunk_mut(&mut nearest, |first, chunk| {
                    for (k, slot) in chunk.iter_mut().enumerate() {
                        *slot = index.nearest_one(&ordered[first + k]).0;
                    }
                });
                let terms: Vec<(Point, Point, Point)> = ordered
                    .iter()
                    .zip(&nearest)
                    .map(|(p, &t)| (*p, target[t], normals[t]))
                    .collect();
                std::hint::black_box(point_to_plane_step(
                    &nalgebra::Matrix4::identity(),
                    &terms,
                    &weights,
                ));
                started.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        times[2]
    }
}
